"""The experts on the sensors they were not developed on (GF225, Xense WS): thinner gels, safe only to 0.8 mm, and
the GF225's image narrower than its gel. Seeds from 100 up: neither the task tests' nor the evaluation's."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest

from univtac_data.generators.tasks.base import TaskConfig
from univtac_data.generators.tasks.collect import TaskEpisodeSpec, run_expert
from univtac_data.generators.scene.touch import TouchReading
from univtac_data.generators.tasks.lift_can import patch_at_image_edge, squareness_from_touch
from univtac_data.generators.tasks.put_bottle_in_shelf import grasp_law
from univtac_data.generators.tasks.registry import make_task
from univtac_data.schema.sensors import get_sensor

os.environ.setdefault("MUJOCO_GL", "egl")


def outcome(task: str, sensor: str, seed: int):
    return run_expert(TaskEpisodeSpec(task, seed, TaskConfig(cameras=False, sensor=sensor)), record=False)


def test_the_bottle_grasp_is_shallower_on_the_thin_gels():
    assert grasp_law(get_sensor("gelsight_mini")).threshold_mm == pytest.approx(0.9)
    for sensor in ("gf225", "xense_ws"):
        law = grasp_law(get_sensor(sensor))
        assert law.threshold_mm == pytest.approx(0.36) and law.threshold_mm < get_sensor(sensor).safe_indentation_mm


@pytest.mark.parametrize("task,sensor,seed", [("lift_bottle", "gf225", 103), ("lift_bottle", "xense_ws", 103),
                                              ("put_bottle_in_shelf", "gf225", 104)])
def test_a_bottle_held_on_a_thin_gel_stays_within_its_safe_indentation(task, sensor, seed):
    # each of these seeds pressed a pad past 0.8 mm with the Mini's grasp depth factor (0.54 mm on these gels)
    o = outcome(task, sensor, seed)
    assert o.safe, o.violation
    assert o.success


@pytest.mark.parametrize("seed", [102, 309])
def test_lift_can_on_the_gf225_turns_when_the_patch_is_off_the_image(seed):
    # the can crosses the pads so far from square that it touches the GF225's gel only beyond its imaged 23.5 mm:
    # both pads press, neither image shows a patch; a turn brings the patch into view, and the squareness read
    # from it corrects the grasp when it is more than 6 deg (seed 309: 6.1 deg; seed 102 is lifted as it is)
    o = outcome("lift_can", "gf225", seed)
    whats = [c["what"] for c in o.memory["corrections"]]
    assert whats == ["grasp squareness, patch off the image"] + ["grasp squareness"] * (seed == 309)
    if seed == 309:
        assert abs(o.memory["corrections"][1]["angle_deg"]) > 6.0
    assert o.success and o.safe


def test_lift_can_on_the_gf225_has_time_left_after_a_blind_turn_the_wrong_way(monkeypatch):
    # the first blind turn (12 deg) went the wrong way and the second turned back 24 deg: with a full re-grasp
    # for each turn and a squareness re-grasp for the 3.4 deg left after them, the can was still turning at the
    # 300-step limit. The turn back, towards square, opens 3 mm and turns at 2.4 rad/s, no re-grasp opens past
    # the gripper's stroke, and after a blind turn only a can more than 6 deg from square is re-grasped
    from univtac_data.generators.tasks import lift_can

    o = outcome("lift_can", "gf225", 101)
    blind = [c for c in o.memory["corrections"] if c["what"] == "grasp squareness, patch off the image"]
    assert [c["angle_deg"] for c in blind] == pytest.approx([12.0, -24.0])
    assert [c["what"] for c in o.memory["corrections"]] == [c["what"] for c in blind]
    assert o.success and o.safe and o.steps < 285
    monkeypatch.setattr(lift_can, "TOWARDS_SQUARE_OPEN_M", lift_can.REGRASP_OPEN_M)
    monkeypatch.setattr(lift_can, "TOWARDS_SQUARE_TURN_RAD_S", lift_can.REGRASP_TURN_RAD_S)
    monkeypatch.setattr(lift_can, "AFTER_BLIND_TOLERANCE_RAD", lift_can.SQUARE_TOLERANCE_RAD)
    monkeypatch.setattr(lift_can, "regrasp_opening_m", lambda width_m, wider_m: width_m + wider_m)
    before = outcome("lift_can", "gf225", 101)
    assert before.memory["corrections"][-1]["what"] == "grasp squareness"
    assert not before.success and before.steps == 300


def test_lift_can_on_the_mini_never_turns_blind():
    # the Mini images its whole gel: a grasped can always shows a patch there
    for seed in range(100, 110):
        o = outcome("lift_can", "gelsight_mini", seed)
        assert not any("off the image" in c["what"] for c in o.memory["corrections"])


@pytest.mark.parametrize("seed", [106, 136])
def test_a_quick_swing_keeps_the_bottle_from_sliding_down_the_gf225(seed, monkeypatch):
    # the GF225's 29 mm contact strip resists the turn more than the Mini's 20.75 mm, so the loose bottle turns
    # later and slides down the pads for as long as it is loose: the slower swing (0.03 mm and 1.5 deg a step)
    # slid these seeds' bottles past the task's 10 mm
    from univtac_data.generators.tasks import put_bottle_in_shelf as put_bottle

    quick = outcome("put_bottle_in_shelf", "gf225", seed)
    assert quick.success and quick.safe, quick.violation
    assert quick.max_in_hand_slip_mm < put_bottle.PutBottleInShelf.max_in_hand_slip_mm
    monkeypatch.setattr(put_bottle, "PIVOT_STEP_M", 0.00003)
    monkeypatch.setattr(put_bottle, "PIVOT_RATE_RAD", math.radians(1.5))
    monkeypatch.setattr(put_bottle, "PIVOT_FAST_RATE_RAD", math.radians(3.0))
    slow = outcome("put_bottle_in_shelf", "gf225", seed)
    assert slow.max_in_hand_slip_mm > put_bottle.PutBottleInShelf.max_in_hand_slip_mm > quick.max_in_hand_slip_mm
    assert not slow.safe


def test_a_patch_running_off_the_gf225_image_gives_the_squareness_from_the_press():
    # a sliver at the image's edge (23.5 of the 27 mm gel imaged): the patch starts at the gel's end out of
    # sight, where the pad presses 0.3 mm, and ends at the sliver's inner end
    sliver = TouchReading(True, 0.1, (11.7, -0.2), 0.0, 1.0, 0.01, 1.0, 0.05, 0.05)
    gf225, mini = get_sensor("gf225"), get_sensor("gelsight_mini")
    assert patch_at_image_edge(sliver, gf225.gel_width_mm, gf225.imaged_width_mm)
    angle = squareness_from_touch(sliver, TouchReading.none(), gf225.gel_width_mm, gf225.imaged_width_mm, (0.3, 0.3))
    assert math.degrees(angle) == pytest.approx(math.degrees(math.atan(0.3 / (13.5 - 11.675))), abs=0.01)
    # the Mini images all of its gel: no patch runs off its image
    assert not patch_at_image_edge(sliver, mini.gel_width_mm, mini.imaged_width_mm)


@pytest.mark.parametrize("seed", [130, 133])
def test_lift_can_on_the_gf225_squares_from_a_patch_at_the_image_edge(seed):
    # the can crosses the pads about 10 deg from square: one image shows only a sliver at its edge (these seeds
    # lifted the can crooked when the expert needed two patches in view)
    o = outcome("lift_can", "gf225", seed)
    task = make_task("lift_can", TaskConfig(cameras=False, sensor="gf225"))
    error_deg = math.degrees(task.sample_layout(np.random.default_rng(seed))["seen_yaw_error_rad"])
    first = o.memory["corrections"][0]
    assert first["what"] == "grasp squareness" and first["patch_span_mm"] < 0.5
    assert first["angle_deg"] == pytest.approx(-error_deg, abs=1.5)
    assert o.success and o.safe
