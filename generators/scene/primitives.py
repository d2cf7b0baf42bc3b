"""Atomic primitives: Grasp (closed loop), Move, Rotate, Probe, Release, Place, and an open-loop squeeze.

Each primitive drives a ``GripperSim`` through ``sim.tick()`` and marks the frames it records with its name.
Tasks and the indenter corpus are scripts of these calls; corrections are scripts too.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from univtac_data.generators.scene.geometry import quat_from_axis_angle, quat_mul, quat_to_mat
from univtac_data.generators.scene.gripper import PADS, opening_to_finger_pos
from univtac_data.generators.scene.sim import GripperSim

PRIMITIVE_NAMES = ["grasp", "hold", "move", "rotate", "probe", "release", "place", "squeeze"]


@dataclass(frozen=True)
class GraspParams:
    """The paper's closed-loop grasp law, per finger, with the speeds of UniVTAC's code scaled to m/s.

    Each control tick a finger closes by ``v_fast * dt`` while its pad is farther than ``approach_margin_mm``
    from the object, then by ``min(gain * |d - threshold|, v_slow * dt)`` toward the threshold (opening again if
    past it), where d is the pad's current indentation. Never an open-loop squeeze.
    """

    threshold_mm: float  # target indentation delta_th, mm
    v_fast_m_s: float = 0.06  # UniVTAC: 0.5 mm per physics step at 120 Hz
    v_slow_m_s: float = 0.006  # UniVTAC: 0.05 mm per physics step
    approach_margin_mm: float = 0.5  # where the fast phase ends (the rigid pad sees the gap before touching)
    tolerance_mm: float = 0.02  # |d - threshold| counted as reached
    # Fraction of the depth error corrected per control tick. UniVTAC steps a kinematic joint by the whole
    # error; our finger is a servo that takes a few ticks to follow, and a whole-error step makes it hunt.
    gain_per_tick: float = 0.25
    # How far a finger's set-point may run ahead of the finger, m. Before contact a finger slowed by its
    # force limit would otherwise let the set-point race past the object and land with an open-loop squeeze.
    # In contact the lead is the squeeze itself (servo force = kp x lead) and grows only at v_slow: MuJoCo
    # gives every contact point its own stiffness, so a ring of twelve capsules needs twelve times the force.
    max_lead_free_m: float = 0.0002
    max_lead_contact_m: float = 0.002
    settle_s: float = 0.05  # reached for this long ends the grasp
    timeout_s: float = 3.0


@dataclass(frozen=True)
class GraspOutcome:
    reached: bool
    indentation_mm: dict[str, float]
    time_s: float


def _finger_step(params: GraspParams, gap_mm: float, dt_s: float, fast_allowed: bool) -> float:
    """Closing increment of one finger set-point for one tick, m (negative opens)."""
    if gap_mm > params.approach_margin_mm and fast_allowed:
        return params.v_fast_m_s * dt_s
    if gap_mm > 0.0:
        return params.v_slow_m_s * dt_s
    error_m = (params.threshold_mm - (-gap_mm)) / 1000.0
    return math.copysign(min(params.gain_per_tick * abs(error_m), params.v_slow_m_s * dt_s), error_m)


def grip_regulator(params: GraspParams, fast_allowed: bool = False) -> Callable[[GripperSim], None]:
    """A per-tick controller that keeps each pad's indentation at the threshold (used while holding)."""

    def regulate(sim: GripperSim) -> None:
        gaps = sim.gap_mm()
        actual = sim.finger_positions_m()
        for k, pad in enumerate(PADS):
            wanted = sim.finger_setpoints_m[k] + _finger_step(params, gaps[pad], sim.dt_s, fast_allowed)
            lead = params.max_lead_contact_m if gaps[pad] <= 0.0 else params.max_lead_free_m
            sim.finger_setpoints_m[k] = min(max(wanted, actual[k] - lead), actual[k] + lead)

    return regulate


def grasp(sim: GripperSim, params: GraspParams, *, hold: bool = True) -> GraspOutcome:
    """Close until both pads indent by ``params.threshold_mm``; keep regulating afterwards if ``hold``."""
    sim.set_primitive("grasp")
    sim.grip_regulator = grip_regulator(params, fast_allowed=True)
    start, reached_since = sim.time_s, None
    gaps = sim.gap_mm()
    while sim.time_s - start < params.timeout_s:
        sim.tick()
        gaps = sim.gap_mm()
        ok = all(abs(-gaps[p] - params.threshold_mm) <= params.tolerance_mm for p in PADS)
        reached_since = (reached_since if reached_since is not None else sim.time_s) if ok else None
        if reached_since is not None and sim.time_s - reached_since >= params.settle_s:
            break
    sim.grip_regulator = grip_regulator(params) if hold else None
    return GraspOutcome(reached_since is not None, {p: max(0.0, -gaps[p]) for p in PADS}, sim.time_s - start)


def hold(sim: GripperSim, duration_s: float) -> None:
    """Keep the current set-points (and the grip regulator, if any) for ``duration_s``."""
    sim.set_primitive("hold")
    end = sim.time_s + duration_s
    while sim.time_s < end:
        sim.tick()


def move(sim: GripperSim, delta_m: np.ndarray | tuple[float, float, float], speed_m_s: float = 0.02, *,
         frame: str = "world") -> None:
    """Translate the end effector by ``delta_m`` (world or gripper frame) at ``speed_m_s``."""
    sim.set_primitive("move")
    delta = np.asarray(delta_m, float)
    if frame == "gripper":
        delta = quat_to_mat(sim.ee_setpoint[3:]) @ delta
    start = sim.ee_setpoint[:3].copy()
    n = max(1, math.ceil(np.linalg.norm(delta) / (speed_m_s * sim.dt_s)))
    for k in range(1, n + 1):
        sim.ee_setpoint[:3] = start + delta * k / n
        sim.tick()


def rotate(sim: GripperSim, axis_gripper: tuple[float, float, float], angle_rad: float,
           speed_rad_s: float = 0.5, max_substep_rad: float = 0.2, pause_s: float = 0.02) -> None:
    """Rotate the end effector about an axis of the gripper frame through its origin (between the pads),
    in sub-steps of at most ``max_substep_rad`` with a short pause after each (UniVTAC's pattern)."""
    sim.set_primitive("rotate")
    substeps = max(1, math.ceil(abs(angle_rad) / max_substep_rad))
    for _ in range(substeps):
        part = angle_rad / substeps
        start = sim.ee_setpoint[3:].copy()
        n = max(1, math.ceil(abs(part) / (speed_rad_s * sim.dt_s)))
        for k in range(1, n + 1):
            sim.ee_setpoint[3:] = quat_mul(start, quat_from_axis_angle(axis_gripper, part * k / n))
            sim.tick()
        end = sim.time_s + pause_s
        while sim.time_s < end:
            sim.tick()


def probe(sim: GripperSim, direction_gripper: tuple[float, float, float], *, contact_mm: float = 0.05,
          speed_m_s: float = 0.005, max_travel_m: float = 0.02, back_off_m: float = 0.002) -> bool:
    """Move along a gripper-frame direction until a pad indents by ``contact_mm``, then back off.
    Returns whether contact was found within ``max_travel_m``."""
    sim.set_primitive("probe")
    direction = quat_to_mat(sim.ee_setpoint[3:]) @ (np.asarray(direction_gripper, float) /
                                                     np.linalg.norm(direction_gripper))
    start, found = sim.ee_setpoint[:3].copy(), False
    step = speed_m_s * sim.dt_s
    travelled = 0.0
    while travelled < max_travel_m:
        travelled += step
        sim.ee_setpoint[:3] = start + direction * travelled
        sim.tick()
        if max(-g for g in sim.gap_mm().values()) >= contact_mm:
            found = True
            break
    target = sim.ee_setpoint[:3] - direction * back_off_m
    n = max(1, math.ceil(back_off_m / step))
    begin = sim.ee_setpoint[:3].copy()
    for k in range(1, n + 1):
        sim.ee_setpoint[:3] = begin + (target - begin) * k / n
        sim.tick()
    return found


def release(sim: GripperSim, opening_m: float, speed_m_s: float = 0.06) -> None:
    """Stop regulating the grip and open the fingers to ``opening_m`` at ``speed_m_s``."""
    sim.set_primitive("release")
    sim.grip_regulator = None
    start = sim.finger_setpoints_m.copy()
    target_finger = opening_to_finger_pos(opening_m)
    n = max(1, math.ceil(np.max(np.abs(start - target_finger)) / (speed_m_s * sim.dt_s)))
    for k in range(1, n + 1):
        sim.finger_setpoints_m[:] = start + (target_finger - start) * k / n
        sim.tick()


def place(sim: GripperSim, delta_m: tuple[float, float, float], opening_m: float, speed_m_s: float = 0.02) -> None:
    """Carry the held object by ``delta_m`` (world) and let go: a Move, then a Release."""
    move(sim, delta_m, speed_m_s)
    sim.set_primitive("place")
    release(sim, opening_m)


def squeeze_open_loop(sim: GripperSim, opening_m: float, duration_s: float) -> None:
    """Command a fixed gel-to-gel distance with no tactile feedback (the stability study's counter-example)."""
    sim.set_primitive("squeeze")
    sim.grip_regulator = None
    sim.set_opening(opening_m)
    end = sim.time_s + duration_s
    while sim.time_s < end:
        sim.tick()
