"""Which univtac-data field becomes which LeRobot feature (``docs/export.md`` has the table for people).

A LeRobot dataset has one feature set for all its episodes, so every episode exported together must share its
sensor, pads, cameras and objects; :func:`lerobot_features` builds the set from the first episode and
:func:`check_same_layout` refuses an episode that differs.
"""

from __future__ import annotations

from dataclasses import dataclass

from univtac_data.schema.models import EpisodeMeta
from univtac_data.schema.sensors import SensorProfile

STATE_NAMES = ["ee_x_m", "ee_y_m", "ee_z_m", "ee_qw", "ee_qx", "ee_qy", "ee_qz", "gripper_width_m",
               "finger_left_m", "finger_right_m"]
POSE_NAMES = ["x_m", "y_m", "z_m", "qw", "qx", "qy", "qz"]
ROBOT_TYPE = "univtac_parallel_gripper"


@dataclass(frozen=True)
class Feature:
    """One LeRobot feature: its ``key``, LeRobot ``dtype`` ("video", "image" or a numpy dtype name), ``shape``,
    ``names``, and the univtac-data arrays it is made of (``sources``, concatenated along the last axis)."""

    key: str
    dtype: str
    shape: tuple[int, ...]
    names: list[str] | None
    sources: tuple[str, ...]

    @property
    def visual(self) -> bool:
        return self.dtype in ("video", "image")

    def info(self) -> dict[str, object]:
        """The feature's entry in ``meta/info.json``."""
        return {"dtype": self.dtype, "shape": list(self.shape), "names": self.names}


def _scalar(key: str, dtype: str, source: str, name: str) -> Feature:
    return Feature(key, dtype, (1,), [name], (source,))


def lerobot_features(meta: EpisodeMeta, profile: SensorProfile, visual: str) -> list[Feature]:
    """The features of an export of episodes laid out like ``meta``; ``visual`` is "video" or "image"."""
    h, w, n = profile.image_height_px, profile.image_width_px, profile.n_markers
    image_names = ["height", "width", "channels"]
    out = [
        Feature("observation.state", "float32", (len(STATE_NAMES),), list(STATE_NAMES),
                ("robot/ee_pose", "robot/gripper_width_m", "robot/finger_pos_m")),
        Feature("action", "float32", (len(meta.action_names),), list(meta.action_names), ("robot/action",)),
    ]
    for camera in meta.cameras:
        base = f"scene/cameras/{camera.name}"
        out.append(Feature(f"observation.images.{camera.name}", visual, (camera.height_px, camera.width_px, 3),
                           image_names, (f"{base}/rgb",)))
        if camera.depth:
            out.append(Feature(f"observation.depth.{camera.name}", "float32", (camera.height_px, camera.width_px),
                               ["height", "width"], (f"{base}/depth_m",)))
    for pad in meta.pads:
        base = f"tactile/{pad}"
        tac = f"observation.tactile.{pad}"
        out += [
            Feature(f"observation.images.tactile_{pad}", visual, (h, w, 3), image_names, (f"{base}/marked_rgb",)),
            Feature(f"observation.images.tactile_{pad}_pure", visual, (h, w, 3), image_names, (f"{base}/pure_rgb",)),
            Feature(f"{tac}.depth_um", "uint16", (h, w), ["height", "width"], (f"{base}/depth_um",)),
            Feature(f"{tac}.markers_px", "float32", (n, 2), ["marker", "uv"], (f"{base}/markers_px",)),
            Feature(f"{tac}.object_pose", "float64", (7,), list(POSE_NAMES), (f"{base}/object_pose",)),
            _scalar(f"{tac}.normal_force_n", "float32", f"{base}/normal_force_n", "normal_force_n"),
            Feature(f"{tac}.shear_force_n", "float32", (2,), ["x_n", "y_n"], (f"{base}/shear_force_n",)),
            _scalar(f"{tac}.slip_mm", "float32", f"{base}/slip_mm", "slip_mm"),
        ]
    for obj in meta.objects:
        out.append(Feature(f"observation.objects.{obj}.pose", "float64", (7,), list(POSE_NAMES),
                           (f"scene/objects/{obj}/pose",)))
    out += [
        _scalar("observation.primitive", "int64", "scene/primitive", "primitive_index"),
        _scalar("observation.timestamp_ns", "int64", "timestamps_ns", "timestamp_ns"),
    ]
    return out


def layout_of(meta: EpisodeMeta) -> tuple[object, ...]:
    """What must agree between episodes exported together."""
    cameras = tuple((c.name, c.width_px, c.height_px, c.depth) for c in meta.cameras)
    return meta.sensor, tuple(meta.pads), cameras, tuple(meta.objects), tuple(meta.action_names)


def check_same_layout(first: EpisodeMeta, meta: EpisodeMeta, where: str) -> None:
    """Raise ``ValueError`` naming what differs between ``meta`` and the first exported episode."""
    names = ("sensor", "pads", "cameras", "objects", "action_names")
    for name, a, b in zip(names, layout_of(first), layout_of(meta)):
        if a != b:
            raise ValueError(f"{where}: episode {meta.episode_id} has {name} {b!r} but episode "
                             f"{first.episode_id} has {a!r}; a LeRobot dataset has one feature set: export "
                             "such episodes into separate datasets")
