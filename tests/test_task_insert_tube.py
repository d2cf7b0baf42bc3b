"""Insert Tube: the expert gets the 2.0 cm tube into the 2.05 cm bore on 100 seeds, safely, without the tube ever
passing through solid material; the first attempt misses by design and the pads' shear is what finds the
hole; replaying the recorded actions reproduces the insertion."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, replace
from typing import Any

import mujoco
import numpy as np
import pytest

from univtac_data import DatasetWriter
from univtac_data.generators.scene.geometry import quat_to_mat
from univtac_data.generators.tasks.base import TaskConfig
from univtac_data.generators.tasks.expert_rollout import expert_rollout
from univtac_data.generators.tasks.collect import ExpertOutcome, TaskEpisodeSpec, run_expert
from univtac_data.generators.tasks.holes import Bore, tube_in_solid_mm
from univtac_data.generators.tasks import insert_tube
from univtac_data.generators.tasks.insert_tube import BORE, TUBE_HALF_M, TUBE_RADIUS_M, InsertTube
from univtac_data.generators.tasks.session import TaskSession
from univtac_data.schema.sensors import get_sensor
from univtac_data.validators import validate

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
    in_solid_mm: float  # deepest the tube's surface went into the bore's walls over the episode
    memory: dict[str, Any]
    first_offset_mm: float
    tilt_at_push_deg: float | None  # the tube's axis from the bore's as the push began (None: no push)
    depth_mm: float  # how deep the tube's end ended below the entrance


def run(task: InsertTube, seed: int, corrections: bool = True) -> Outcome:
    """The expert from ``seed``, checking every step's tube pose against the hole's geometry."""
    with expert_rollout(task, seed, corrections=corrections) as run:
        session, state = run.session, run.state
        pos, quat = task.hole_pose(session.layout)
        deepest, tilt = 0.0, None
        for step in run.steps():
            if step.primitive == "insert" and tilt is None:
                cos_tilt = quat_to_mat(state.objects["tube"][3:])[:, 2] @ quat_to_mat(quat)[:, 2]
                tilt = math.degrees(math.acos(min(1.0, abs(float(cos_tilt)))))
            state = run.take(step)
            deepest = max(deepest, tube_in_solid_mm(state.objects["tube"], TUBE_RADIUS_M, TUBE_HALF_M, pos, quat, BORE))
        depth = -1000.0 * float(task.tube_end_in_hole(session.layout, state.objects["tube"])[2])
        return Outcome(seed, task.success(state), session.safe, session.first_violation(), session.steps, deepest,
                       dict(run.ctx.memory), 1000 * float(np.hypot(*session.layout["first_offset_m"])), tilt, depth)


def retries_of(o: Outcome | ExpertOutcome) -> list[dict[str, Any]]:
    return [c for c in o.memory["corrections"] if c["what"] == "search step after a miss"]


@pytest.fixture(scope="module")
def outcomes() -> list[Outcome]:
    task = InsertTube(FAST, PROFILE)
    return [run(task, seed) for seed in range(100)]


@pytest.mark.slow
def test_expert_inserts_on_100_seeds_safely_and_never_through_solid(outcomes: list[Outcome]):
    successes = sum(o.success for o in outcomes)
    retried = [o for o in outcomes if retries_of(o)]
    print(f"insert_tube expert: success {successes}/100, safe {sum(o.safe for o in outcomes)}, retries on "
          f"{len(retried)} seeds (at most {max(len(retries_of(o)) for o in outcomes)}), steps max "
          f"{max(o.steps for o in outcomes)}, deepest in a wall {max(o.in_solid_mm for o in outcomes):.2f} mm")
    assert successes >= 90, [o.seed for o in outcomes if not o.success]
    assert all(o.safe for o in outcomes), [(o.seed, o.violation) for o in outcomes if not o.safe]
    assert max(o.steps for o in outcomes) < InsertTube.max_steps
    # no tunnelling: the tube's surface never goes deeper into a wall than contact softness allows (the
    # stability study's peak penetration), far from the 10 mm a tube through the rim would show
    assert max(o.in_solid_mm for o in outcomes) < 0.6, max(o.in_solid_mm for o in outcomes)


@pytest.mark.slow
def test_misses_are_found_by_shear_and_without_retries_the_expert_fails_more_often(outcomes: list[Outcome]):
    retried = [o for o in outcomes if retries_of(o)]
    assert len(retried) >= 30  # a first attempt 1-4 mm off misses the chamfer's reach often
    for o in outcomes:
        for c in o.memory["corrections"]:
            if c["what"] == "search step after a miss":
                assert c["signal"].startswith("axial shear")
                assert c["shear_mm"] > 0.75 and 1.0 < c["move_mm"] <= 4.5 + 1e-6
            elif c["what"] == "step across the grasp after a miss on the chamfer":
                assert c["signal"].startswith("axial shear") and c["shear_mm"] > 0.75
                assert c["end_depth_mm"] >= 1000 * insert_tube.CHAMFER_MISS_M
                assert c["move_mm"] in (pytest.approx(1.5), pytest.approx(3.0))
            else:
                assert c["what"] == "straighten the tube" and c["signal"].startswith("marker field's rotation")
                assert 1.5 < abs(c["turn_deg"]) < 10.0 and c["pivot_deg"] == -c["turn_deg"]
    # a large first offset is always a miss, a small one goes straight in
    assert all(retries_of(o) for o in outcomes if o.first_offset_mm > 3.0)
    assert not any(retries_of(o) for o in outcomes if o.first_offset_mm < 1.2)
    near = [o for o in outcomes if o.first_offset_mm < 2.0]
    assert sum(not retries_of(o) for o in near) >= 0.8 * len(near)  # within the chamfer's reach
    seeds = range(30)
    task = InsertTube(FAST, PROFILE, corrections=False)
    without = [run(task, seed, corrections=True) for seed in seeds]
    assert not any(o.memory["corrections"] for o in without)
    ok_with = sum(outcomes[s].success and outcomes[s].safe for s in seeds) / len(seeds)
    ok_without = sum(o.success and o.safe for o in without) / len(seeds)
    print(f"insert_tube seeds 0-29: success (and safe) {ok_with:.0%} with retries, {ok_without:.0%} without")
    assert ok_without <= ok_with - 0.25, (ok_with, ok_without)


@pytest.mark.slow
def test_a_tube_turned_in_the_grasp_is_straightened_before_the_push(outcomes: list[Outcome], monkeypatch):
    """The chamfer turns the tube in the grasp by up to about 5 deg; the pads' marker rotation reads it and
    the gripper turns it back before the push. On the GF225's seed 144 (development seed) the tube turned 4
    deg: pushed crooked it wedged in the bore, slid 9 mm up the pads and ended 26 mm deep. (Its search is the
    ring's, as when the seed was found: with the step across the grasp it reaches the hole elsewhere.)"""
    straightened = [o for o in outcomes if any(c["what"] == "straighten the tube" for c in o.memory["corrections"])]
    assert straightened and all(o.tilt_at_push_deg < 1.5 for o in straightened), \
        [(o.seed, o.tilt_at_push_deg) for o in straightened]
    gf225 = TaskConfig(sensor="gf225", cameras=False)
    monkeypatch.setattr(insert_tube, "CHAMFER_MISS_M", math.inf)
    straight = run(InsertTube(gf225, get_sensor("gf225")), 144)
    monkeypatch.setattr(insert_tube, "STRAIGHTEN_TURN_RAD", math.inf)
    crooked = run(InsertTube(gf225, get_sensor("gf225")), 144)
    print(f"GF225 seed 144: straightened {straight.tilt_at_push_deg:.2f} deg at the push, {straight.depth_mm:.1f} mm "
          f"deep; not straightened {crooked.tilt_at_push_deg:.2f} deg, {crooked.depth_mm:.1f} mm deep")
    assert straight.success and straight.tilt_at_push_deg < 1.5 and straight.depth_mm > 33.0
    assert crooked.tilt_at_push_deg > 2.5 and crooked.depth_mm < straight.depth_mm - 5.0


@pytest.mark.slow
def test_a_probe_that_ends_on_the_chamfer_steps_across_the_grasp(monkeypatch):
    """Across the grasp (the pads' normal, the hole frame's x) the grip holds the tube rigidly and a probe
    more than about 1.3 mm off that way catches on the chamfer, its end 1.0-1.9 mm below the entrance instead
    of the flat plate's 0.1 mm. The expert reads that depth (the hand's travel less the slide up the pads) and
    steps 1.5 mm across the grasp. GF225 development seed 349: the second ring point ends 1.3 mm down; the
    step, to the side nearer the first attempt, goes in. Without it the ring ran out and the expert gave up."""
    task = InsertTube(TaskConfig(sensor="gf225", cameras=False), get_sensor("gf225"))
    stepped = run(task, 349)
    across = [c for c in stepped.memory["corrections"] if c["what"].startswith("step across the grasp")]
    ring = retries_of(stepped)
    print(f"GF225 seed 349: {len(ring)} ring steps, then across {[round(c['step_x_mm'], 2) for c in across]} mm "
          f"after a probe {across[0]['end_depth_mm']:.2f} mm below the entrance; {stepped.steps} steps")
    assert stepped.success and stepped.safe and len(across) == 1
    assert across[0]["end_depth_mm"] > 1.0 and across[0]["move_mm"] == pytest.approx(1.5)
    # the step is along the hole frame's x only, from the ring point the chamfer caught
    assert across[0]["step_y_mm"] == pytest.approx(ring[-1]["step_y_mm"])
    assert abs(across[0]["step_x_mm"] - ring[-1]["step_x_mm"]) == pytest.approx(1.5)
    monkeypatch.setattr(insert_tube, "CHAMFER_MISS_M", math.inf)
    ring_only = run(task, 349)
    assert not ring_only.success and not ring_only.memory["inside"]
    assert ring_only.memory["attempts"] == 1 + insert_tube.SEARCH_POINTS


def test_replaying_recorded_actions_reproduces_the_insertion_and_the_episode_validates(tmp_path):
    outcome = run_expert(TaskEpisodeSpec("insert_tube", 78, FAST))
    episode = outcome.episode
    assert outcome.success and outcome.safe and episode is not None and episode.meta.success
    assert len(retries_of(outcome)) == 6, "seed 78 misses six times: the most sliding in the grasp"
    names = episode.meta.primitive_names
    used = {names[i] for i in np.unique(episode["scene/primitive"]) if i >= 0}
    assert {"probe", "retry", "insert"} <= used
    task = InsertTube(FAST, PROFILE)
    session = TaskSession(task)
    try:
        session.reset(episode.meta.seed)
        for action in episode["robot/action"][:-1]:
            state = session.step(action)
        assert task.success(state)
        assert np.linalg.norm(state.objects["tube"][:3] - episode["scene/objects/tube/pose"][-1][:3]) < 1e-3
    finally:
        session.close()
    # the validators pass it, the pads' recorded slip included (the task's own max_pad_slip_mm)
    writer = DatasetWriter.open(tmp_path / "ds")
    writer.add(episode)
    report = validate(str(tmp_path / "ds"))
    failed = [c.rule for c in report.episodes[episode.meta.episode_id].checks if c.status == "fail"]
    assert not failed, failed


def test_the_bore_is_round_to_its_radius_and_a_tube_through_the_rim_is_caught():
    bore = Bore(radius_m=0.01025, depth_m=0.05, chamfer_m=0.002)
    model = mujoco.MjModel.from_xml_string(
        f'<mujoco><compiler angle="radian"/><worldbody><body>{bore.walls_xml("b")}</body></worldbody></mujoco>')
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    hit = np.zeros(1, np.int32)
    for z in (-0.004, -0.03):  # below the chamfer: every direction meets a wall between 10.25 and 10.34 mm
        dists = [mujoco.mj_ray(model, data, np.array([0, 0, z]), np.array([math.cos(a), math.sin(a), 0.0]), None, 1,
                               -1, hit) for a in np.linspace(0, 2 * math.pi, 73)]
        assert 0.01025 - 1e-6 <= min(dists) and max(dists) <= 0.01025 / math.cos(math.pi / bore.n_walls) + 1e-6
    centred = np.array([0, 0, -0.03 + TUBE_HALF_M, 1, 0, 0, 0])
    ident = np.array([1.0, 0, 0, 0])
    assert tube_in_solid_mm(centred, TUBE_RADIUS_M, TUBE_HALF_M, np.zeros(3), ident, bore) == 0.0
    through_rim = centred + np.array([0.004, 0, 0, 0, 0, 0, 0])
    assert tube_in_solid_mm(through_rim, TUBE_RADIUS_M, TUBE_HALF_M, np.zeros(3), ident, bore) == pytest.approx(3.75)


def test_success_needs_the_tube_3_cm_deep_and_centred():
    task = InsertTube(FAST, PROFILE)
    session = TaskSession(task)
    try:
        state = session.reset(0)
        assert not task.success(state)  # it starts above the hole
        pos, quat = task.hole_pose(session.layout)
        mat = quat_to_mat(quat)

        def tube_at(x_mm: float, depth_mm: float) -> Any:
            centre = pos + mat @ np.array([x_mm / 1000, 0.0, TUBE_HALF_M - depth_mm / 1000])
            return replace(state, objects={"tube": np.array([*centre, *quat])})

        assert task.success(tube_at(0.0, 31.0)) and task.success(tube_at(4.9, 31.0))
        assert not task.success(tube_at(0.0, 29.0)) and not task.success(tube_at(5.1, 31.0))
    finally:
        session.close()
