"""Policies for ``univtac-data evaluate``: anything with ``reset()`` and ``act(obs) -> action``.

``expert`` (the task's scripted expert, with privileged access to the simulation), ``zero`` (stay where
the gripper is), ``random`` (a seeded random walk of the end effector and the opening), ``replay:DATASET``
(the recorded actions of a dataset's episodes, each on its own seed), and ``module:factory`` for the user's
own: ``factory()`` returns the policy. Actions are absolute (8,): x, y, z m, quaternion w, x, y, z, opening m.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator
from typing import Any, Protocol

import numpy as np

from univtac_data.envs.task_env import TaskEnv
from univtac_data.generators.tasks.base import ExpertContext, Step
from univtac_data.storage.errors import DatasetError


class Policy(Protocol):
    def reset(self) -> None: ...

    def act(self, obs: dict[str, Any]) -> np.ndarray: ...


class ExpertPolicy:
    """The task's scripted expert, stepping the environment's own session (it reads touch and poses)."""

    def __init__(self, env: TaskEnv) -> None:
        self.env = env
        self._script: Iterator[Step] | None = None

    def reset(self) -> None:
        session = self.env.session
        self._script = self.env.task.expert(ExpertContext(session, session.rng))

    def act(self, obs: dict[str, Any]) -> np.ndarray:
        assert self._script is not None, "reset() first"
        step = next(self._script, None)
        return self.env.session.last_action.astype(np.float32) if step is None else step.action.astype(np.float32)


class ZeroPolicy:
    """Hold the current pose and opening (the action that changes nothing)."""

    def reset(self) -> None:
        pass

    def act(self, obs: dict[str, Any]) -> np.ndarray:
        return np.asarray(obs["agent_pos"], np.float32).copy()


class RandomPolicy:
    """A random walk: up to 1 cm, 0.1 rad and 5 mm of opening a step, from the current state (seeded)."""

    def __init__(self, seed: int = 0) -> None:
        self.seed = seed
        self.rng = np.random.default_rng(seed)

    def reset(self) -> None:
        pass

    def act(self, obs: dict[str, Any]) -> np.ndarray:
        from univtac_data.generators.scene.geometry import quat_from_axis_angle, quat_mul

        action = np.asarray(obs["agent_pos"], np.float64).copy()
        action[:3] += self.rng.uniform(-0.01, 0.01, 3)
        axis = self.rng.normal(size=3)
        action[3:7] = quat_mul(quat_from_axis_angle(axis, self.rng.uniform(0, 0.1)), action[3:7])
        action[7] = float(np.clip(action[7] + self.rng.uniform(-0.005, 0.005), 0.0, 0.08))
        return action.astype(np.float32)


class ReplayPolicy:
    """Replays recorded actions: ``episodes`` maps a seed to its (T, 8) actions; ``start(seed)`` picks one."""

    def __init__(self, episodes: dict[int, np.ndarray]) -> None:
        self.episodes = episodes
        self._actions: np.ndarray | None = None
        self._k = 0

    def start(self, seed: int) -> None:
        self._actions, self._k = self.episodes[seed], 0

    def reset(self) -> None:
        self._k = 0

    def act(self, obs: dict[str, Any]) -> np.ndarray:
        assert self._actions is not None, "start(seed) first"
        # actions[k] was sent after frame k; the last row repeats the final target
        action = self._actions[min(self._k, len(self._actions) - 2)]
        self._k += 1
        return action


def load_replay(path: str, task: str) -> ReplayPolicy:
    """The recorded actions of every episode of ``task`` in the dataset at ``path``, by seed."""
    from univtac_data.storage import Dataset

    dataset = Dataset.open(path)
    episodes = {}
    for eid, row in dataset.index.items():
        if row.kind == "task" and row.name == task:
            with dataset.open_episode(eid) as handle:
                episodes[row.seed] = handle.read("robot/action")
    if not episodes:
        raise DatasetError(f"{path}: no episode of task {task!r} to replay")
    return ReplayPolicy(dict(sorted(episodes.items())))


def user_policy(spec: str) -> Policy:
    """``module:factory`` -> ``factory()``, checked to have ``reset`` and ``act``."""
    module_name, _, attr = spec.partition(":")
    try:
        module = importlib.import_module(module_name)
    except Exception as error:  # the user's module may fail in any way; say so in one line
        raise DatasetError(f"--policy {spec}: cannot import {module_name!r}: {type(error).__name__}: {error}") from None
    factory = getattr(module, attr, None)
    if factory is None:
        raise DatasetError(f"--policy {spec}: module {module_name!r} has no {attr!r}")
    try:
        policy = factory()
    except Exception as error:
        raise DatasetError(f"--policy {spec}: {attr}() failed: {type(error).__name__}: {error}") from None
    if not (callable(getattr(policy, "reset", None)) and callable(getattr(policy, "act", None))):
        raise DatasetError(f"--policy {spec}: {attr}() must return an object with reset() and act(obs)")
    return policy


__all__ = ["ExpertPolicy", "Policy", "RandomPolicy", "ReplayPolicy", "ZeroPolicy", "load_replay", "user_policy"]
