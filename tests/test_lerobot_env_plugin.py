"""The LeRobot env plugin ``integrations/lerobot_env_univtac``: its distribution name, its features against the
environment and against ``univtac-data export lerobot``, and (where lerobot 0.4.4 imports) LeRobot's own
discovery, ``make_env``, ``preprocess_observation`` and evaluation loop on a task."""

from __future__ import annotations

import importlib.util
import io
import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import gymnasium as gym
import numpy as np
import pyarrow.parquet as pq
import pytest
from PIL import Image

from univtac_data import Dataset
from univtac_data.export import export_lerobot
from univtac_data.generators.tasks.base import TaskConfig
from univtac_data.generators.tasks.collect import TaskEpisodeSpec, run_expert
from univtac_data.generators.tasks.lift_can import LiftCan
from univtac_data.generators.tasks.registry import TASK_NAMES
from univtac_data.storage import DatasetWriter

PLUGIN_DIR = Path(__file__).resolve().parents[1] / "integrations" / "lerobot_env_univtac"
if importlib.util.find_spec("lerobot_env_univtac") is None:  # not pip-installed: use the source tree
    sys.path.insert(0, str(PLUGIN_DIR))

from lerobot_env_univtac import env_features, features_map, gym_id  # noqa: E402

NO_CAMERAS = TaskConfig(cameras=False)
SMALL_CAMERAS = TaskConfig(cameras=True, camera_size=(64, 48))
EXPORT_SEED = 3
EXPORT_STEPS = 40


def flat_observation(obs: dict) -> dict[str, np.ndarray]:
    """An observation under the plugin's environment keys (``pixels/<name>``, ``agent_pos``)."""
    out = {f"pixels/{name}": image for name, image in obs["pixels"].items()}
    out["agent_pos"] = obs["agent_pos"]
    return out


def make(task: str, config: TaskConfig, **kwargs):
    w, h = config.camera_size
    return gym.make(gym_id(task), cameras=config.cameras, camera_width=w, camera_height=h, **kwargs)


# --- without lerobot ----------------------------------------------------------------------------------------
def test_the_distribution_is_named_as_lerobot_discovers_plugins(tmp_path):
    """LeRobot imports an installed distribution by its raw metadata ``Name`` (not the normalised one), so the
    built wheel's Name must keep the underscores, start with ``lerobot_env_`` and be the importable module."""
    source = shutil.copytree(PLUGIN_DIR, tmp_path / "src", ignore=shutil.ignore_patterns("build", "*.egg-info"))
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w",
                    str(tmp_path / "dist"), str(source)], check=True, capture_output=True, timeout=300)
    (wheel,) = (tmp_path / "dist").glob("*.whl")
    with zipfile.ZipFile(wheel) as zf:
        metadata = next(zf.read(n).decode() for n in zf.namelist() if n.endswith(".dist-info/METADATA"))
        modules = {n.split("/")[0] for n in zf.namelist() if n.endswith(".py")}
    name = next(line.split(":", 1)[1].strip() for line in metadata.splitlines() if line.startswith("Name:"))
    assert name == "lerobot_env_univtac" and name.startswith("lerobot_env_")
    assert name in modules
    assert "Requires-Dist: univtac-data" in metadata


@pytest.mark.parametrize("task", TASK_NAMES)
def test_features_cover_every_observation_with_its_shape(task):
    features = env_features(task, NO_CAMERAS)
    env = make(task, NO_CAMERAS)
    try:
        obs, _ = env.reset(seed=0)
        obs2, *_ = env.step(obs["agent_pos"][:8])  # hold: the pose and opening the state reports
        assert env.action_space.shape == next(f.shape for f in features if f.env_key == "action")
        observed = {f.env_key: f for f in features if f.kind != "ACTION"}
        for o in (obs, obs2):
            assert env.observation_space.contains(o)
            flat = flat_observation(o)
            assert set(flat) == set(observed)
            for key, value in flat.items():
                assert value.shape == observed[key].shape, key
                assert value.dtype == (np.uint8 if observed[key].kind == "VISUAL" else np.float32), key
    finally:
        env.close()
    # every key maps to the name LeRobot's preprocess_observation gives it
    for f in features:
        if f.env_key.startswith("pixels/"):
            assert f.policy_key == "observation.images." + f.env_key.removeprefix("pixels/")
    assert features_map(features)["agent_pos"] == "observation.state"
    assert len(set(features_map(features).values())) == len(features)


def test_features_include_the_scene_cameras_at_their_size():
    features = {f.env_key: f for f in env_features("lift_can", SMALL_CAMERAS)}
    assert features["pixels/head"].shape == features["pixels/wrist"].shape == (48, 64, 3)
    env = make("lift_can", SMALL_CAMERAS)
    try:
        obs, _ = env.reset(seed=1)
        flat = flat_observation(obs)
        assert set(flat) == set(features) - {"action"}
        assert all(flat[k].shape == features[k].shape for k in flat)
    finally:
        env.close()


def test_unknown_task_names_the_known_ones():
    with pytest.raises(KeyError, match="lift_can"):
        env_features("lift_jar", NO_CAMERAS)


def expert_episode(max_steps: int | None = None):
    """The expert's lift_can episode from ``EXPORT_SEED`` (no cameras), cut at ``max_steps`` policy steps."""
    with pytest.MonkeyPatch.context() as patch:
        if max_steps is not None:
            patch.setattr(LiftCan, "max_steps", max_steps)
        outcome = run_expert(TaskEpisodeSpec("lift_can", EXPORT_SEED, NO_CAMERAS))
    assert outcome.episode is not None
    return outcome


@pytest.fixture(scope="module")
def lift_can_export(tmp_path_factory):
    """The first EXPORT_STEPS steps of an expert lift_can episode (no cameras; the pads touch the can from
    frame 28), and its LeRobot export (images as PNG). Cut short because the export of the whole episode
    takes a minute: the PNG images."""
    root = tmp_path_factory.mktemp("plugin")
    outcome = expert_episode(EXPORT_STEPS)
    assert outcome.episode.arrays["tactile/left/normal_force_n"].max() > 0  # the export includes contact
    with DatasetWriter.open(str(root / "src"), storage="hdf5", sensors=[NO_CAMERAS.sensor]) as writer:
        writer.add(outcome.episode)
    export_lerobot(str(root / "src"), root / "lr")
    return root / "src", root / "lr"


def test_the_export_and_the_environment_agree_on_keys_shapes_and_values(lift_can_export):
    """A policy trained on an export reads the environment: the export has every feature the environment
    observes, with the same shape, and replaying the export's actions in the environment reproduces the
    exported state and images frame by frame."""
    src, lr = lift_can_export
    info = json.loads((lr / "meta/info.json").read_text())
    features = env_features("lift_can", NO_CAMERAS)
    for f in features:
        assert f.policy_key in info["features"], f.policy_key
        assert tuple(info["features"][f.policy_key]["shape"]) == f.shape, f.policy_key
    rows = [row for path in sorted((lr / "data").glob("chunk-*/file-*.parquet")) for row in pq.read_table(path).to_pylist()]
    assert Dataset.open(str(src)).episode_ids == [f"lift_can-gelsight_mini-{EXPORT_SEED:06d}"]
    observed = [f for f in features if f.kind != "ACTION"]
    env = make("lift_can", NO_CAMERAS)
    try:
        assert list(pq.read_table(lr / "meta/tasks.parquet").to_pandas().index) == [env.task_description]
        obs, _ = env.reset(seed=EXPORT_SEED)
        for row in rows:
            flat = flat_observation(obs)
            where = f"frame {row['frame_index']}"
            for f in observed:
                if f.kind == "VISUAL":
                    exported = np.asarray(Image.open(io.BytesIO(row[f.policy_key]["bytes"])).convert("RGB"))
                    # float32 actions (the export's dtype) move the gel by nanometres: a level here and there,
                    # and a few marker-edge pixels
                    off = np.abs(flat[f.env_key].astype(int) - exported) > 1
                    assert off.mean() < 1e-3, f"{f.policy_key} at {where}: {off.mean():.2%} of values off"
                else:
                    np.testing.assert_allclose(flat[f.env_key], row[f.policy_key], atol=1e-6, err_msg=where)
            obs, _, terminated, truncated, _ = env.step(np.asarray(row["action"], np.float32))
            assert not (terminated or truncated), where
    finally:
        env.close()
    assert len(rows) == EXPORT_STEPS + 1


def test_the_experts_actions_succeed_in_the_environment():
    """The whole expert episode's recorded actions (what the export writes as ``action``, as float32) replayed
    in the plugin's environment lift the can: the actions mean the same thing in both."""
    episode = expert_episode().episode
    assert episode.meta.success
    actions = episode.arrays["robot/action"]
    env = make("lift_can", NO_CAMERAS)
    try:
        env.reset(seed=EXPORT_SEED)
        for k, action in enumerate(actions):
            _, reward, terminated, truncated, info = env.step(action)
            if terminated or truncated:
                break
    finally:
        env.close()
    assert info["is_success"] and reward == 1.0 and terminated and not truncated
    assert info["safety"]["ok"] and k < len(actions) - 1


# --- with lerobot 0.4.4 -------------------------------------------------------------------------------------
def lerobot_or_skip():
    try:
        import lerobot  # noqa: F401
        from lerobot.envs.configs import EnvConfig  # noqa: F401
    except ImportError as error:
        pytest.skip(f"lerobot is not installed ({error}); see docs/export.md for the lerobot 0.4.4 environment")
    except RuntimeError as error:  # torchvision built for another torch: "operator torchvision::nms does not exist"
        pytest.skip(f"lerobot is installed but cannot import beside this torch ({error})")


def test_lerobot_eval_command_line_finds_the_env_type():
    """``--env.discover_packages_path=lerobot_env_univtac`` (how lerobot 0.4.4 loads env plugins) then
    ``--env.type=univtac --env.task=...``: parsed by lerobot-eval's own parser in a fresh interpreter."""
    lerobot_or_skip()
    script = (
        "import sys, json\n"
        "from lerobot.configs import parser\n"
        "from lerobot.configs.eval import EvalPipelineConfig\n"
        "@parser.wrap()\n"
        "def main(cfg: EvalPipelineConfig):\n"
        "    print(json.dumps({'type': cfg.env.type, 'gym_id': cfg.env.gym_id, 'steps': cfg.env.episode_length,\n"
        "                      'map': cfg.env.features_map}))\n"
        "main()\n"
    )
    args = ["--env.discover_packages_path=lerobot_env_univtac", "--env.type=univtac", "--env.task=grasp_classify",
            "--env.cameras=false", "--policy.type=act", "--policy.device=cpu"]
    env = {**os.environ, "PYTHONPATH": str(PLUGIN_DIR), "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    result = subprocess.run([sys.executable, "-c", script, *args], capture_output=True, text=True, timeout=300,
                            env=env)
    assert result.returncode == 0, result.stderr[-2000:]
    parsed = json.loads(result.stdout.strip().splitlines()[-1])
    assert parsed["type"] == "univtac" and parsed["gym_id"] == "lerobot_env_univtac/GraspClassify-v0"
    assert parsed["steps"] == 1250
    assert parsed["map"]["pixels/tactile_left"] == "observation.images.tactile_left"
    # the task's limit is a time: at 25 frames a second half as many steps
    slower = subprocess.run([sys.executable, "-c", script, *args, "--env.fps=25"], capture_output=True, text=True,
                            timeout=300, env=env)
    assert slower.returncode == 0, slower.stderr[-2000:]
    assert json.loads(slower.stdout.strip().splitlines()[-1])["steps"] == 625


def test_lerobot_plugin_discovery_imports_the_plugin():
    """``register_third_party_plugins()`` (lerobot-eval and lerobot-train call it) imports installed
    distributions by name prefix. lerobot 0.4.4 scans robot, camera, teleoperator and policy prefixes only,
    which is why the command line also needs ``--env.discover_packages_path``; once lerobot scans
    ``lerobot_env_`` it finds this plugin by its name alone."""
    lerobot_or_skip()
    import inspect

    from lerobot.utils import import_utils

    source = inspect.getsource(import_utils.register_third_party_plugins)
    if "lerobot_env_" not in source:
        assert '"lerobot_policy_"' in source  # the 0.4.4 list: the reason the docs give the extra argument
        return
    import_utils.register_third_party_plugins()
    assert "lerobot_env_univtac" in sys.modules


@pytest.fixture(scope="module")
def lerobot():
    """Skip (before any costly fixture) where lerobot does not import."""
    lerobot_or_skip()


def univtac_config(**kwargs):
    from lerobot_env_univtac.configs import UnivtacEnv

    return UnivtacEnv(task="lift_can", cameras=False, **kwargs)


def test_make_env_and_preprocess_observation():
    lerobot_or_skip()
    from lerobot.envs.factory import make_env
    from lerobot.envs.utils import add_envs_task, env_to_policy_features, preprocess_observation

    cfg = univtac_config(episode_length=4)
    envs = make_env(cfg, n_envs=2)
    vec = envs["univtac"][0]
    try:
        obs, _ = vec.reset(seed=[0, 1])
        batch = preprocess_observation(obs)
        expected = {k: f for k, f in env_to_policy_features(cfg).items() if k != "action"}
        assert set(batch) == set(expected)
        for key, feature in expected.items():
            assert tuple(batch[key].shape) == (2, *feature.shape), key
        assert vec.call("_max_episode_steps")[0] == 4
        assert add_envs_task(vec, batch)["task"] == ["lift can", "lift can"]
    finally:
        vec.close()


def test_lerobot_eval_policy_runs_a_policy_made_from_the_export(lerobot, lift_can_export):
    """LeRobot's evaluation loop (``eval_policy``: rollout, success, rewards) on the environment, with an ACT
    policy made from the export's metadata as lerobot-train makes it (fresh weights, the export's statistics)."""
    import torch
    from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
    from lerobot.envs.factory import make_env, make_env_pre_post_processors
    from lerobot.policies.act.configuration_act import ACTConfig
    from lerobot.policies.factory import make_policy, make_pre_post_processors
    from lerobot.scripts.lerobot_eval import eval_policy

    _, lr = lift_can_export
    meta = LeRobotDatasetMetadata("univtac/plugin-test", root=lr)
    torch.manual_seed(0)
    policy_cfg = ACTConfig(device="cpu", pretrained_backbone_weights=None, chunk_size=5, n_action_steps=5,
                           dim_model=64, dim_feedforward=128, n_encoder_layers=1, n_decoder_layers=1, n_heads=2,
                           use_vae=False)
    policy = make_policy(policy_cfg, ds_meta=meta)
    preprocessor, postprocessor = make_pre_post_processors(policy_cfg, dataset_stats=meta.stats)
    cfg = univtac_config(episode_length=6)
    env_pre, env_post = make_env_pre_post_processors(cfg, policy_cfg)
    vec = make_env(cfg, n_envs=1)["univtac"][0]
    try:
        info = eval_policy(vec, policy, env_pre, env_post, preprocessor, postprocessor, n_episodes=1, start_seed=0,
                           return_episode_data=True)
    finally:
        vec.close()
    assert [e["seed"] for e in info["per_episode"]] == [0]
    assert info["aggregated"]["pc_success"] in (0.0, 100.0) and np.isfinite(info["aggregated"]["avg_sum_reward"])
    episode = info["episodes"]
    n = len(episode["frame_index"])
    assert 2 <= n <= 7  # at most the 6-step limit, plus the final observation
    assert tuple(episode["action"].shape) == (n, 8) and bool(torch.isfinite(episode["action"]).all())
    for key in ("observation.state", "observation.images.tactile_left", "observation.images.tactile_right_pure"):
        assert episode[key].shape[0] == n, key
