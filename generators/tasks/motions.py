"""Step-level primitives for experts: generators that yield one ``Step`` per policy step.

The scene primitives (``scene.primitives``) drive the simulation tick by tick for the indenter corpus; a
task's expert is a policy, so its primitives emit actions, one per step, and read the sensors between
them. Each starts from ``ctx.target`` (the last action), so primitives chain without jumps. Speeds are
limits in m/s and rad/s, turned into whole steps.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from univtac_data.generators.scene.geometry import quat_from_axis_angle, quat_mul, quat_to_mat, slerp
from univtac_data.generators.scene.gripper import MAX_OPENING_M, MIN_OPENING_M
from univtac_data.generators.tasks.base import ExpertContext, Step
from univtac_data.schema.sensors import SensorProfile


def steps_for(ctx: ExpertContext, distance: float, speed: float) -> int:
    return max(1, math.ceil(abs(distance) / (speed * ctx.dt_s)))


def move_to(ctx: ExpertContext, pos: np.ndarray | None = None, quat: np.ndarray | None = None, *,
            width: float | None = None, speed_m_s: float = 0.10, turn_rad_s: float = 1.5,
            primitive: str = "move") -> Iterator[Step]:
    """A straight line to ``pos`` (m, world) while turning to ``quat`` and opening to ``width`` (m)."""
    start = ctx.target.copy()
    goal = start.copy()
    if pos is not None:
        goal[:3] = pos
    if quat is not None:
        q = np.asarray(quat, float)
        goal[3:7] = q if np.dot(q, start[3:7]) >= 0 else -q
    if width is not None:
        goal[7] = width
    angle = 2 * math.acos(min(1.0, abs(float(np.dot(start[3:7], goal[3:7])))))
    n = max(steps_for(ctx, float(np.linalg.norm(goal[:3] - start[:3])), speed_m_s),
            steps_for(ctx, angle, turn_rad_s), steps_for(ctx, goal[7] - start[7], 0.1))
    for k in range(1, n + 1):
        t = k / n
        action = start + (goal - start) * t
        action[3:7] = slerp(start[3:7], goal[3:7], t)
        yield ctx.step(primitive, action)


def rotate_about(ctx: ExpertContext, axis_world: np.ndarray, angle_rad: float, pivot_m: np.ndarray | None = None,
                 *, turn_rad_s: float = 1.2, primitive: str = "rotate") -> Iterator[Step]:
    """Turn the gripper by ``angle_rad`` about a world axis through ``pivot_m`` (default: the gripper origin)."""
    start = ctx.target.copy()
    pivot = start[:3] if pivot_m is None else np.asarray(pivot_m, float)
    n = steps_for(ctx, angle_rad, turn_rad_s)
    for k in range(1, n + 1):
        turn = quat_from_axis_angle(axis_world, angle_rad * k / n)
        action = start.copy()
        action[:3] = pivot + quat_to_mat(turn) @ (start[:3] - pivot)
        action[3:7] = quat_mul(turn, start[3:7])
        yield ctx.step(primitive, action)


def wait(ctx: ExpertContext, seconds: float, primitive: str = "hold") -> Iterator[Step]:
    for _ in range(max(1, round(seconds / ctx.dt_s))):
        yield ctx.step(primitive, ctx.target)


def open_to(ctx: ExpertContext, width_m: float = MAX_OPENING_M, speed_m_s: float = 0.08,
            primitive: str = "release") -> Iterator[Step]:
    """Open (or close without feedback) to ``width_m`` at ``speed_m_s``."""
    start = ctx.target.copy()
    n = steps_for(ctx, width_m - start[7], speed_m_s)
    for k in range(1, n + 1):
        action = start.copy()
        action[7] = start[7] + (width_m - start[7]) * k / n
        yield ctx.step(primitive, action)


@dataclass(frozen=True)
class GraspLaw:
    """The paper's closed-loop grasp on the gripper opening (UniVTAC's speeds): close fast while both pads
    are farther than ``approach_margin_mm``, then slowly, until both indent by ``threshold_mm``; never an
    open-loop squeeze. Mass-produced grasps must not crush: the opening never runs more than
    ``max_lead_m`` ahead of the fingers."""

    threshold_mm: float
    v_fast_m_s: float = 0.06
    v_slow_m_s: float = 0.006
    approach_margin_mm: float = 0.5  # the fast phase ends this far from contact
    # in contact, per 20 ms step (50 Hz; close_until scales both by ``ctx.step_scale``, so that a grasp at 25 Hz
    # takes as long as at 50 Hz): the fraction of the depth error closed (the servo lags a little) and the
    # least closing, m (the gel's last tenths of a millimetre converge slowly)
    gain_per_step: float = 0.6
    min_closing_m: float = 2e-5
    max_lead_m: float = 0.0015
    timeout_s: float = 2.0


def grasp_depth_mm(profile: SensorProfile) -> float:
    """The indentation the task experts grasp to, mm: 0.5 on a gel whose safe limit is 1.5 mm (GelSight Mini,
    UniVTAC's target), 0.3 on the thinner gels safe to 0.8 mm (GF225, Xense WS)."""
    return 0.5 if profile.safe_indentation_mm >= 1.5 else 0.3


def held_opening_m(profile: SensorProfile, width_m: float) -> float:
    """The opening a set-up leaves the fingers at on an object ``width_m`` wide between the pads (m): its width
    less the kit's grasp depth (``grasp_depth_mm``) on each pad."""
    return width_m - 2 * grasp_depth_mm(profile) / 1000


def close_until(ctx: ExpertContext, law: GraspLaw, primitive: str = "grasp") -> Iterator[Step]:
    """Close on an object until both pads reach ``law.threshold_mm``; sets ``ctx.memory['grasped']``."""
    ctx.memory["grasped"] = False
    gain, least = min(0.9, law.gain_per_step * ctx.step_scale), law.min_closing_m * ctx.step_scale
    for _ in range(max(1, round(law.timeout_s / ctx.dt_s))):
        gaps = ctx.gap_mm()
        depth = {pad: max(0.0, -gap) for pad, gap in gaps.items()}
        if min(depth.values()) >= law.threshold_mm:
            ctx.memory["grasped"] = True
            return
        if min(gaps.values()) > law.approach_margin_mm:
            closing = law.v_fast_m_s * ctx.dt_s
        else:
            error_m = (law.threshold_mm - min(depth.values())) / 1000.0
            closing = min(law.v_slow_m_s * ctx.dt_s, max(gain * error_m, least)) if min(gaps.values()) <= 0 \
                else law.v_slow_m_s * ctx.dt_s
        action = ctx.target.copy()
        # never more than max_lead_m ahead of the fingers: the servo's squeeze stays what the law asked for
        action[7] = max(MIN_OPENING_M, action[7] - closing, ctx.opening_m() - law.max_lead_m)
        yield ctx.step(primitive, action)


__all__ = ["GraspLaw", "close_until", "grasp_depth_mm", "held_opening_m", "move_to", "open_to", "rotate_about", "steps_for", "wait"]
