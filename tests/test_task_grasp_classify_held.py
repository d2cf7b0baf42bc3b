"""Grasp Classify (held), the paper's policy protocol: the expert puts the held cylinder on its class's pad on
100 seeds, deciding the class from touch alone, and nothing but the pads tells the two classes apart."""

from __future__ import annotations

import os
from dataclasses import dataclass, replace

import numpy as np
import pytest

from univtac_data.generators.tasks.base import TaskConfig
from univtac_data.generators.tasks.expert_rollout import expert_rollout
from univtac_data.generators.tasks.grasp_classify import GOAL_PADS_XY_M, GRASP_HEIGHT_M, RADIUS_M
from univtac_data.generators.tasks.grasp_classify_held import CYLINDER, GraspClassifyHeld
from univtac_data.generators.tasks.session import TaskSession
from univtac_data.schema.sensors import get_sensor

os.environ.setdefault("MUJOCO_GL", "egl")
FAST = TaskConfig(cameras=False)
PROFILE = get_sensor("gelsight_mini")


@dataclass(frozen=True)
class Outcome:
    seed: int
    success: bool
    safe: bool
    violation: str | None
    steps: int
    decided: str  # the expert's class
    truth: str  # the layout's
    start_in_hand_mm: float  # the cylinder's axis from the gripper centre after the set-up, mm


def run_expert(task: GraspClassifyHeld, seed: int) -> Outcome:
    """The expert from ``seed``, with a context whose layout lacks ``held_class``: it must decide from touch."""
    with expert_rollout(task, seed) as run:
        session, ctx = run.session, run.ctx
        ee = session.sim.ee_pose()
        axis_xy = session.sim.object_pose(CYLINDER)[:2]
        ctx.layout = {key: value for key, value in session.layout.items() if key != "held_class"}
        state = run.run()
        return Outcome(seed, task.success(state), session.safe, session.first_violation(), session.steps,
                       ctx.memory["held_class"], session.layout["held_class"],
                       float(np.linalg.norm(axis_xy - ee[:2]) * 1000))


@pytest.fixture(scope="module")
def outcomes() -> list[Outcome]:
    task = GraspClassifyHeld(FAST, PROFILE)
    return [run_expert(task, seed) for seed in range(100)]


@pytest.mark.slow
def test_expert_places_the_held_cylinder_on_100_seeds_and_decides_from_touch(outcomes: list[Outcome]):
    successes = sum(o.success for o in outcomes)
    correct = sum(o.decided == o.truth for o in outcomes)
    print(f"grasp_classify_held expert: success {successes}/100, class right {correct}/100, steps "
          f"{min(o.steps for o in outcomes)}-{max(o.steps for o in outcomes)}")
    assert successes >= 95, [(o.seed, o.decided, o.truth) for o in outcomes if not o.success]
    assert all(o.safe for o in outcomes), [(o.seed, o.violation) for o in outcomes if not o.safe]
    assert correct == 100, [(o.seed, o.decided, o.truth) for o in outcomes if o.decided != o.truth]
    # both classes come up: a constant choice would be right about half the time, never always
    truths = [o.truth for o in outcomes]
    assert 25 <= truths.count("rough") <= 75, truths.count("rough")
    assert max(o.steps for o in outcomes) < GraspClassifyHeld.max_steps
    # the set-up really holds the cylinder between the pads (within a few mm of the gripper's centre)
    assert max(o.start_in_hand_mm for o in outcomes) < 5.0


def test_the_classes_differ_only_in_what_the_pads_feel():
    """The same seed's scene with the other class is the same MJCF (cameras render the same), and differs
    only in the tactile texture; the start pose does not depend on the class either."""
    task = GraspClassifyHeld(FAST, PROFILE)
    layout = task.sample_layout(np.random.default_rng(5))
    other = {**layout, "held_class": "plain" if layout["held_class"] == "rough" else "rough"}
    assert task.scene_xml(layout) == task.scene_xml(other)
    np.testing.assert_array_equal(task.start_pose(layout), task.start_pose(other))
    assert sorted(len(task.textures(x)) for x in (layout, other)) == [0, 1]
    # the set-up grips the cylinder: the opening is its diameter less the grasp depth on each pad
    start = task.start_pose(layout)
    assert start[7] == pytest.approx(2 * RADIUS_M - 2 * 0.5e-3)
    assert start[2] == pytest.approx(0.05 + GRASP_HEIGHT_M)


def test_success_needs_the_pad_of_the_cylinders_class():
    """Held over the wrong pad is a failure; over the right one, low enough and upright, a success."""
    task = GraspClassifyHeld(FAST, PROFILE)
    session = TaskSession(task)
    try:
        state = session.reset(1)
        cls = session.layout["held_class"]
        wrong = "plain" if cls == "rough" else "rough"
        for goal, expected in ((GOAL_PADS_XY_M[cls], True), (GOAL_PADS_XY_M[wrong], False)):
            pose = state.objects[CYLINDER].copy()
            pose[:2], pose[2], pose[3:] = goal, 0.003 + 0.005 + 0.05, (1.0, 0.0, 0.0, 0.0)
            moved = replace(state, objects={CYLINDER: pose})
            assert task.success(moved) is expected
        assert not task.success(state)  # the start, 5 cm up and away from both pads
    finally:
        session.close()
