"""Pull-out Key: the expert finds the release angle at the lock's end stop by touch on 100 seeds, without that
correction the key stays in the lock, the blade never passes through the face plate, and replay reproduces an
episode."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import pytest

from univtac_data.generators.scene.geometry import quat_to_mat
from univtac_data.generators.tasks.base import TaskConfig
from univtac_data.generators.tasks.expert_rollout import expert_rollout
from univtac_data.generators.tasks.collect import TaskEpisodeSpec, run_expert
from univtac_data.generators.tasks.pull_out_key import (
    BLADE_HALF_M,
    BLADE_TOP_M,
    FACE_Z_M,
    PLATE_T_M,
    SLOT_HALF_M,
    STOP_RAD,
    PullOutKey,
)
from univtac_data.generators.tasks.session import TaskSession
from univtac_data.schema.sensors import get_sensor

os.environ.setdefault("MUJOCO_GL", "egl")
FAST = TaskConfig(cameras=False)
PROFILE = get_sensor("gelsight_mini")
PENETRATION_TOLERANCE_M = 0.0002


@dataclass(frozen=True)
class Outcome:
    seed: int
    success: bool
    safe: bool
    violation: str | None
    steps: int
    corrections: list[dict[str, Any]]
    worst_plate_mm: float  # deepest a blade edge got into the face plate's solid part
    angle_at_pull_deg: float  # the key's angle from the release angle when the pull began
    max_indentation_mm: float


def plate_depth_m(angle_rad: float, rise_m: float) -> float:
    """How far the blade's vertical edges lie inside the face plate's solid part, m, for the key turned by
    ``angle_rad`` from the release angle and raised by ``rise_m``: while the blade spans the plate's
    thickness, its four edges must be inside the keyway; an edge outside it is inside the plate by the lesser
    of its distance out of the keyway and how far the blade's top has risen into the plate."""
    top, bottom = BLADE_TOP_M + rise_m, BLADE_TOP_M - 2 * BLADE_HALF_M[2] + rise_m
    if top <= -PLATE_T_M or bottom >= 0.0:
        return 0.0
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    worst = 0.0
    for sx in (-1, 1):
        for sy in (-1, 1):
            x, y = sx * BLADE_HALF_M[0], sy * BLADE_HALF_M[1]
            px, py = c * x - s * y, s * x + c * y
            outside = max(abs(px) - SLOT_HALF_M[0], abs(py) - SLOT_HALF_M[1])
            worst = max(worst, min(outside, top + PLATE_T_M))
    return max(0.0, worst)


def key_angle(pose: np.ndarray, lock_yaw: float) -> float:
    x_axis = quat_to_mat(pose[3:])[:, 0]
    return (math.atan2(x_axis[1], x_axis[0]) - lock_yaw + math.pi) % (2 * math.pi) - math.pi


def run(task: PullOutKey, seed: int, corrections: bool = True) -> Outcome:
    with expert_rollout(task, seed, corrections=corrections) as run:
        session, state = run.session, run.state
        lock_yaw = session.layout["lock_yaw_rad"]
        worst, at_pull = 0.0, math.nan
        for step in run.steps():
            if step.primitive == "pull" and math.isnan(at_pull):
                at_pull = math.degrees(key_angle(state.objects["key"], lock_yaw))
            state = run.take(step)
            pose = state.objects["key"]
            worst = max(worst, plate_depth_m(key_angle(pose, lock_yaw), pose[2] - FACE_Z_M))
        return Outcome(seed, task.success(state), session.safe, session.first_violation(), session.steps,
                       list(run.ctx.memory["corrections"]), worst * 1000, at_pull, session.max_indentation_mm)


@pytest.fixture(scope="module")
def outcomes() -> list[Outcome]:
    task = PullOutKey(FAST, PROFILE)
    return [run(task, seed) for seed in range(100)]


@pytest.mark.slow
def test_expert_pulls_the_key_on_100_seeds_safely_without_tunnelling(outcomes: list[Outcome]):
    successes = sum(o.success for o in outcomes)
    print(f"pull_out_key expert: success {successes}/100, steps max {max(o.steps for o in outcomes)}, key angle "
          f"at the pull {min(o.angle_at_pull_deg for o in outcomes):.1f}..{max(o.angle_at_pull_deg for o in outcomes):.1f}"
          f" deg, deepest into the plate {max(o.worst_plate_mm for o in outcomes):.3f} mm, deepest indentation "
          f"{max(o.max_indentation_mm for o in outcomes):.2f} mm")
    assert successes >= 90, [o.seed for o in outcomes if not o.success]
    assert all(o.safe for o in outcomes), [(o.seed, o.violation) for o in outcomes if not o.safe]
    assert max(o.steps for o in outcomes) <= PullOutKey.max_steps
    assert max(o.worst_plate_mm for o in outcomes) < PENETRATION_TOLERANCE_M * 1000
    # the correction leaves the key inside the keyway's window (+-3.7 deg) on the seeds that succeed
    assert all(abs(o.angle_at_pull_deg) < 3.7 for o in outcomes if o.success)


@pytest.mark.slow
def test_the_stop_is_felt_and_without_the_correction_the_key_stays_in(outcomes: list[Outcome]):
    for o in outcomes:
        assert len(o.corrections) == 1
        c = o.corrections[0]
        assert c["signal"].startswith("indentation rise on the pads") and c["rise_mm"] > 0.12
        assert c["turn_back_deg"] == pytest.approx(math.degrees(STOP_RAD) + c["overshoot_deg"], abs=1e-6)
        assert 0.0 < c["overshoot_deg"] < 5.0
    task = PullOutKey(FAST, PROFILE)
    without = [run(task, seed, corrections=False) for seed in range(30)]
    assert not any(o.corrections for o in without)
    # turned to the angle the camera sees, 5-10 deg off (less the grasp's own give): outside the keyway's window,
    # so the blade catches under the face plate
    outside = sum(abs(o.angle_at_pull_deg) > 3.7 for o in without)
    print(f"pull_out_key without the correction: key angle at the pull {sorted(round(o.angle_at_pull_deg, 1) for o in without)}")
    assert outside >= 0.8 * len(without), outside
    rate_without = sum(o.success for o in without) / len(without)
    print(f"pull_out_key on seeds 0-29: success {sum(o.success for o in outcomes[:30]) / 30:.0%} with the "
          f"correction, {rate_without:.0%} without")
    assert rate_without <= 0.1
    assert max(o.worst_plate_mm for o in without) < PENETRATION_TOLERANCE_M * 1000  # pulled hard, still no tunnel


def test_replay_reproduces_the_episode_and_its_labels():
    seed = 4
    outcome = run_expert(TaskEpisodeSpec("pull_out_key", seed, FAST))
    episode = outcome.episode
    assert outcome.success and outcome.safe and episode is not None and episode.meta.success
    names = episode.meta.primitive_names
    used = {names[i] for i in np.unique(episode["scene/primitive"]) if i >= 0}
    assert {"grasp", "turn", "correct", "pull"} <= used
    assert episode.meta.extra["task"]["memory"]["stop_felt"]
    task = PullOutKey(FAST, PROFILE)
    session = TaskSession(task)
    try:
        session.reset(seed)
        for action in episode["robot/action"][:-1]:
            state = session.step(action)
        assert task.success(state)
        final = episode["scene/objects/key/pose"][-1]
        assert np.linalg.norm(state.objects["key"][:3] - final[:3]) < 1e-4
    finally:
        session.close()


def test_success_needs_the_key_out_and_upright():
    task = PullOutKey(FAST, PROFILE)
    session = TaskSession(task)
    try:
        state = session.reset(2)
        assert not task.success(state)
        start = state.objects["key"]
        out = start + [0, 0, 0.027, 0, 0, 0, 0]
        assert task.success(replace(state, objects={"key": out}))
        assert not task.success(replace(state, objects={"key": start + [0, 0, 0.025, 0, 0, 0, 0]}))
        turn = math.radians(16) / 2
        tilted = out.copy()
        tilted[3:] = [math.cos(turn), math.sin(turn), 0.0, 0.0]
        assert not task.success(replace(state, objects={"key": tilted}))
    finally:
        session.close()


def test_blade_geometry_check_sees_a_blade_through_the_plate():
    # the tunnelling check itself: a blade turned 30 deg and raised 5 mm would be inside the plate
    assert plate_depth_m(math.radians(30), 0.005) > 0.001
    assert plate_depth_m(math.radians(30), 0.00052) == pytest.approx(0.00002)  # pressed up under the plate
    assert plate_depth_m(0.0, 0.005) == 0.0  # aligned: through the keyway
    assert plate_depth_m(math.radians(30), 0.0) == 0.0  # below the plate
