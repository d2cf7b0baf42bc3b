"""PolicyChunkDataset on task episodes: cameras, tactile images, agent_pos and action chunks, and agent_pos
equal to what the Gymnasium environment observes on the same rollout."""

from __future__ import annotations

import os

import numpy as np
import pytest
import torch

from univtac_data import DatasetWriter
from univtac_data.envs.task_env import TaskEnv
from univtac_data.generators.tasks.base import TaskConfig
from univtac_data.generators.tasks.collect import TaskEpisodeSpec, run_expert
from univtac_data.loaders import AGENT_POS, TASK_OBS_KEYS, PolicyChunkDataset

os.environ.setdefault("MUJOCO_GL", "egl")


@pytest.fixture(scope="module")
def task_dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("tasks") / "ds"
    outcome = run_expert(TaskEpisodeSpec("lift_can", 4, TaskConfig(camera_size=(32, 24))))
    assert outcome.episode is not None
    DatasetWriter.open(root).add(outcome.episode)
    return root, outcome.episode


def test_policy_chunks_of_task_episodes(task_dataset):
    root, episode = task_dataset
    data = PolicyChunkDataset(root, obs_keys=TASK_OBS_KEYS, chunk=8, history=2, names="lift_can")
    assert len(data) == episode.meta.n_frames
    last = data[len(data) - 1]
    obs = last["obs"]
    assert obs["scene/cameras/head/rgb"].shape == (2, 3, 24, 32) and obs["tactile/left/marked_rgb"].shape == (2, 3, 240, 320)
    assert obs[AGENT_POS].shape == (2, 8) and obs[AGENT_POS].dtype == torch.float32
    assert last["action"].shape == (8, 8) and last["action_is_pad"].tolist() == [False] + [True] * 7
    t = 40
    sample = data[t]
    stored = np.concatenate([episode["robot/ee_pose"][t], [episode["robot/gripper_width_m"][t]]]).astype(np.float32)
    assert np.allclose(sample["obs"][AGENT_POS][-1].numpy(), stored)
    assert np.array_equal(sample["action"].numpy(), episode["robot/action"][t:t + 8])


def test_agent_pos_is_what_the_environment_observes(task_dataset):
    root, episode = task_dataset
    data = PolicyChunkDataset(root, obs_keys=(AGENT_POS,), chunk=1)
    env = TaskEnv("lift_can", cameras=False)
    obs, _ = env.reset(seed=episode.meta.seed)
    assert np.allclose(obs["agent_pos"], data[0]["obs"][AGENT_POS][0].numpy(), atol=1e-6)
    for t, action in enumerate(episode["robot/action"][:30]):
        obs, *_ = env.step(action)
        assert np.allclose(obs["agent_pos"], data[t + 1]["obs"][AGENT_POS][0].numpy(), atol=1e-5), t
    env.close()
