"""The task environments as LeRobot evaluates them: ``lerobot_env_univtac/<Task>-v0`` (e.g.
``lerobot_env_univtac/LiftCan-v0``), a :class:`univtac_data.envs.TaskEnv` (absolute 8-d actions) whose
observation matches ``univtac-data export lerobot``:

- ``agent_pos``: (10,) float32, the export's ``observation.state``: end-effector pose in the world (x, y, z m;
  qw, qx, qy, qz), gripper opening (gel to gel, m), left and right finger slide positions (m);
- ``pixels``: the scene cameras (``head``, ``wrist``) and per pad I_marked (``tactile_<pad>``) and I_pure
  (``tactile_<pad>_pure``), (H, W, 3) uint8.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.envs.registration import WrapperSpec

from univtac_data.envs.task_env import TaskEnv
from univtac_data.export.lerobot import task_text
from univtac_data.export.lerobot_features import STATE_NAMES
from univtac_data.generators.scene.gripper import MAX_OPENING_M, PADS
from univtac_data.generators.tasks.registry import TASKS, task_class

NAMESPACE = "lerobot_env_univtac"
FINGER_RANGE_M = (-0.01, MAX_OPENING_M)  # slide joint positions stay within the opening range (m), with margin


def gym_id(task: str) -> str:
    """``lift_can`` -> ``lerobot_env_univtac/LiftCan-v0`` (the name part of the task's own gym id)."""
    return f"{NAMESPACE}/{task_class(task).gym_id.split('/', 1)[1]}"


class ExportObservation(gym.ObservationWrapper[dict[str, Any], np.ndarray, dict[str, Any]],
                        gym.utils.RecordConstructorArgs):
    """Reshape a :class:`TaskEnv` observation into the export's: the 10-d state and the pads' I_pure images."""

    def __init__(self, env: gym.Env[dict[str, Any], np.ndarray]) -> None:
        gym.utils.RecordConstructorArgs.__init__(self)
        super().__init__(env)
        base = env.observation_space
        assert isinstance(base, spaces.Dict)
        pixels = dict(base["pixels"].spaces)  # type: ignore[attr-defined]
        for pad in PADS:
            pixels[f"tactile_{pad}_pure"] = pixels[f"tactile_{pad}"]
        agent = base["agent_pos"]
        assert isinstance(agent, spaces.Box)
        low = np.concatenate([agent.low, [FINGER_RANGE_M[0]] * 2]).astype(np.float32)
        high = np.concatenate([agent.high, [FINGER_RANGE_M[1]] * 2]).astype(np.float32)
        assert low.shape == (len(STATE_NAMES),)
        self.observation_space = spaces.Dict({**base.spaces, "pixels": spaces.Dict(pixels),
                                              "agent_pos": spaces.Box(low, high, dtype=np.float32)})

    def observation(self, observation: dict[str, Any]) -> dict[str, Any]:
        env = self.env.unwrapped
        assert isinstance(env, TaskEnv)
        sim = env.session.sim
        assert sim is not None
        pixels = dict(observation["pixels"])
        for pad in PADS:
            pixels[f"tactile_{pad}_pure"] = sim.pixels[f"tactile/{pad}/pure_rgb"].array()[-1].copy()
        fingers = np.asarray(sim.frames[-1].finger_pos_m, np.float32)
        state = np.concatenate([observation["agent_pos"], fingers]).astype(np.float32)
        return {**observation, "pixels": pixels, "agent_pos": state}


class TaskDescription(gym.Wrapper[dict[str, Any], np.ndarray, dict[str, Any], np.ndarray],
                      gym.utils.RecordConstructorArgs):
    """Carries ``task_description``, the export's task string ("lift can"), and ``task``, the task's name
    ("lift_can"), where LeRobot's evaluation looks for both (on the outermost wrapper; language-conditioned
    policies read the description); otherwise a pass-through."""

    def __init__(self, env: gym.Env[dict[str, Any], np.ndarray], task: str) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, task=task)
        super().__init__(env)
        self.task = task
        self.task_description = task_text("task", task)


def make_env(task: str, *, sensor: str = "gelsight_mini", contact: str = "geometric", cameras: bool = True,
             camera_width: int = 480, camera_height: int = 270, rate_hz: float = 50.0,
             render_mode: str | None = "rgb_array") -> TaskEnv:
    """The gym entry point of ``lerobot_env_univtac/<Task>-v0``: the bare :class:`TaskEnv` (LeRobot's
    ``EnvConfig`` passes scalars; this makes the camera size of them). ``gym.make`` adds the step limit
    (TimeLimit), then :class:`ExportObservation` and :class:`TaskDescription`, in that order, outermost last."""
    return TaskEnv(task, sensor=sensor, contact=contact, cameras=cameras, camera_size=(camera_width, camera_height),
                   rate_hz=rate_hz, render_mode=render_mode)


def register_envs() -> None:
    """Register ``lerobot_env_univtac/<Task>-v0`` for every task (idempotent)."""
    for name, cls in TASKS.items():
        if gym_id(name) not in gym.registry:
            # additional wrappers go outside gym's TimeLimit: LeRobot reads task_description off the outermost
            wrappers = (WrapperSpec("ExportObservation", "lerobot_env_univtac.env:ExportObservation", {}),
                        WrapperSpec("TaskDescription", "lerobot_env_univtac.env:TaskDescription", {"task": name}))
            gym.register(id=gym_id(name), entry_point="lerobot_env_univtac.env:make_env", kwargs={"task": name},
                         max_episode_steps=cls.max_steps, additional_wrappers=wrappers)
