"""The task kit on Lift Can: the expert's success over 100 seeds, what its correction is worth, the zero
policy, replay from recorded actions, the Gymnasium checks, and `univtac-data generate task`."""

from __future__ import annotations

import math
import os
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from univtac_data import Dataset
from univtac_data.episode import content_hash
from univtac_data.generators.scene import sim as sim_module
from univtac_data.generators.scene.touch import read_touch
from univtac_data.generators.tactile.gap_field import gap_field
from univtac_data.generators.tactile import GAP_FAR_MM, sensor_grid
from univtac_data.generators.tasks.base import EVAL_SEED_BASE, TaskConfig
from univtac_data.generators.tasks.collect import TaskEpisodeSpec, run_expert
from univtac_data.generators.tasks.registry import TASK_NAMES, make_task
from univtac_data.generators.tasks.session import TaskSession
from univtac_data.schema.sensors import get_sensor

os.environ.setdefault("MUJOCO_GL", "egl")
FAST = TaskConfig(cameras=False)


def cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "univtac_data.cli.main", *args], capture_output=True, text=True,
                          timeout=900, env={**os.environ, "MUJOCO_GL": "egl"})


@pytest.mark.slow
def test_lift_can_expert_succeeds_on_100_seeds_and_its_correction_matters():
    outcomes = [run_expert(TaskEpisodeSpec("lift_can", seed, FAST), record=False) for seed in range(100)]
    successes = sum(o.success for o in outcomes)
    assert successes >= 95, [o.seed for o in outcomes if not o.success]
    assert all(o.safe for o in outcomes), [(o.seed, o.violation) for o in outcomes if not o.safe]
    corrected = [o for o in outcomes if o.memory["corrections"]]
    assert len(corrected) >= 50  # the camera's yaw error is 6-18 deg: most grasps need squaring
    # the correction's estimate from touch matches the deliberate vision error it corrects (sign and size)
    task = make_task("lift_can", FAST)
    for o in corrected[:10]:
        layout = task.sample_layout(np.random.default_rng(o.seed))
        first = o.memory["corrections"][0]
        assert first["signal"].startswith("contact patch")
        assert first["angle_deg"] == pytest.approx(-math.degrees(layout["seen_yaw_error_rad"]), abs=2.0)
    without = [run_expert(TaskEpisodeSpec("lift_can", seed, FAST), record=False, corrections=False)
               for seed in range(30)]
    assert sum(o.success for o in without) <= 0.5 * 30  # the correction is what makes the task work


@pytest.mark.parametrize("name", TASK_NAMES)
def test_zero_policy_never_succeeds(name):
    task = make_task(name, FAST)
    for seed in range(2):
        session = TaskSession(task)
        session.reset(EVAL_SEED_BASE + seed)
        for _ in range(task.max_steps):
            state = session.step(session.last_action)
        assert not task.success(state)
        session.close()


def test_replaying_recorded_actions_reproduces_the_episode():
    outcome = run_expert(TaskEpisodeSpec("lift_can", 7, FAST))
    episode = outcome.episode
    assert outcome.success and episode is not None and episode.meta.success
    actions = episode["robot/action"]
    assert actions.shape == (episode.meta.n_frames, 8) and episode.meta.n_frames == outcome.steps + 1
    task = make_task("lift_can", FAST)
    session = TaskSession(task)
    session.reset(episode.meta.seed)
    for action in actions[:-1]:
        state = session.step(action)
    assert task.success(state)
    final = episode["scene/objects/can/pose"][-1]
    assert np.linalg.norm(state.objects["can"][:3] - final[:3]) < 1e-3
    session.close()


def test_the_recorded_episode_shows_the_correction_and_the_primitives():
    outcome = run_expert(TaskEpisodeSpec("lift_can", 3, FAST))
    episode = outcome.episode
    assert episode is not None
    names = episode.meta.primitive_names
    used = {names[i] for i in np.unique(episode["scene/primitive"]) if i >= 0}
    assert {"grasp", "regrasp", "lift", "rotate"} <= used
    task_meta = episode.meta.extra["task"]
    assert task_meta["memory"]["corrections"][0]["what"] == "grasp squareness"
    assert task_meta["safe"] and task_meta["max_indentation_mm"] <= get_sensor("gelsight_mini").safe_indentation_mm


def test_touch_reading_of_a_band_and_of_a_tilted_strip():
    grid = sensor_grid(get_sensor("gelsight_mini"), 1)
    x, y = grid.mesh()
    band = np.where(np.abs(y) < 2.0, -0.4, GAP_FAR_MM)  # a can pressed square across the pad
    reading = read_touch(band, grid)
    assert reading.touching and reading.span_x_mm > 25.0 and reading.fill > 0.95
    assert abs(reading.axis_angle_rad) < 0.01 and reading.max_depth_mm == pytest.approx(0.4)
    tilt = math.radians(10)
    strip = np.where((np.abs(y) < 2.0) & (x < -10.0), -(x + 10.0) * -math.tan(tilt) - 0.0, GAP_FAR_MM)
    strip = np.where(strip < 0, strip, GAP_FAR_MM)
    edge = read_touch(strip, grid)
    assert edge.centroid_mm[0] < -10.0 and math.atan2(edge.max_depth_mm, edge.span_x_mm) == pytest.approx(tilt, abs=0.02)
    assert not read_touch(np.full(grid.shape, GAP_FAR_MM), grid).touching


def _cylinder_strip(grid, angle_rad: float, offset_mm: tuple[float, float], depth_mm, radius_mm: float = 32.5):
    """Gap field (mm) of a cylinder lying on the pad, its axis at ``angle_rad`` from +x through ``offset_mm``,
    pressed ``depth_mm(s)`` deep at ``s`` mm along its axis (deeper at one end when that is not constant)."""
    x, y = grid.mesh()
    ux, uy = math.cos(angle_rad), math.sin(angle_rad)
    along = (x - offset_mm[0]) * ux + (y - offset_mm[1]) * uy
    across = -(x - offset_mm[0]) * uy + (y - offset_mm[1]) * ux
    gap = across**2 / (2 * radius_mm) - depth_mm(along)
    return np.where(gap < 0, gap, GAP_FAR_MM)


@pytest.mark.parametrize("sensor", ["gf225", "gelsight_mini"])
@pytest.mark.parametrize("angle_deg", [100.0, 75.0, 20.0, -15.0])
def test_the_chord_line_is_a_cylinders_axis_where_the_principal_direction_is_not(sensor, angle_deg):
    """A bottle's strip, pressed deeper at one end and cut off by the image's border (as the GF225 holds a
    bottle 5-30 deg off its pads' axis): the midpoints of the patch's chords lie on the axis, whatever the
    press; the patch's principal direction leans towards the wide end."""
    grid = sensor_grid(get_sensor(sensor), 1)
    angle = math.radians(angle_deg)
    wedge = _cylinder_strip(grid, angle, (1.5, -2.0), lambda s: np.clip(0.1 + 0.03 * s, 0.0, None))
    reading = read_touch(wedge, grid)
    expected = (angle + math.pi / 2) % math.pi - math.pi / 2
    assert reading.chord_line_angle_rad is not None
    assert abs(reading.chord_line_angle_rad - expected) < math.radians(0.5)
    assert abs(reading.axis_angle_rad - expected) > math.radians(4.0)  # what the chord line is for
    # the same patch read through a window of the grid (the gap field's box): the same line
    rows, cols = np.nonzero(wedge < 0)
    box = (slice(rows.min(), rows.max() + 1), slice(cols.min(), cols.max() + 1))
    assert read_touch(wedge, grid, box).chord_line_angle_rad == pytest.approx(reading.chord_line_angle_rad)
    # an even press (the image's rectangle alone cuts such a strip unevenly, so its principal direction
    # is 1-3 deg off too)
    even = read_touch(_cylinder_strip(grid, angle, (0.0, 0.0), lambda s: np.full_like(s, 0.3)), grid)
    assert abs(even.chord_line_angle_rad - expected) < math.radians(0.5)


def test_the_chord_line_leaves_out_chords_the_border_cuts():
    grid = sensor_grid(get_sensor("gelsight_mini"), 1)
    # a strip at 60 deg that leaves the image through its right side: its chords there are cut short (kept,
    # they would turn the line by 2.4 deg)
    half_width = grid.x_mm[-1]
    side = _cylinder_strip(grid, math.radians(60), (half_width - 4.0, 0.0), lambda s: np.full_like(s, 0.3))
    assert (side[:, -1] < 0).any()
    assert read_touch(side, grid).chord_line_angle_rad == pytest.approx(math.radians(60), abs=math.radians(0.5))
    # a strip at 45 deg that ends square inside the image (a bottle's body ends at its base): chords taken
    # along the grid's rows or columns would cut across that end, chords across the strip do not
    for angle_deg in (45.0, -40.0):
        ends = _cylinder_strip(grid, math.radians(angle_deg), (0.0, 0.0), lambda s: np.where(s > -4.0, 0.3, 0.0))
        line = read_touch(ends, grid).chord_line_angle_rad
        assert line == pytest.approx(math.radians(angle_deg), abs=math.radians(0.5))
    tiny = np.full(grid.shape, GAP_FAR_MM)
    tiny[0:2, 100:103] = -0.1  # six cells on the top border: every chord is cut
    reading = read_touch(tiny, grid)
    assert reading.touching and reading.chord_line_angle_rad is None


@pytest.mark.parametrize("contact_method", ["geometric", "elastic"])
def test_touch_after_a_recorded_frame_reads_its_fields_and_equals_its_own(contact_method, monkeypatch):
    """An expert reads the pads right after a frame is recorded: touch() then takes the frame's gap fields
    (cut off at 0 or 2 mm, its own at 1 mm) and must read exactly what its own fields give; once the scene
    has moved it makes its own again. Grasp Classify: a knurl (textures) on a held cylinder."""
    session = TaskSession(make_task("grasp_classify_held", TaskConfig(cameras=False, contact_method=contact_method)),
                          record=True)
    try:
        session.reset(3)  # frame 0 recorded: the knurled cylinder in the grasp
        sim = session.sim
        checked = 0
        made = []
        monkeypatch.setattr(sim_module, "gap_field", lambda *a, **kw: made.append(1) or gap_field(*a, **kw))
        for k in range(4):
            assert sim._recorded_fields_current()
            made.clear()
            reused = sim.touch()
            assert not made  # no field made: the recorded ones were read
            kept, sim._recorded_geom_poses = sim._recorded_geom_poses, None
            own = sim.touch()
            sim._recorded_geom_poses = kept
            assert reused == own and own["left"].touching and own["right"].touching
            checked += 1
            sim.tick()  # the scene moves, nothing recorded: the fields are stale
            assert not sim._recorded_fields_current()
            session.step(session.last_action + np.array([0.004, 0, 0, 0, 0, 0, 0, 0]))
        assert checked == 4
    finally:
        session.close()


@pytest.mark.parametrize("name", TASK_NAMES)
def test_gymnasium_environment_passes_the_checker_and_resets_deterministically(name):
    import univtac_data.envs  # noqa: F401  (registers the environments)

    env = gym.make(make_task(name).gym_id, camera_size=(64, 48))
    assert env.spec is not None and env.spec.max_episode_steps == make_task(name).max_steps
    check_env(env.unwrapped)
    first, info = env.reset(seed=11)
    again, _ = env.reset(seed=11)
    for key in first["pixels"]:
        assert np.array_equal(first["pixels"][key], again["pixels"][key]), key
    assert np.array_equal(first["agent_pos"], again["agent_pos"]) and first["agent_pos"].dtype == np.float32
    assert set(first["pixels"]) == {"head", "wrist", "tactile_left", "tactile_right"}
    assert not info["is_success"] and info["safety"]["ok"]
    with pytest.raises(ValueError, match="non-finite"):
        env.step(np.full(8, np.nan, np.float32))
    assert env.render().shape == (48, 64, 3)
    env.close()


def test_generation_evaluation_and_the_environment_share_one_time_limit(monkeypatch):
    """``max_steps`` counts 50 Hz steps: at 25 Hz the expert is cut at half as many (the same seconds) when it
    generates, the environment truncates there, and a dataset records that limit."""
    from univtac_data.envs import TaskEnv
    from univtac_data.envs.evaluate import step_limit
    from univtac_data.generators.tasks.base import time_limited_steps
    from univtac_data.generators.tasks.lift_can import LiftCan

    assert [time_limited_steps(300, hz) for hz in (50.0, 25.0, 10.0, 100.0)] == [300, 150, 60, 600]
    monkeypatch.setattr(LiftCan, "max_steps", 40)  # the expert needs more: it is cut at the limit
    slow = TaskConfig(cameras=False, rate_hz=25.0)
    outcome = run_expert(TaskEpisodeSpec("lift_can", 3, slow))
    assert outcome.steps == 20 and not outcome.success
    assert outcome.episode is not None and outcome.episode.meta.extra["task"]["max_steps"] == 20
    env = TaskEnv("lift_can", cameras=False, rate_hz=25.0)
    try:
        assert step_limit(env) == env.task.step_limit == 20
        env.reset(seed=3)
        truncated = [env.step(env.session.last_action.astype(np.float32))[3] for _ in range(20)]
        assert truncated == [False] * 19 + [True]
    finally:
        env.close()


def test_an_expert_rollout_takes_each_step_once_and_closes_its_session():
    """Every caller runs the expert through ``expert_rollout``: a step asked for must be taken before the next
    (the expert decides from the state it left), and the session is closed when the block ends."""
    from univtac_data.generators.tasks.expert_rollout import expert_rollout

    task = make_task("lift_can", FAST)
    with expert_rollout(task, 3) as run:
        steps = run.steps()
        next(steps)
        with pytest.raises(RuntimeError, match="lift_can: expert step 0 was not taken"):
            next(steps)
    assert run.session.sim is None

    def first_actions(n: int) -> list[np.ndarray]:
        with expert_rollout(task, 3) as run:
            actions = []
            for step in run.steps():
                before = run.state
                assert run.take(step) is run.state is not before
                actions.append(step.action.copy())
                if len(actions) == n:
                    break
            assert run.session.steps == n
            return actions

    assert all(np.array_equal(a, b) for a, b in zip(first_actions(3), first_actions(3)))


def test_delta_actions_move_the_target():
    import univtac_data.envs  # noqa: F401

    env = gym.make("univtac/LiftCan-v0", cameras=False, action_mode="delta", tactile_extras=True)
    obs, _ = env.reset(seed=1)
    start = obs["agent_pos"][:3].copy()
    for _ in range(10):
        obs, *_ = env.step(np.array([0, 0, 0.01, 0, 0, 0, 0], np.float32))
    assert obs["agent_pos"][2] - start[2] == pytest.approx(0.1, abs=0.01)
    assert obs["tactile"]["left_depth_mm"].shape == (240, 320)
    env.close()


@pytest.mark.slow
def test_generate_task_cli_is_the_same_for_any_worker_count_and_resumes(tmp_path):
    one, two = tmp_path / "one", tmp_path / "two"
    common = ["generate", "task", "lift_can", "--episodes", "2", "--camera-size", "64x48"]
    first = cli(*common, "--out", str(one), "--workers", "1")
    assert first.returncode == 0, first.stderr
    assert "2 of 2 successful episodes" in first.stdout and "expert success" in first.stdout
    partial = cli(*common[:4], "1", "--camera-size", "64x48", "--out", str(two), "--workers", "2")
    assert partial.returncode == 0, partial.stderr
    resumed = cli(*common, "--out", str(two), "--workers", "2")
    assert resumed.returncode == 0 and "tried 1 seeds" in resumed.stdout, resumed.stdout
    a, b = Dataset.open(one), Dataset.open(two)
    assert a.episode_ids == b.episode_ids and len(a) == 2
    for eid in a.episode_ids:
        assert content_hash(a.load_episode(eid)) == content_hash(b.load_episode(eid))
    episode = a.load_episode(a.episode_ids[0])
    assert episode.meta.kind == "task" and episode.meta.success
    assert {c.name for c in episode.meta.cameras} == {"head", "wrist"}
    assert episode["scene/cameras/head/rgb"].shape[1:] == (48, 64, 3)
    assert episode["scene/cameras/head/rgb"].std() > 5  # not blank
    assert not any(p.name.startswith(".tmp") for p in (one / "episodes").iterdir())
    check = cli("validate", str(one))
    assert check.returncode == 0, check.stdout + check.stderr


def test_generate_task_refuses_bad_input(tmp_path):
    out = tmp_path / "x"
    unknown = cli("generate", "task", "no_such_task", "--out", str(out))
    assert unknown.returncode == 2 and "unknown task 'no_such_task'" in unknown.stderr
    assert len(unknown.stderr.strip().splitlines()) == 1 and not out.exists()
    rate = cli("generate", "task", "lift_can", "--rate", "60", "--out", str(out))
    assert rate.returncode == 2 and "whole number" in rate.stderr and not out.exists()
    size = cli("generate", "task", "lift_can", "--camera-size", "big", "--out", str(out))
    assert size.returncode == 2 and "--camera-size" in size.stderr and not out.exists()


def test_a_run_that_runs_out_of_seeds_says_why(tmp_path):
    """The demonstration seeds end below the evaluation seeds, and --max-seeds caps a run: a run stopped short by
    either says so (exit 1), instead of only "1 of 3 successful episodes"."""
    top = cli("generate", "task", "lift_can", "--episodes", "3", "--seed", "999999", "--no-cameras",
              "--out", str(tmp_path / "top"))
    assert top.returncode == 1 and "1 of 3 successful episodes" in top.stdout, top.stdout + top.stderr
    assert "lift_can: no demonstration seed left: seeds 999999 to 999999 are all tried (evaluation seeds start " \
           "at 1000000)" in top.stderr
    capped = cli("generate", "task", "lift_can", "--episodes", "2", "--max-seeds", "1", "--no-cameras",
                 "--out", str(tmp_path / "capped"))
    assert capped.returncode == 1 and "lift_can: gave up after seeds 0 to 0 (--max-seeds 1;" in capped.stderr
    zero = cli("generate", "task", "lift_can", "--max-seeds", "0", "--out", str(tmp_path / "zero"))
    assert zero.returncode == 2 and "--max-seeds: must be a positive integer" in zero.stderr
    assert not (tmp_path / "zero").exists()


@pytest.mark.slow
def test_generate_task_on_ray_into_zarr_gives_the_same_episode(tmp_path):
    pytest.importorskip("ray")
    local, remote = tmp_path / "local", tmp_path / "ray"
    common = ["generate", "task", "lift_can", "--episodes", "1", "--no-cameras", "--seed", "5"]
    assert cli(*common, "--out", str(local), "--workers", "1").returncode == 0
    run = cli(*common, "--out", str(remote), "--workers", "1", "--executor", "ray", "--format", "zarr")
    assert run.returncode == 0, run.stderr
    a, b = Dataset.open(local), Dataset.open(remote)
    assert b.info.storage == "zarr" and a.episode_ids == b.episode_ids
    assert content_hash(a.load_episode(a.episode_ids[0])) == content_hash(b.load_episode(b.episode_ids[0]))
