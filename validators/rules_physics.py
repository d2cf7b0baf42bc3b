"""Physical invariants of values and motion: finite numbers, unit quaternions, continuous poses, regular
timestamps, and no kinetic energy out of nowhere.

These rules ignore non-finite values (``physics.finite`` reports them once) and use the recorded frame
intervals where the timestamps increase, the nominal 1 / rate elsewhere.
"""

from __future__ import annotations

import numpy as np

from univtac_data.validators.context import EpisodeContext
from univtac_data.validators.poses import angular_speeds_rad_s, linear_speeds_m_s, quaternion_norm_error
from univtac_data.validators.registry import Skip, collect, frame_finding, rule
from univtac_data.validators.report import Finding

POSE_FIELDS = ("robot/ee_pose", "scene/objects/{object}/pose", "tactile/{pad}/object_pose", "tactile/{pad}/pad_pose")


@rule("physics.finite", "physics")
def finite(ctx: EpisodeContext) -> list[Finding]:
    """Every float array holds finite values only (no NaN, no +-inf)."""
    out = []
    for path, array in sorted(ctx.arrays.items()):
        if not np.issubdtype(array.dtype, np.floating):
            continue
        state = ctx.fields[path]
        if state.spec is not None and state.spec.sampling == "per_episode":
            n_bad = int((~np.isfinite(array)).sum())
            if n_bad:
                out.append(Finding(message=f"{path}: {n_bad} non-finite value(s)", field=path))
            continue
        bad_values = ~np.isfinite(array.reshape(array.shape[0], -1))
        first_bad = np.where(bad_values.any(axis=1), array.reshape(array.shape[0], -1)[
            np.arange(array.shape[0]), bad_values.argmax(axis=1)].astype(np.float64), 0.0)
        out.append(frame_finding(path, bad_values.any(axis=1), first_bad, "hold non-finite values",
                                 ctx.config.max_listed_frames))
    for camera in ctx.meta.cameras:
        key = f"camera/{camera.name}/depth_nonfinite_px"
        if key in ctx.summaries:
            counts = ctx.summaries[key]
            out.append(frame_finding(f"scene/cameras/{camera.name}/depth_m", counts > 0, counts,
                                     "hold non-finite pixels (value: how many)", ctx.config.max_listed_frames))
    return collect(out)


def _quaternions(ctx: EpisodeContext) -> list[tuple[str, np.ndarray]]:
    out = [(path, ctx.arrays[path][:, 3:7]) for pattern in POSE_FIELDS for path in ctx.paths_like(pattern)]
    if "robot/action" in ctx.arrays:
        out.append(("robot/action[:, 3:7]", ctx.arrays["robot/action"][:, 3:7]))
    return out


@rule("physics.quaternion_norm", "physics", threshold="quaternion_norm_tolerance")
def quaternion_norm(ctx: EpisodeContext) -> list[Finding]:
    """Every pose and action quaternion has unit norm within quaternion_norm_tolerance."""
    tol = ctx.config.quaternion_norm_tolerance
    return collect([frame_finding(path, error > tol, error, f"have | |q| - 1 | above {tol}",
                                  ctx.config.max_listed_frames)
                    for path, q in _quaternions(ctx) for error in [quaternion_norm_error(q)]])


@rule("physics.pose_continuity", "physics", threshold="max_linear_speed_m_s")
def pose_continuity(ctx: EpisodeContext) -> list[Finding]:
    """No pose moves faster than max_linear_speed_m_s or turns faster than max_angular_speed_rad_s between two
    frames (no teleports)."""
    cfg, dt, out = ctx.config, ctx.intervals_s(), []
    for pattern in POSE_FIELDS:
        for path in ctx.paths_like(pattern):
            pose = ctx.arrays[path]
            speed = linear_speeds_m_s(pose, dt)
            turn = angular_speeds_rad_s(pose, dt)
            out.append(frame_finding(f"{path}[:, :3]", speed > cfg.max_linear_speed_m_s, speed,
                                     f"reached after moving faster than {cfg.max_linear_speed_m_s} m/s",
                                     cfg.max_listed_frames, frame_offset=1, unit="m/s"))
            out.append(frame_finding(f"{path}[:, 3:7]", turn > cfg.max_angular_speed_rad_s, turn,
                                     f"reached after turning faster than {cfg.max_angular_speed_rad_s} rad/s",
                                     cfg.max_listed_frames, frame_offset=1, unit="rad/s"))
    return collect(out)


@rule("physics.timestamps", "physics", threshold="timestamp_tolerance_fraction")
def timestamps(ctx: EpisodeContext) -> list[Finding]:
    """timestamps_ns start at or after 0, increase strictly, and every interval is 1e9 / nominal_rate_hz ns
    within timestamp_tolerance_fraction (no dropped or doubled frames)."""
    stamps = ctx.array("timestamps_ns").astype(np.int64)
    period_ns = 1e9 / ctx.meta.nominal_rate_hz
    tol = ctx.config.timestamp_tolerance_fraction
    out = []
    if stamps.size and stamps[0] < 0:
        out.append(Finding(message=f"timestamps_ns: first timestamp is {int(stamps[0])} ns, expected >= 0",
                           field="timestamps_ns", frames=[0], values=[float(stamps[0])], n_frames=1))
    diffs = np.diff(stamps).astype(np.float64)
    out.append(frame_finding("timestamps_ns", diffs <= 0, diffs, "not after the previous frame (interval in ns)",
                             ctx.config.max_listed_frames, frame_offset=1, unit="ns"))
    off = (diffs > 0) & (np.abs(diffs - period_ns) > tol * period_ns)
    out.append(frame_finding("timestamps_ns", off, diffs,
                             f"at an interval off the nominal {period_ns:.0f} ns by more than {tol:.0%}",
                             ctx.config.max_listed_frames, frame_offset=1, unit="ns"))
    return collect(out)


def speed_budget_m_s(ctx: EpisodeContext, path: str, speeds: dict[str, np.ndarray]) -> np.ndarray:
    """(T-2,) the most speed object ``path`` may have over intervals 1..T-2, m/s: what it had, plus gravity;
    or contact_speed_factor times the fastest pusher around (the gripper's contact point or another object)."""
    cfg, dt = ctx.config, ctx.intervals_s()
    ee = ctx.array("robot/ee_pose").astype(np.float64)
    pose = ctx.arrays[path].astype(np.float64)
    lever = np.minimum(np.linalg.norm(pose[:-1, :3] - ee[:-1, :3], axis=1), cfg.lever_arm_max_m)
    contact = linear_speeds_m_s(ee, dt) + angular_speeds_rad_s(ee, dt) * lever
    others = [s for p, s in speeds.items() if p != path]
    if others:
        contact = np.maximum(contact, np.max(others, axis=0))
    pusher = np.maximum(contact[:-1], contact[1:])
    own = speeds[path]
    gained = own[:-1] + cfg.gravity_m_s2 * np.maximum(dt[:-1], dt[1:])
    return np.maximum(gained, cfg.contact_speed_factor * pusher) + cfg.speed_tolerance_m_s


@rule("physics.kinetic_energy", "physics", threshold="speed_tolerance_m_s")
def kinetic_energy(ctx: EpisodeContext) -> list[Finding]:
    """No scene object gains speed (kinetic energy) that gravity, the gripper's motion or another object's
    motion cannot explain: speed <= max(previous + g dt, contact_speed_factor x pusher) + speed_tolerance_m_s."""
    objects = ctx.paths_like("scene/objects/{object}/pose")
    if not objects:
        raise Skip("no scene object poses")
    ctx.array("robot/ee_pose")
    if ctx.n_frames < 3:
        return []
    dt = ctx.intervals_s()
    speeds = {path: linear_speeds_m_s(ctx.arrays[path], dt) for path in objects}
    out = []
    for path in objects:
        budget = speed_budget_m_s(ctx, path, speeds)
        own = speeds[path][1:]
        out.append(frame_finding(f"{path}[:, :3]", own > budget, own,
                                 "reached at a speed no recorded work explains (energy injected)",
                                 ctx.config.max_listed_frames, limits=budget, frame_offset=2, unit="m/s"))
    return collect(out)
