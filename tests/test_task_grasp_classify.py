"""Grasp Classify: the expert sorts the two cylinders on 100 seeds from touch alone, the cylinders look the same
to the camera but not to the pads, and the re-place correction is what makes the placing reliable."""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import pytest

from univtac_data.generators.tasks.base import TaskConfig, TaskState
from univtac_data.generators.tasks.expert_rollout import expert_rollout
from univtac_data.generators.tasks.grasp_classify import FILL_ROUGH_BELOW, GOAL_PADS_XY_M, GraspClassify
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
    classes: dict[str, str]  # the expert's decision per spot
    truth: dict[str, str]  # the layout's class per spot
    corrections: list[dict[str, Any]]


def run_expert(task: GraspClassify, seed: int, corrections: bool = True) -> Outcome:
    """The expert from ``seed`` until its script ends or the step limit. The expert's context has the layout
    without ``rough_spot`` (the ground truth of which cylinder is knurled): it must decide from touch.
    ``corrections=False``: the expert never re-places (to measure what re-placing is worth)."""
    with expert_rollout(task, seed, corrections=corrections) as run:
        session, ctx = run.session, run.ctx
        ctx.layout = {key: value for key, value in session.layout.items() if key != "rough_spot"}
        state = run.run()
        return Outcome(seed, task.success(state), session.safe, session.first_violation(), session.steps,
                       dict(ctx.memory["classes"]), task.true_classes(session.layout), list(ctx.memory["corrections"]))


@pytest.fixture(scope="module")
def outcomes() -> list[Outcome]:
    task = GraspClassify(FAST, PROFILE)
    return [run_expert(task, seed) for seed in range(100)]


@pytest.mark.slow
def test_expert_sorts_the_cylinders_on_100_seeds_safely_and_classifies_from_touch(outcomes: list[Outcome]):
    successes = sum(o.success for o in outcomes)
    correct = sum(o.classes == o.truth for o in outcomes)
    print(f"grasp_classify expert: success {successes}/100, classification accuracy {correct}/100 episodes, "
          f"{sum(len(o.corrections) for o in outcomes)} re-places on {sum(bool(o.corrections) for o in outcomes)} "
          f"seeds, steps max {max(o.steps for o in outcomes)} (limit {GraspClassify.max_steps})")
    assert successes >= 95, [(o.seed, o.classes, o.truth) for o in outcomes if not o.success]
    assert all(o.safe for o in outcomes), [(o.seed, o.violation) for o in outcomes if not o.safe]
    assert correct == 100, [(o.seed, o.classes, o.truth) for o in outcomes if o.classes != o.truth]
    # both classes come up on both spots: the decision is not a constant
    assert {o.truth["0"] for o in outcomes} == {"rough", "plain"}
    # the script fits its step limit: a rollout cut off there would be a failure for the wrong reason
    assert max(o.steps for o in outcomes) < GraspClassify.max_steps


@pytest.mark.slow
def test_re_place_fires_on_misses_and_without_it_the_expert_fails_more_often(outcomes: list[Outcome]):
    corrected = [o for o in outcomes if o.corrections]
    assert len(corrected) >= 20, len(corrected)  # the pads' seen centres are off by up to 3 cm
    for o in corrected:
        for c in o.corrections:
            assert c["what"] == "re-place after a miss" and c["signal"].startswith("head camera")
            assert c["miss_mm"] > 12.0
    task = GraspClassify(FAST, PROFILE)
    seeds = range(40)
    without = [run_expert(task, seed, corrections=False) for seed in seeds]
    assert not any(o.corrections for o in without)
    rate_with = sum(outcomes[s].success for s in seeds) / len(seeds)
    rate_without = sum(o.success for o in without) / len(seeds)
    print(f"grasp_classify on seeds 0-39: success {rate_with:.0%} with re-placing, {rate_without:.0%} without")
    assert rate_without <= rate_with - 0.25, (rate_with, rate_without)


class SwappedGraspClassify(GraspClassify):
    """The same layouts with the knurled and the plain cylinder exchanged (every pose the same)."""

    def sample_layout(self, rng: np.random.Generator) -> dict[str, Any]:
        layout = super().sample_layout(rng)
        layout["rough_spot"] = 1 - layout["rough_spot"]
        return layout


def head_image(task: GraspClassify, seed: int) -> np.ndarray:
    session = TaskSession(task, record=True)
    try:
        session.reset(seed)
        return session.sim.pixel_arrays()["scene/cameras/head/rgb"][0].copy()
    finally:
        session.close()


def test_the_head_camera_cannot_tell_the_cylinders_apart():
    config = TaskConfig(cameras=True, camera_size=(240, 136))
    seed = 3
    image = head_image(GraspClassify(config, PROFILE), seed)
    swapped = head_image(SwappedGraspClassify(config, PROFILE), seed)
    assert image.shape == (136, 240, 3) and image.std() > 10  # a scene, not a blank frame
    np.testing.assert_array_equal(image, swapped)
    # the camera does see the cylinders: another layout moves them and the image changes
    other = head_image(GraspClassify(config, PROFILE), seed + 1)
    assert np.abs(other.astype(int) - image.astype(int)).max() > 50


def grasp_spot_0(task: GraspClassify, seed: int) -> tuple[dict[str, Any], dict[str, np.ndarray], np.ndarray]:
    """Run the expert until it has classified the cylinder on spot 0; its touch, one recorded tactile frame
    and that cylinder's world pose."""
    with expert_rollout(task, seed) as run:
        session, ctx = run.session, run.ctx
        for step in run.steps():
            run.take(step)
            if "0" in ctx.memory.get("classes", {}):
                break
        touch = ctx.touch()
        session.sim.start_recording()
        session.sim.record_frame()
        pixels = {path: array[0].copy() for path, array in session.sim.pixel_arrays().items()}
        x, y = task.cylinder_xy(session.layout, "rough" if session.layout["rough_spot"] == 0 else "plain")
        held = min((session.sim.object_pose(name) for name in task.objects()),
                   key=lambda pose: float(np.hypot(pose[0] - x, pose[1] - y)))
        return touch, pixels, held


def test_the_pads_tell_the_cylinders_apart():
    seed = 3
    task, swapped = GraspClassify(FAST, PROFILE), SwappedGraspClassify(FAST, PROFILE)
    layout = task.sample_layout(np.random.default_rng(seed))
    touch_a, pixels_a, pose_a = grasp_spot_0(task, seed)
    touch_b, pixels_b, pose_b = grasp_spot_0(swapped, seed)
    # the same grasp of the same-looking cylinder on the same spot: only the surface differs
    np.testing.assert_allclose(pose_a[:3], pose_b[:3], atol=1e-4)
    rough, plain = (touch_a, touch_b) if layout["rough_spot"] == 0 else (touch_b, touch_a)
    for pad in ("left", "right"):
        assert rough[pad].touching and plain[pad].touching
        assert rough[pad].fill < 0.4 < FILL_ROUGH_BELOW < 0.55 < plain[pad].fill, (rough[pad], plain[pad])
        depth_a, depth_b = pixels_a[f"tactile/{pad}/depth_um"], pixels_b[f"tactile/{pad}/depth_um"]
        assert depth_a.max() > 300 and depth_b.max() > 300  # both pressed about 0.5 mm
        assert (depth_a != depth_b).mean() > 0.02  # the knurl's grooves leave the gel untouched in stripes
        mask_a = pixels_a[f"tactile/{pad}/contact_mask"].astype(bool)
        mask_b = pixels_b[f"tactile/{pad}/contact_mask"].astype(bool)
        assert mask_a.sum() != mask_b.sum()


def test_success_needs_each_cylinder_on_its_own_pad():
    session = TaskSession(GraspClassify(FAST, PROFILE))
    task = session.task
    try:
        state = session.reset(0)
        assert not task.success(state)  # both start on their spots
        pad_top = 0.003
        name = {c: task.cylinder_of(state.layout, c) for c in ("rough", "plain")}
        on_pads = {name[c]: np.array([*GOAL_PADS_XY_M[c], pad_top + 0.05, 1, 0, 0, 0]) for c in name}
        assert task.success(_with_objects(state, on_pads))
        crossed = {name["rough"]: on_pads[name["plain"]], name["plain"]: on_pads[name["rough"]]}
        assert not task.success(_with_objects(state, crossed))
        off = dict(on_pads)
        off[name["plain"]] = on_pads[name["plain"]] + [0.0, 0.021, 0, 0, 0, 0, 0]
        assert not task.success(_with_objects(state, off))
        tilted = dict(on_pads)
        turn = 0.14  # half of 16 deg, rad: the quaternion of a 16 deg tilt about x
        tilted[name["rough"]] = np.array([*GOAL_PADS_XY_M["rough"], pad_top + 0.05,
                                               np.cos(turn), np.sin(turn), 0, 0])
        assert not task.success(_with_objects(state, tilted))  # 16 deg
    finally:
        session.close()


def _with_objects(state: TaskState, objects: dict[str, np.ndarray]) -> TaskState:
    return replace(state, objects=objects)
