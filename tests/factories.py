"""Factories for episodes and datasets in tests: small, deterministic, spec-conforming.

The arrays are synthetic (a pressed blob moving across the pad), not physics; the generator tests use
real scenes.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import torch

from univtac_data import CameraInfo, Episode, EpisodeMeta, GeneratorInfo, SafetySummary, get_sensor
from univtac_data.storage import DatasetWriter


def make_episode(sensor: str = "gelsight_mini", n_frames: int = 4, episode_id: str = "ep0", *, seed: int = 0,
                 kind: str = "indenter", name: str = "sphere", cameras: tuple[str, ...] = (),
                 camera_depth: bool = False, objects: tuple[str, ...] = ("indenter",),
                 rate_hz: float = 60.0, reference: bool = True) -> Episode:
    """A conforming episode of ``n_frames`` frames for ``sensor``; ``seed`` changes every array.
    ``reference``: hold each pad's ``pure_ref_rgb`` (so that the writer stores ``pure_rgb`` as its residual)."""
    profile = get_sensor(sensor)
    rng = np.random.default_rng(seed)
    h, w, n = profile.image_height_px, profile.image_width_px, profile.n_markers
    arrays: dict[str, np.ndarray] = {"timestamps_ns": (np.arange(n_frames, dtype=np.int64) * int(1e9 / rate_hz))}
    yy, xx = np.mgrid[0:h, 0:w]
    gx, gy = np.meshgrid(np.arange(profile.marker_cols), np.arange(profile.marker_rows))
    ref = np.stack([profile.cx_px + (gx.ravel() - (profile.marker_cols - 1) / 2) * profile.marker_pitch_x_mm
                    * profile.fx_px / profile.camera_to_surface_mm,
                    profile.cy_px + (gy.ravel() - (profile.marker_rows - 1) / 2) * profile.marker_pitch_y_mm
                    * profile.fy_px / profile.camera_to_surface_mm], axis=1).astype(np.float32)
    for pad in ("left", "right"):
        depth = np.zeros((n_frames, h, w), np.uint16)
        centre = np.array([w / 2, h / 2]) + rng.normal(0, 5, 2)
        for t in range(n_frames):
            r2 = (xx - centre[0] - 2 * t) ** 2 + (yy - centre[1]) ** 2
            depth[t] = np.clip(300 * (1 - r2 / (30.0 ** 2)), 0, None).astype(np.uint16) * (t > 0)
        base = np.array(profile.optics.background_rgb, np.uint8)
        pure = np.broadcast_to(base, (n_frames, h, w, 3)).copy()
        pure[..., 0] = np.clip(pure[..., 0].astype(np.int32) + depth // 4, 0, 255).astype(np.uint8)
        marked = pure.copy()
        for u, v in ref.astype(int):
            marked[:, max(v - 2, 0):v + 3, max(u - 2, 0):u + 3] = 20
        arrays[f"tactile/{pad}/pure_rgb"] = pure
        if reference:
            arrays[f"tactile/{pad}/pure_ref_rgb"] = np.broadcast_to(base, (h, w, 3)).copy()
        arrays[f"tactile/{pad}/marked_rgb"] = marked
        arrays[f"tactile/{pad}/depth_um"] = depth
        arrays[f"tactile/{pad}/contact_mask"] = depth > 0
        arrays[f"tactile/{pad}/markers_ref_px"] = ref
        arrays[f"tactile/{pad}/markers_px"] = (ref[None] + rng.normal(0, 0.3, (n_frames, n, 2))).astype(np.float32)
        pose = np.zeros((n_frames, 7))
        pose[:, 2] = 0.002 - 1e-4 * np.arange(n_frames)
        pose[:, 3] = 1.0
        arrays[f"tactile/{pad}/object_pose"] = pose
        arrays[f"tactile/{pad}/normal_force_n"] = (depth.reshape(n_frames, -1).sum(1) * 1e-6).astype(np.float32)
        touching = (depth.reshape(n_frames, -1) > 0).any(axis=1)[:, None]  # no shear without contact
        arrays[f"tactile/{pad}/shear_force_n"] = (rng.normal(0, 0.01, (n_frames, 2)) * touching).astype(np.float32)
        arrays[f"tactile/{pad}/slip_mm"] = np.zeros(n_frames, np.float32)
    ee = np.zeros((n_frames, 7))
    ee[:, 2] = 0.1 + 0.001 * np.arange(n_frames)
    ee[:, 3] = 1.0
    arrays["robot/ee_pose"] = ee
    arrays["robot/gripper_width_m"] = np.linspace(0.04, 0.03, n_frames, dtype=np.float32)
    arrays["robot/finger_pos_m"] = np.stack([np.linspace(0, 0.005, n_frames)] * 2, 1).astype(np.float32)
    action = np.concatenate([ee, arrays["robot/gripper_width_m"][:, None]], 1).astype(np.float32)
    arrays["robot/action"] = action
    arrays["scene/primitive"] = np.array([0] * (n_frames // 2) + [1] * (n_frames - n_frames // 2), np.int16)
    camera_infos = []
    for cam in cameras:
        camera_infos.append(CameraInfo(name=cam, width_px=64, height_px=48, fovy_deg=60, depth=camera_depth,
                                       mount="gripper" if cam == "wrist" else "world"))
        arrays[f"scene/cameras/{cam}/rgb"] = rng.integers(0, 255, (n_frames, 48, 64, 3), dtype=np.uint8)
        if camera_depth:
            arrays[f"scene/cameras/{cam}/depth_m"] = rng.uniform(0.2, 2.0, (n_frames, 48, 64)).astype(np.float32)
    for obj in objects:
        arrays[f"scene/objects/{obj}/pose"] = ee.copy()
    max_depth = max(float(arrays[f"tactile/{p}/depth_um"].max()) for p in ("left", "right")) / 1000
    meta = EpisodeMeta(
        episode_id=episode_id, kind=kind, name=name, sensor=sensor, seed=seed,  # type: ignore[arg-type]
        generator=GeneratorInfo(name="tests.factories", version="0", settings={"n_frames": n_frames}),
        success=None if kind == "indenter" else True,
        safety=SafetySummary(max_indentation_mm=max_depth, max_slip_mm=0.0,
                             max_normal_force_n=float(max(arrays[f"tactile/{p}/normal_force_n"].max()
                                                          for p in ("left", "right")))),
        nominal_rate_hz=rate_hz, n_frames=n_frames, cameras=camera_infos, objects=list(objects),
        tactile_object=objects[0] if objects else None, primitive_names=["grasp", "rotate"],
    )
    return Episode(meta=meta, arrays=arrays)


def make_dataset(root: Path | str, storage: str = "hdf5", n_episodes: int = 2, *, sensor: str = "gelsight_mini",
                 n_frames: int = 4, cameras: tuple[str, ...] = (), **kwargs: object) -> Path:
    """A dataset of ``n_episodes`` episodes (ids ep0, ep1, ...) at ``root``; returns ``root``."""
    writer = DatasetWriter.open(root, storage=storage, sensors=[sensor])
    for k in range(n_episodes):
        writer.add(make_episode(sensor, n_frames, f"ep{k}", seed=k, cameras=cameras, **kwargs))  # type: ignore[arg-type]
    return Path(root)


if __name__ == "__main__":
    # `python tests/factories.py OUT [hdf5|zarr]`: a small synthetic dataset to try the CLI on.
    import sys

    out = make_dataset(sys.argv[1], sys.argv[2] if len(sys.argv) > 2 else "hdf5", 4, n_frames=30, cameras=("head",))
    print(f"wrote a synthetic 4-episode dataset to {out}")


IMAGE_KEYS = ("marked_rgb", "pure_rgb")


def has_hwc_memory(image: torch.Tensor) -> bool:
    """Whether a (..., 3, H, W) image is a view of contiguous (..., H, W, 3) memory (``torch.channels_last``)."""
    return image.movedim(-3, -1).is_contiguous()


def assert_same(a: Any, b: Any, *, channels_last: bool = False, key: str = "") -> None:
    """Equal keys, types, dtypes, shapes and values, bit for bit. Every tensor of ``a`` is contiguous, except
    images (``marked_rgb``, ``pure_rgb``) with ``channels_last``: views of HWC memory instead."""
    assert type(a) is type(b)
    if isinstance(a, dict):
        assert list(a) == list(b)
        for k in a:
            assert_same(a[k], b[k], channels_last=channels_last, key=k)
    elif isinstance(a, torch.Tensor):
        assert a.dtype == b.dtype and a.shape == b.shape and torch.equal(a, b), key
        hwc = channels_last and key in IMAGE_KEYS
        assert has_hwc_memory(a) if hwc else a.is_contiguous(), (key, tuple(a.shape), a.stride())
    elif isinstance(a, list):
        assert len(a) == len(b)
        for x, y in zip(a, b):
            assert_same(x, y, channels_last=channels_last, key=key)
    else:
        assert a == b


def stored_blosc_levels(episode_path) -> set[int]:
    """The Blosc levels an episode's compressed arrays were written at, as the file records them."""
    if str(episode_path).endswith(".h5"):
        levels: set[int] = set()

        def visit(_name: str, node: object) -> None:
            if isinstance(node, h5py.Dataset):
                plist = node.id.get_create_plist()
                for i in range(plist.get_nfilters()):
                    code, _flags, values, _name = plist.get_filter(i)
                    if code == 32001:  # Blosc; its level is cd_values[4]
                        levels.add(int(values[4]))

        with h5py.File(episode_path, "r") as f:
            f.visititems(visit)
        return levels

    def walk(node: object):
        if isinstance(node, dict):
            if "clevel" in node:
                yield int(node["clevel"])
            for value in node.values():
                yield from walk(value)
        elif isinstance(node, list):
            for value in node:
                yield from walk(value)

    return {level for meta in episode_path.rglob("zarr.json") for level in walk(json.loads(meta.read_text()))}

