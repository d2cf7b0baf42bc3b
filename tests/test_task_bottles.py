"""Lift Bottle and Put Bottle in Shelf: the experts on 100 seeds each, what their corrections from touch are
worth, the bottle's pivot in a loosened grasp, replay of recorded actions, and the correction in the data."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest

from univtac_data import DatasetWriter
from univtac_data.generators.scene.geometry import quat_from_axis_angle, quat_mul, quat_to_mat
from univtac_data.generators.scene.touch import TouchReading
from univtac_data.generators.tasks.base import ExpertContext, TaskConfig
from univtac_data.generators.tasks.expert_rollout import expert_rollout
from univtac_data.generators.tasks.bottle import in_hand_from_touch
from univtac_data.generators.tasks.collect import ExpertOutcome, TaskEpisodeSpec, run_expert
from univtac_data.generators.tasks.motions import close_until, move_to
from univtac_data.generators.tasks.put_bottle_in_shelf import PIVOT_MIN_DEPTH_MM, grasp_law
from univtac_data.generators.tasks.registry import make_task
from univtac_data.generators.tasks.session import TaskSession
from univtac_data.validators import validate

os.environ.setdefault("MUJOCO_GL", "egl")
FAST = TaskConfig(cameras=False)


def outcomes(name: str, seeds: range, corrections: bool = True) -> list[ExpertOutcome]:
    return [run_expert(TaskEpisodeSpec(name, seed, FAST), record=False, corrections=corrections) for seed in seeds]


@pytest.fixture(scope="module")
def lift_bottle() -> list[ExpertOutcome]:
    return outcomes("lift_bottle", range(100))


@pytest.fixture(scope="module")
def put_bottle() -> list[ExpertOutcome]:
    return outcomes("put_bottle_in_shelf", range(100))


def _report(name: str, runs: list[ExpertOutcome]) -> None:
    print(f"{name} expert: success {sum(o.success for o in runs)}/100, unsafe {sum(not o.safe for o in runs)}, "
          f"steps max {max(o.steps for o in runs)}")


def expert_with_true_tilt(name: str, seed: int) -> tuple[dict, list[float]]:
    """The expert's memory and the bottle's true tilt (deg) after each step (index 0: after reset)."""
    with expert_rollout(make_task(name, FAST), seed) as run:
        tilts = [_tilt_deg(run.session)]
        for step in run.steps():
            run.take(step)
            tilts.append(_tilt_deg(run.session))
        return run.ctx.memory, tilts


def test_lift_bottle_expert_succeeds_on_100_seeds(lift_bottle):
    _report("lift_bottle", lift_bottle)
    assert sum(o.success for o in lift_bottle) >= 95, [o.seed for o in lift_bottle if not o.success]
    assert all(o.safe for o in lift_bottle), [(o.seed, o.violation) for o in lift_bottle if not o.safe]
    assert max(o.steps for o in lift_bottle) < make_task("lift_bottle", FAST).max_steps
    for o in lift_bottle:
        kinds = [c["what"] for c in o.memory["corrections"]]
        assert "push to the wall" in kinds  # every bottle is set down by the wall from its in-hand pose
    # the set-up's pitch (3-15 deg) leaves most bottles visibly off upright after the open-loop turn
    assert sum(o.memory["corrections"][0]["what"] == "turn upright" for o in lift_bottle) >= 80


@pytest.mark.parametrize("name, what", [("lift_bottle", "turn upright"), ("put_bottle_in_shelf", "swing upright")])
def test_the_tilt_the_strips_show_is_the_true_tilt(name, what):
    checked = 0
    for seed in range(6):
        memory, tilts = expert_with_true_tilt(name, seed)
        corrections = [c for c in memory["corrections"] if c["what"] == what]
        if not corrections:  # a Lift Bottle grasp pitched by less than 1.5 deg needs no turn
            continue
        c = corrections[0]
        assert c["signal"].startswith("contact strip angle")
        if what == "turn upright":  # noted before the turn
            # a lying bottle pressed 0.9 mm touches a band 15 mm wide that the 21 mm pad clips: the band's
            # principal axis leans towards the pad's long side (the tilt read 3-4.5 deg high from it, seeds
            # 0-5); the line through its chords' midpoints is the axis
            assert c["total_tilt_deg"] == pytest.approx(tilts[int(c["step"])], abs=0.3), seed
        else:  # noted after the swing, which began c['steps'] steps earlier
            # before: still (0.01 deg off, seeds 0-5); after: the bottle is still turning (up to 1.8 deg)
            assert c["tilt_before_deg"] == pytest.approx(tilts[int(c["step"] - c["steps"])], abs=0.3), seed
            assert c["tilt_after_deg"] == pytest.approx(tilts[int(c["step"])], abs=2.5), seed
        checked += 1
    assert checked >= 4


def test_lift_bottle_fails_without_its_corrections():
    without = outcomes("lift_bottle", range(20), corrections=False)
    assert sum(o.success for o in without) <= 0.3 * 20


def test_put_bottle_expert_at_25_hz_fits_the_time_limit_it_has_at_50_hz():
    """The swing and the grasps are per 20 ms step, scaled at other rates: at 25 Hz the expert takes about as
    long in seconds as at 50 Hz and finishes inside the task's 6 s (150 steps), as ``evaluate`` allows."""
    slow = TaskConfig(cameras=False, rate_hz=25.0)
    runs = [run_expert(TaskEpisodeSpec("put_bottle_in_shelf", seed, slow), record=False) for seed in range(8)]
    limit = make_task("put_bottle_in_shelf", slow).step_limit
    assert limit == 150
    assert all(o.success and o.safe for o in runs), [(o.seed, o.steps, o.violation) for o in runs]
    assert max(o.steps for o in runs) < limit - 5, [o.steps for o in runs]
    at_50 = [run_expert(TaskEpisodeSpec("put_bottle_in_shelf", seed, FAST), record=False) for seed in range(2)]
    for fast, slow_run in zip(at_50, runs):
        swing_50, swing_25 = (o.memory["corrections"][0] for o in (fast, slow_run))
        assert swing_25["steps"] / 25 == pytest.approx(swing_50["steps"] / 50, rel=0.35)
        assert slow_run.steps / 25 == pytest.approx(fast.steps / 50, rel=0.15)


def test_put_bottle_expert_succeeds_on_100_seeds_and_swings_the_bottle_upright(put_bottle):
    _report("put_bottle_in_shelf", put_bottle)
    assert sum(o.success for o in put_bottle) >= 95, [o.seed for o in put_bottle if not o.success]
    assert all(o.safe for o in put_bottle), [(o.seed, o.violation) for o in put_bottle if not o.safe]
    assert max(o.steps for o in put_bottle) < make_task("put_bottle_in_shelf", FAST).max_steps
    for o in put_bottle:
        swing, place = o.memory["corrections"][:2]
        assert swing["what"] == "swing upright" and place["what"] == "place from the in-hand pose"
        # the swing takes most of the hand's 60-71.5 deg tilt out
        assert swing["tilt_before_deg"] > 50.0 and swing["tilt_after_deg"] < 20.0 and swing["loosened_mm"] > 0.5
        assert abs(place["offset_mm"]) < 12.0 and place["axis_tilt_deg"] < 20.0


def test_put_bottle_fails_without_the_swing():
    without = outcomes("put_bottle_in_shelf", range(20), corrections=False)
    assert sum(o.success for o in without) <= 0.3 * 20


def _tilt_deg(session: TaskSession) -> float:
    axis = quat_to_mat(session.sim.object_pose("bottle")[3:])[:, 2]
    return math.degrees(math.acos(min(1.0, float(axis[2]))))


def _held_tilted(seed: int) -> tuple[TaskSession, ExpertContext]:
    """Put Bottle in Shelf up to the expert's tilt: the bottle gripped, lifted and tilted with the hand."""
    task = make_task("put_bottle_in_shelf", FAST)
    session = TaskSession(task)
    session.reset(seed)
    ctx = ExpertContext(session, session.rng)
    for step in move_to(ctx, task.seen_bottle(session.layout), speed_m_s=0.35):
        session.step(step.action, step.primitive)
    for step in close_until(ctx, grasp_law(task.profile)):
        session.step(step.action, step.primitive)
    closing = quat_to_mat(ctx.target[3:7])[:, 0]
    tilted = quat_mul(quat_from_axis_angle(closing, session.layout["tilt_rad"]), ctx.target[3:7])
    for step in move_to(ctx, ctx.target[:3] + [0.0, 0.0, session.layout["lift_m"]], tilted, speed_m_s=0.4,
                        turn_rad_s=3.0):
        session.step(step.action, step.primitive)
    for _ in range(10):  # let the hand settle
        session.step(ctx.target, "hold")
    return session, ctx


def _hold(session: TaskSession, ctx: ExpertContext, seconds: float, press_mm: float | None) -> None:
    """Hold the hand still; with ``press_mm`` regulate the opening so the shallower pad presses that deep."""
    for _ in range(round(seconds * session.config.rate_hz)):
        action = ctx.target.copy()
        if press_mm is not None:
            depth = min(ctx.indentation_mm().values())
            action[7] += float(np.clip((depth - press_mm) * 1e-3, -3e-5, 9e-5))
        ctx.target = action
        session.step(action, "swing")


@pytest.mark.parametrize("seed", [0, 3])
def test_the_bottle_pivots_in_a_loosened_grasp_and_not_in_a_tight_one(seed):
    tight, tight_ctx = _held_tilted(seed)
    before = _tilt_deg(tight)
    assert before > 55.0
    _hold(tight, tight_ctx, 1.0, None)
    assert abs(_tilt_deg(tight) - before) < 1.5  # gripped as grasped: friction holds the torque
    tight.close()

    loose, ctx = _held_tilted(seed)
    start = _tilt_deg(loose)
    _hold(loose, ctx, 1.2, PIVOT_MIN_DEPTH_MM)
    swung = _tilt_deg(loose)
    assert start - swung > 35.0  # turned towards upright under gravity
    for step in close_until(ctx, grasp_law(loose.task.profile), primitive="regrasp"):
        loose.step(step.action, step.primitive)
    gripped = _tilt_deg(loose)
    _hold(loose, ctx, 0.5, None)
    assert abs(_tilt_deg(loose) - gripped) < 1.0  # re-gripped: it stops
    assert loose.safe
    loose.close()


def test_in_hand_pose_from_two_strips():
    # a bottle axis 20 deg from gripper +z towards +y, crossing 3 mm along gripper y: each pad sees a strip
    angle = math.radians(20.0)
    left = TouchReading(True, 100.0, (3.0, 0.0), math.pi / 2 - angle, 8.0, 0.5, 0.9, 20.0, 8.0)
    right = TouchReading(True, 100.0, (-3.0, 0.0), math.pi / 2 + angle - math.pi, 8.0, 0.5, 0.9, 20.0, 8.0)
    pose = in_hand_from_touch(left, right)
    assert pose.both and pose.angle_rad == pytest.approx(angle, abs=1e-9)
    assert pose.point_m[0] == pytest.approx(0.003 * math.cos(angle) ** 2, abs=1e-9)
    axis = pose.axis_world(np.array([1.0, 0.0, 0.0, 0.0]))
    assert axis == pytest.approx([0.0, math.sin(angle), math.cos(angle)])
    # a strip has no arrow: the expert's hint picks the way
    assert pose.axis_world(np.array([1.0, 0.0, 0.0, 0.0]), np.array([0.0, 0.0, -1.0]))[2] < 0
    assert not in_hand_from_touch(TouchReading.none(), TouchReading.none()).both


@pytest.mark.parametrize("name, correction_primitives", [("lift_bottle", {"square", "push"}),
                                                         ("put_bottle_in_shelf", {"swing", "regrasp"})])
def test_recorded_episode_replays_validates_and_shows_the_correction(tmp_path, name, correction_primitives):
    outcome = run_expert(TaskEpisodeSpec(name, 4, FAST))
    episode = outcome.episode
    assert outcome.success and episode is not None and episode.meta.success
    names = episode.meta.primitive_names
    labels = [names[i] if i >= 0 else None for i in episode["scene/primitive"]]
    assert correction_primitives <= set(labels)
    poses = episode["scene/objects/bottle/pose"]
    tilt = np.degrees(np.arccos(np.clip([quat_to_mat(p[3:])[2, 2] for p in poses], -1, 1)))
    frames = [k for k, label in enumerate(labels) if label in correction_primitives]
    # the correction turns the bottle towards upright, in the world and against the pads
    assert tilt[frames[0]] - tilt[frames[-1]] > 3.0
    in_pad = episode["tactile/left/object_pose"]
    turn = [abs(math.degrees(2 * math.acos(min(1.0, abs(float(np.dot(in_pad[frames[0], 3:], in_pad[k, 3:])))))))
            for k in frames]
    if name == "put_bottle_in_shelf":
        assert max(turn) > 30.0  # the swing: the bottle turns between the pads
    assert episode.meta.extra["task"]["memory"]["corrections"]
    # replaying the recorded actions from the seed gives the same rollout
    task = make_task(name, FAST)
    session = TaskSession(task)
    session.reset(episode.meta.seed)
    for action in episode["robot/action"][:-1]:
        state = session.step(action)
    assert task.success(state)
    assert np.linalg.norm(state.objects["bottle"][:3] - poses[-1][:3]) < 1e-3
    session.close()
    writer = DatasetWriter.open(tmp_path / "ds")
    writer.add(episode)
    report = validate(str(tmp_path / "ds"))
    failed = [c.rule for c in report.episodes[episode.meta.episode_id].checks if c.status == "fail"]
    assert not failed, failed


def test_gel_slip_is_counted_from_the_end_of_a_controlled_slip():
    from univtac_data.validators.rules_safety import slip_since_controlled

    # slip_mm accumulates from contact onset: 0.2 before the swing, 3.0 during it, 3.4 after it, then a new
    # contact (the drop to 0) counts from 0
    slip = np.array([0.0, 0.2, 1.5, 3.0, 3.1, 3.4, 0.0, 0.5])
    controlled = np.array([False, False, True, True, False, False, False, False])
    assert slip_since_controlled(slip, controlled) == pytest.approx([0.0, 0.2, 0.0, 0.0, 0.1, 0.4, 0.0, 0.5])
