"""benchmarks/insertion_stability.py: every swept setting reaches the compiled scene (a setting that silently kept
the task's would chart the task twice), and the whole-expert run reports what the docs quote from it."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest

from univtac_data.generators.tasks.base import TaskConfig
from univtac_data.generators.tasks import insert_tube

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from insertion_stability import TASK_OPTION, SweptTube, label, run_expert_seed, settings  # noqa: E402

os.environ.setdefault("MUJOCO_GL", "egl")

ROWS = {label(row): row for row in settings()}


def compiled(row_label: str) -> mujoco.MjModel:
    row = ROWS[row_label]
    task = SweptTube(TaskConfig(cameras=False, timestep_s=row["timestep_s"]), row)
    layout = task.sample_layout(np.random.default_rng(0))
    return mujoco.MjModel.from_xml_string(task.scene_xml(layout))


def test_labels_are_unique_and_the_task_row_comes_first():
    rows = settings()
    assert len(ROWS) == len(rows)
    assert rows[0]["group"] == "task" and rows[0]["option"] == TASK_OPTION


@pytest.mark.parametrize(("row_label", "cone", "noslip", "solver"), [
    ("task (1 ms, boxes, solref 0.002 s, Newton)", mujoco.mjtCone.mjCONE_ELLIPTIC, 4, mujoco.mjtSolver.mjSOL_NEWTON),
    ("elliptic cone, noslip 0", mujoco.mjtCone.mjCONE_ELLIPTIC, 0, mujoco.mjtSolver.mjSOL_NEWTON),
    ("elliptic cone, noslip 1", mujoco.mjtCone.mjCONE_ELLIPTIC, 1, mujoco.mjtSolver.mjSOL_NEWTON),
    ("pyramidal cone, noslip 4", mujoco.mjtCone.mjCONE_PYRAMIDAL, 4, mujoco.mjtSolver.mjSOL_NEWTON),
    ("solver PGS", mujoco.mjtCone.mjCONE_ELLIPTIC, 4, mujoco.mjtSolver.mjSOL_PGS),
])
def test_each_solver_row_reaches_the_compiled_model(row_label, cone, noslip, solver):
    model = compiled(row_label)
    assert model.opt.cone == cone
    assert model.opt.noslip_iterations == noslip
    assert model.opt.solver == solver
    assert model.opt.timestep == pytest.approx(0.001)


def test_a_scene_without_the_option_it_sweeps_is_refused(monkeypatch):
    import insertion_stability

    monkeypatch.setattr(insertion_stability, "TASK_OPTION", 'cone="elliptic" noslip_iterations="9"')
    row = ROWS["elliptic cone, noslip 0"]
    task = SweptTube(TaskConfig(cameras=False), row)
    with pytest.raises(RuntimeError, match="no longer holds"):
        task.scene_xml(task.sample_layout(np.random.default_rng(0)))


def test_the_expert_run_reports_its_attempts_and_slip():
    run = run_expert_seed(ROWS["task (1 ms, boxes, solref 0.002 s, Newton)"], 0)
    assert run["success"] and run["safe"] and run["found_the_hole"]
    assert 1 <= run["attempts"] <= 3 + insert_tube.SEARCH_POINTS  # the first, the ring, two steps across
    assert 0.0 < run["max_in_hand_slip_mm"] < 10.0


def test_experts_only_reruns_the_expert_column_and_keeps_the_push(tmp_path, monkeypatch):
    import insertion_stability
    monkeypatch.setattr(insertion_stability, "plot", lambda rows, sdf: None)  # the docs' chart stays as it is
    task_label = "task (1 ms, boxes, solref 0.002 s, Newton)"
    stored = {"rows": [{"label": task_label, "inserted": 0.875, "us_per_step": 123.0, "expert_seeds": 1,
                        "expert_success": 0.0, "expert_success_95": [0.0, 0.79], "expert_safe": 0.0,
                        "expert_runs": []}], "sdf": {}}
    path = tmp_path / "insertion_stability.json"
    path.write_text(json.dumps(stored))
    insertion_stability.rerun_experts(path)
    row = json.loads(path.read_text())["rows"][0]
    assert row["inserted"] == 0.875 and row["us_per_step"] == 123.0  # the push trials and timings as stored
    assert row["expert_success"] == 1.0 and row["expert_safe"] == 1.0 and [r["seed"] for r in row["expert_runs"]] == [0]
    assert "experts_rerun" in json.loads(path.read_text())
    stored["rows"][0]["label"] = "a setting since removed"
    path.write_text(json.dumps(stored))
    with pytest.raises(SystemExit, match="insertion_stability.json: settings no longer in settings"):
        insertion_stability.rerun_experts(path)
