"""``TaskEnv``: a benchmark task as a Gymnasium environment (the LeRobot gym convention for observations).

Observation (a dict)
    ``pixels``: dict of (H, W, 3) uint8 RGB images: ``head`` and ``wrist`` (the scene cameras, unless made
    with ``cameras=False``), ``tactile_left`` and ``tactile_right`` (each pad's marked tactile image).
    ``agent_pos``: (8,) float32, the end-effector pose in the world (x, y, z m; quaternion w, x, y, z) and the
    gripper opening (gel to gel, m).
    With ``tactile_extras=True`` also ``tactile``: per pad ``{pad}_depth_mm`` (H, W) float32 mm,
    ``{pad}_markers_px`` (N, 2) float32 px, ``{pad}_force_n`` (3,) float32 N (normal, shear x, shear y).
Action
    ``action_mode="absolute"`` (default): (8,) float32, the end-effector target in the world frame (x, y, z m;
    quaternion w, x, y, z, normalised by the environment) and the opening (m), bounded by the workspace box
    (x, y in [-0.5, 0.5] m, z in [0, 0.6] m) and [0, 0.08] m. ``"delta"``: (7,) float32, a world-frame
    displacement (m, at most 2 cm a step), a rotation vector (rad, at most 0.2 rad a step) and an opening change
    (m, at most 1 cm a step), applied to the last target.
Rate
    ``rate_hz`` policy steps a second (default 50 Hz; one step must be a whole number of 2 ms control ticks).
Reward, termination
    reward 1.0 on the step success first holds, else 0.0; ``terminated`` when the task succeeds or a tactile
    safety rule is broken (``info["safety"]`` says which); ``truncated`` at the task's step limit, which is a
    time limit (``Task.step_limit``: ``max_steps`` at 50 Hz, 150 steps for 300 at 25 Hz), the same that
    ``generate`` and ``evaluate`` use. ``gym.make`` also wraps the registration's TimeLimit of ``max_steps``
    steps, which is the same at 50 Hz and longer at lower rates; above 50 Hz pass ``max_episode_steps``. ``info["is_success"]``: success now; ``info["safety"]``: {"ok", "reason", "max_indentation_mm",
    "max_in_hand_slip_mm"}.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from univtac_data.generators.scene.geometry import quat_from_axis_angle, quat_mul
from univtac_data.generators.scene.gripper import MAX_OPENING_M, PADS
from univtac_data.generators.tasks.base import TaskConfig
from univtac_data.generators.tasks.registry import make_task
from univtac_data.generators.tasks.session import ActionBounds, TaskSession

DELTA_LIMITS = np.array([0.02, 0.02, 0.02, 0.2, 0.2, 0.2, 0.01], np.float32)


class TaskEnv(gym.Env[dict[str, Any], np.ndarray]):
    """A registered task (``univtac_data.generators.tasks.registry``) as a Gymnasium environment."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 50}

    def __init__(self, task: str, *, sensor: str = "gelsight_mini", contact: str = "geometric",
                 cameras: bool = True, camera_size: tuple[int, int] = (480, 270), action_mode: str = "absolute",
                 tactile_extras: bool = False, render_mode: str | None = "rgb_array",
                 rate_hz: float = TaskConfig.rate_hz) -> None:
        if action_mode not in ("absolute", "delta"):
            raise ValueError(f"action_mode must be 'absolute' or 'delta' (got {action_mode!r})")
        self.config = TaskConfig(sensor=sensor, contact_method=contact, cameras=cameras,  # type: ignore[arg-type]
                                 camera_size=camera_size, rate_hz=rate_hz)
        self.task = make_task(task, self.config)
        self.session = TaskSession(self.task, record=True)
        self.action_mode = action_mode
        self.tactile_extras = tactile_extras
        self.render_mode = render_mode
        self.metadata = {**self.metadata, "render_fps": int(self.config.rate_hz)}
        bounds = ActionBounds.default()
        if action_mode == "absolute":
            self.action_space = spaces.Box(bounds.low, bounds.high, dtype=np.float32)
        else:
            self.action_space = spaces.Box(-DELTA_LIMITS, DELTA_LIMITS, dtype=np.float32)
        profile = self.task.profile
        pixels = {cam.name: spaces.Box(0, 255, (cam.height_px, cam.width_px, 3), np.uint8) for cam in self.task.cameras()}
        for pad in PADS:
            pixels[f"tactile_{pad}"] = spaces.Box(0, 255, (profile.image_height_px, profile.image_width_px, 3), np.uint8)
        obs: dict[str, spaces.Space[Any]] = {
            "pixels": spaces.Dict(pixels),
            # positions within 2 m of the world origin, unit-quaternion components, opening 0-0.1 m
            "agent_pos": spaces.Box(np.array([-2.0] * 3 + [-1.0] * 4 + [0.0], np.float32),
                                    np.array([2.0] * 3 + [1.0] * 4 + [0.1], np.float32), dtype=np.float32),
        }
        if tactile_extras:
            extra: dict[str, spaces.Space[Any]] = {}
            for pad in PADS:
                h, w = profile.image_height_px, profile.image_width_px
                extra[f"{pad}_depth_mm"] = spaces.Box(0.0, 65.535, (h, w), np.float32)  # uint16 um
                extra[f"{pad}_markers_px"] = spaces.Box(-float(w), 2.0 * w, (profile.n_markers, 2), np.float32)
                extra[f"{pad}_force_n"] = spaces.Box(-1000.0, 1000.0, (3,), np.float32)
            obs["tactile"] = spaces.Dict(extra)
        self.observation_space = spaces.Dict(obs)
        self._succeeded = False

    # --- gymnasium API -------------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[dict[str, Any], dict[str, Any]]:
        super().reset(seed=seed)
        if seed is None:
            seed = int(self.np_random.integers(0, 2**31 - 1))
        self.session.reset(seed)
        self._succeeded = False
        state = self.session.state()
        return self._observation(), self._info(self.task.success(state))

    def step(self, action: np.ndarray) -> tuple[dict[str, Any], float, bool, bool, dict[str, Any]]:
        target = self.session.bounds.check(self._absolute(np.asarray(action, dtype=np.float64)))
        sim = self.session.sim
        assert sim is not None
        sim.forget_frames()  # only the newest observation is kept
        state = self.session.step(target)
        success = self.task.success(state)
        reward = 1.0 if success and not self._succeeded else 0.0
        self._succeeded |= success
        safe = self.session.safety_log[-1].ok
        truncated = self.session.steps >= self.task.step_limit
        return self._observation(), reward, bool(success or not safe), truncated, self._info(success)

    def render(self) -> np.ndarray:
        """(H, W, 3) uint8: the head camera (or, without cameras, the left tactile image)."""
        pixels = self._observation()["pixels"]
        return pixels.get("head", pixels["tactile_left"])

    def close(self) -> None:
        self.session.close()

    # --- helpers -------------------------------------------------------------------------------------
    def _absolute(self, action: np.ndarray) -> np.ndarray:
        if self.action_mode == "absolute":
            return action
        if action.shape != (7,) or not np.isfinite(action).all():
            raise ValueError(f"a delta action is 7 finite numbers (dx, dy, dz m; rx, ry, rz rad; dwidth m), got {action!r}")
        delta = np.clip(action, -DELTA_LIMITS, DELTA_LIMITS)
        target = self.session.last_action.copy()
        target[:3] += delta[:3]
        angle = float(np.linalg.norm(delta[3:6]))
        if angle > 1e-9:
            target[3:7] = quat_mul(quat_from_axis_angle(delta[3:6], angle), target[3:7])
        target[7] = float(np.clip(target[7] + delta[6], 0.0, MAX_OPENING_M))
        return target

    def _observation(self) -> dict[str, Any]:
        sim = self.session.sim
        assert sim is not None
        pixels = {cam.name: sim.pixels[f"scene/cameras/{cam.name}/rgb"].array()[-1].copy() for cam in sim.camera_specs}
        for pad in PADS:
            pixels[f"tactile_{pad}"] = sim.pixels[f"tactile/{pad}/marked_rgb"].array()[-1].copy()
        frame = sim.frames[-1]
        agent = np.concatenate([frame.ee_pose, [frame.opening_m]]).astype(np.float32)
        obs: dict[str, Any] = {"pixels": pixels, "agent_pos": agent}
        if self.tactile_extras:
            extra = {}
            for pad in PADS:
                rec = frame.tactile[pad]
                extra[f"{pad}_depth_mm"] = sim.pixels[f"tactile/{pad}/depth_um"].array()[-1].astype(np.float32) / 1000.0
                extra[f"{pad}_markers_px"] = rec.markers_px.astype(np.float32)
                extra[f"{pad}_force_n"] = np.array([rec.normal_force_n, *rec.shear_force_n], np.float32)
            obs["tactile"] = extra
        return obs

    def _info(self, success: bool) -> dict[str, Any]:
        check = self.session.safety_log[-1]
        return {"is_success": bool(success), "safety": {
            "ok": check.ok, "reason": check.reason, "max_indentation_mm": self.session.max_indentation_mm,
            "max_in_hand_slip_mm": self.session.max_in_hand_slip_mm}}
