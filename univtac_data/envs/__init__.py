"""Gymnasium environments of the benchmark tasks: ``import univtac_data.envs`` registers ``univtac/<Task>-v0``
for every task in ``univtac_data.generators.tasks.registry`` (``gymnasium.make("univtac/LiftCan-v0")``)."""

from __future__ import annotations

import gymnasium as gym

from univtac_data.envs.task_env import TaskEnv
from univtac_data.generators.tasks.registry import TASKS

for _name, _cls in TASKS.items():
    if _cls.gym_id not in gym.registry:
        gym.register(id=_cls.gym_id, entry_point="univtac_data.envs.task_env:TaskEnv",
                     kwargs={"task": _name}, max_episode_steps=_cls.max_steps)

__all__ = ["TaskEnv"]
