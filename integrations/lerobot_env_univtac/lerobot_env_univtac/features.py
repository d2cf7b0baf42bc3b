"""What the environment observes, as LeRobot features, named as ``univtac-data export lerobot`` names them.

Each :class:`EnvFeature` pairs a key of the environment's observation (LeRobot's gym convention:
``pixels/<name>`` for an image of the ``pixels`` dict, ``agent_pos``, and ``action``) with the LeRobot key
``lerobot.envs.utils.preprocess_observation`` turns it into (``observation.images.<name>``,
``observation.state``). The keys and shapes are those of an export of episodes recorded with the same sensor,
cameras and camera size, so a policy trained on the export reads the environment unchanged. The export's other
features (tactile depth maps, marker positions, forces, object poses) are not observed here: object poses are
simulator ground truth, and LeRobot's policies read only ``observation.state`` and the images.

No lerobot import here: the plugin's features can be checked without it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from univtac_data.export.lerobot_features import STATE_NAMES
from univtac_data.generators.scene.gripper import PADS
from univtac_data.generators.tasks.base import TaskConfig
from univtac_data.generators.tasks.registry import make_task

Kind = Literal["VISUAL", "STATE", "ACTION"]  # lerobot.configs.types.FeatureType member names
ACTION_DIM = 8  # end-effector target in the world frame (x, y, z m; qw, qx, qy, qz) and gel-to-gel opening (m)


@dataclass(frozen=True)
class EnvFeature:
    """``env_key``: the observation key (``pixels/<name>``, ``agent_pos``, ``action``); ``policy_key``: the
    LeRobot (and export) key; ``kind``: a ``FeatureType`` name; ``shape``: (H, W, 3) for images (channel last,
    as the environment returns them), (n,) otherwise."""

    env_key: str
    policy_key: str
    kind: Kind
    shape: tuple[int, ...]


def pad_image_names() -> list[str]:
    """Per pad: I_marked (``tactile_<pad>``) and I_pure (``tactile_<pad>_pure``), as the export names them."""
    return [name for pad in PADS for name in (f"tactile_{pad}", f"tactile_{pad}_pure")]


def env_features(task: str, config: TaskConfig) -> list[EnvFeature]:
    """The features of ``task`` made with ``config`` (sensor, cameras, camera size): the scene cameras, both
    pads' images, the state and the action."""
    made = make_task(task, config)  # raises UnknownTaskError naming the known tasks
    out = [EnvFeature(f"pixels/{cam.name}", f"observation.images.{cam.name}", "VISUAL", (cam.height_px, cam.width_px, 3))
           for cam in made.cameras()]
    tactile_shape = (made.profile.image_height_px, made.profile.image_width_px, 3)
    out += [EnvFeature(f"pixels/{name}", f"observation.images.{name}", "VISUAL", tactile_shape)
            for name in pad_image_names()]
    out += [EnvFeature("agent_pos", "observation.state", "STATE", (len(STATE_NAMES),)),
            EnvFeature("action", "action", "ACTION", (ACTION_DIM,))]
    return out


def features_map(features: list[EnvFeature]) -> dict[str, str]:
    """``EnvConfig.features_map``: environment key -> LeRobot key."""
    return {f.env_key: f.policy_key for f in features}
