"""Scene cameras: RGB images of named MJCF cameras, rendered only when a frame is recorded or observed.

MuJoCo renders through OpenGL; on a machine without a GPU that is software EGL (``MUJOCO_GL=egl``), about
5-8 ms a frame at 480 x 270 in the task scenes, which turn multisampling off (15-20 ms with MuJoCo's default
4x). One ``mujoco.Renderer`` is made per image size and reused for every camera
of that size: making one costs far more than a frame. Images are written straight into the caller's
buffer (a row of the episode's array).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Literal

import mujoco
import numpy as np

from univtac_data.schema.models import CameraInfo

DEFAULT_CAMERA_SIZE = (480, 270)  # width, height in px: UniVTAC's cameras


@dataclass(frozen=True)
class CameraSpec:
    """A camera of a scene: its MJCF name, how it is mounted, and the image size (px)."""

    name: str  # 'head' (third person, fixed in the world) or 'wrist' (carried by the gripper)
    mount: Literal["world", "gripper"]
    width_px: int = DEFAULT_CAMERA_SIZE[0]
    height_px: int = DEFAULT_CAMERA_SIZE[1]

    def info(self, model: mujoco.MjModel) -> CameraInfo:
        """The format's ``CameraInfo`` (field of view read from the model)."""
        fovy = float(model.cam_fovy[model.camera(self.name).id])
        return CameraInfo(name=self.name, width_px=self.width_px, height_px=self.height_px, fovy_deg=fovy,
                          depth=False, mount=self.mount)


def ensure_gl_backend() -> None:
    """Default MuJoCo to EGL (headless, no display needed) unless the user chose a backend."""
    os.environ.setdefault("MUJOCO_GL", "egl")


class CameraRig:
    """Renders a scene's cameras. Owns one renderer per image size; ``close()`` frees them."""

    def __init__(self, model: mujoco.MjModel, cameras: list[CameraSpec]) -> None:
        ensure_gl_backend()
        self.model = model
        self.cameras = list(cameras)
        for cam in self.cameras:
            if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, cam.name) < 0:
                raise KeyError(f"the scene has no camera named {cam.name!r}")
        needed_w = max((c.width_px for c in self.cameras), default=1)
        needed_h = max((c.height_px for c in self.cameras), default=1)
        # the offscreen buffer must hold the largest image: grow it in the model if the scene's is smaller
        model.vis.global_.offwidth = max(int(model.vis.global_.offwidth), needed_w)
        model.vis.global_.offheight = max(int(model.vis.global_.offheight), needed_h)
        self._renderers: dict[tuple[int, int], mujoco.Renderer] = {}

    def _renderer(self, cam: CameraSpec) -> mujoco.Renderer:
        key = (cam.height_px, cam.width_px)
        if key not in self._renderers:
            self._renderers[key] = mujoco.Renderer(self.model, height=cam.height_px, width=cam.width_px)
        return self._renderers[key]

    def render(self, data: mujoco.MjData, cam: CameraSpec, out: np.ndarray | None = None) -> np.ndarray:
        """(h, w, 3) uint8 RGB of ``cam`` at the current ``data`` (after ``mj_forward`` or a step)."""
        renderer = self._renderer(cam)
        renderer.update_scene(data, camera=cam.name)
        return renderer.render(out=out)

    def close(self) -> None:
        for renderer in self._renderers.values():
            renderer.close()
        self._renderers.clear()


def look_at_xyaxes(eye: tuple[float, float, float], target: tuple[float, float, float]) -> str:
    """MJCF ``xyaxes`` of a camera at ``eye`` looking at ``target`` (world z up), for scene builders."""
    forward = np.subtract(target, eye, dtype=float)
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, (0.0, 0.0, 1.0))
    if np.linalg.norm(right) < 1e-9:
        right = np.array([1.0, 0.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    return " ".join(f"{v:.6f}" for v in (*right, *up))


def fovy_for_hfov(hfov_deg: float, width_px: int, height_px: int) -> float:
    """Vertical field of view (deg) that gives ``hfov_deg`` horizontally at this aspect ratio."""
    half = math.radians(hfov_deg) / 2
    return math.degrees(2 * math.atan(math.tan(half) * height_px / width_px))


__all__ = ["DEFAULT_CAMERA_SIZE", "CameraRig", "CameraSpec", "ensure_gl_backend", "fovy_for_hfov", "look_at_xyaxes"]
