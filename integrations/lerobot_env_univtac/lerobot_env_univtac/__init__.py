"""univtac-data's tasks as a LeRobot environment plugin.

Importing this package registers the gym environments ``lerobot_env_univtac/<Task>-v0`` (see ``env``) and, when
lerobot is installed, the LeRobot env type ``univtac`` (``configs.UnivtacEnv``), so that
``lerobot-eval --env.discover_packages_path=lerobot_env_univtac --env.type=univtac --env.task=lift_can ...``
runs our tasks.
"""

from __future__ import annotations

import importlib.util

from lerobot_env_univtac.env import NAMESPACE, ExportObservation, TaskDescription, gym_id, make_env, register_envs
from lerobot_env_univtac.features import EnvFeature, env_features, features_map

register_envs()

# without lerobot the environments and their features stay usable (and testable); with it, any import error
# of lerobot surfaces here instead of an "unknown env type" later
if importlib.util.find_spec("lerobot") is not None:
    from lerobot_env_univtac.configs import UnivtacEnv  # noqa: F401  (registers --env.type=univtac)

__all__ = ["NAMESPACE", "EnvFeature", "ExportObservation", "TaskDescription", "env_features", "features_map", "gym_id", "make_env",
           "register_envs"]
