"""Turn the frames a ``GripperSim`` recorded into a spec-conforming ``Episode``."""

from __future__ import annotations

from typing import Any

import numpy as np

from univtac_data.episode import Episode
from univtac_data.generators.scene.frame_stack import PIXEL_FIELDS
from univtac_data.generators.scene.gripper import PADS
from univtac_data.generators.scene.sim import RecordedFrame
from univtac_data.schema.models import CameraInfo, EpisodeMeta, GeneratorInfo, SafetySummary


def frames_to_arrays(frames: list[RecordedFrame], pixels: dict[str, np.ndarray], rate_hz: float,
                     reference_rgb: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Every array of the format from the recorded frames (T = len(frames)) and per-pixel arrays
    (``GripperSim.pixel_arrays()``, (T, ...) by path: tactile images and maps, camera images);
    ``reference_rgb``: the undeformed gel's I_pure
    (``GripperSim.reference_rgb``), recorded as each pad's ``pure_ref_rgb``.

    ``robot/action[k]`` is the set-point commanded over the interval from frame k to frame k+1, i.e. the
    set-point in force when frame k+1 is recorded; the last frame repeats its own set-point.
    """
    t = len(frames)
    arrays: dict[str, np.ndarray] = {
        "timestamps_ns": np.rint(np.arange(t) * (1e9 / rate_hz)).astype(np.int64),
        "robot/ee_pose": np.stack([f.ee_pose for f in frames]).astype(np.float64),
        "robot/gripper_width_m": np.array([f.opening_m for f in frames], np.float32),
        "robot/finger_pos_m": np.stack([f.finger_pos_m for f in frames]).astype(np.float32),
        "scene/primitive": np.array([f.primitive for f in frames], np.int16),
    }
    for name in frames[0].objects_world:
        arrays[f"scene/objects/{name}/pose"] = np.stack([f.objects_world[name] for f in frames]).astype(np.float64)
    for path, stack in pixels.items():
        if path.startswith("scene/cameras/"):
            arrays[path] = stack
    setpoints = np.stack([np.concatenate([f.ee_setpoint, [f.opening_setpoint_m]]) for f in frames])
    arrays["robot/action"] = np.concatenate([setpoints[1:], setpoints[-1:]]).astype(np.float32)
    for pad in PADS:
        tac = [f.tactile[pad] for f in frames]
        prefix = f"tactile/{pad}/"
        for name in PIXEL_FIELDS:
            arrays[prefix + name] = pixels[prefix + name]
        arrays[prefix + "markers_ref_px"] = tac[0].markers_ref_px.astype(np.float32)
        if reference_rgb is not None:
            arrays[prefix + "pure_ref_rgb"] = np.array(reference_rgb, dtype=np.uint8)
        arrays[prefix + "markers_px"] = np.stack([x.markers_px for x in tac]).astype(np.float32)
        arrays[prefix + "object_pose"] = np.stack([f.object_in_pad[pad] for f in frames]).astype(np.float64)
        arrays[prefix + "normal_force_n"] = np.array([x.normal_force_n for x in tac], np.float32)
        arrays[prefix + "shear_force_n"] = np.stack([x.shear_force_n for x in tac]).astype(np.float32)
        arrays[prefix + "slip_mm"] = np.array([x.slip_mm for x in tac], np.float32)
        arrays[prefix + "pad_pose"] = np.stack([f.pad_world[pad] for f in frames]).astype(np.float64)
    return arrays


def safety_summary(arrays: dict[str, np.ndarray]) -> SafetySummary:
    return SafetySummary(
        max_indentation_mm=max(int(arrays[f"tactile/{p}/depth_um"].max()) for p in PADS) / 1000.0,
        max_slip_mm=max(float(arrays[f"tactile/{p}/slip_mm"].max()) for p in PADS),
        max_normal_force_n=max(float(arrays[f"tactile/{p}/normal_force_n"].max()) for p in PADS),
    )


def build_episode(frames: list[RecordedFrame], pixels: dict[str, np.ndarray], *, episode_id: str, kind: str, name: str, sensor: str, seed: int,
                  generator: GeneratorInfo, success: bool | None, rate_hz: float, primitive_names: list[str],
                  reference_rgb: np.ndarray | None = None, cameras: list[CameraInfo] | None = None,
                  actions: np.ndarray | None = None, extra: dict[str, Any] | None = None) -> Episode:
    """An ``Episode`` of the recorded frames. Objects: those of the frames, the first the tactile object.
    ``actions``: (T, 8) the commanded actions when the caller knows them exactly (the task environments:
    action k is what the policy sent after frame k), instead of reading them off the set-points."""
    arrays = frames_to_arrays(frames, pixels, rate_hz, reference_rgb)
    if actions is not None:
        arrays["robot/action"] = np.asarray(actions, np.float32)
    objects = list(frames[0].objects_world)
    meta = EpisodeMeta(
        episode_id=episode_id, kind=kind, name=name, sensor=sensor, seed=seed,  # type: ignore[arg-type]
        generator=generator, success=success, safety=safety_summary(arrays), nominal_rate_hz=rate_hz,
        n_frames=len(frames), objects=objects, tactile_object=objects[0],
        primitive_names=primitive_names, cameras=cameras or [], extra=extra or {},
    )
    return Episode(meta=meta, arrays=arrays)
