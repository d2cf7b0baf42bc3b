"""benchmarks/expert_heldout.py: the jobs cover exactly the held-out seeds asked for, the summary counts what
the experts did, and a short run from the command line writes its JSON and chart."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import expert_heldout  # noqa: E402

from univtac_data.generators.tasks.base import EVAL_SEED_BASE  # noqa: E402

os.environ.setdefault("MUJOCO_GL", "egl")


def test_jobs_cover_the_held_out_seeds_once():
    jobs = expert_heldout.chunked_jobs(["lift_can", "insert_tube"], episodes=23, without=12)
    for task in ("lift_can", "insert_tube"):
        on = [s for t, seeds, c in jobs if t == task and c for s in seeds]
        off = [s for t, seeds, c in jobs if t == task and not c for s in seeds]
        assert on == [EVAL_SEED_BASE + k for k in range(23)]
        assert off == on[:12]  # paired with the first seeds of the expert as shipped
    assert all(len(seeds) <= expert_heldout.CHUNK for _, seeds, _ in jobs)
    # more seeds without corrections than with them are capped, none asked gives none
    assert not [j for j in expert_heldout.chunked_jobs(["lift_can"], 5, 0) if not j[2]]
    assert sum(len(j[1]) for j in expert_heldout.chunked_jobs(["lift_can"], 5, 9) if not j[2]) == 5
    # a later block starts where asked; a task with nothing to switch off runs only as shipped
    later = expert_heldout.chunked_jobs(["grasp_classify_held"], 3, 3, first=200)
    assert later == [("grasp_classify_held", [EVAL_SEED_BASE + 200 + k for k in range(3)], True)]


def test_summary_counts_failures_and_violations():
    rows = [{"seed": 7, "success": True, "safe": True, "steps": 100, "violation": None, "in_hand_slip_mm": 1.0,
             "cpu_s": 1.0},
            {"seed": 5, "success": False, "safe": True, "steps": 300, "violation": None, "in_hand_slip_mm": 3.0,
             "cpu_s": 3.0},
            {"seed": 6, "success": True, "safe": False, "steps": 200, "violation": "slip", "in_hand_slip_mm": 12.0,
             "cpu_s": 2.0}]
    s = expert_heldout.summarise(rows)
    assert (s["n"], s["successes"], s["unsafe"], s["kept"]) == (3, 2, 1, 1)  # kept: successful and safe
    assert s["success_rate"] == pytest.approx(2 / 3) and s["mean_steps"] == pytest.approx(200)
    assert s["in_hand_slip_mm"] == pytest.approx([1.0, 3.0, 12.0])  # min, median, max
    lo, hi = s["wilson95"]
    assert lo < 2 / 3 < hi
    # every seed that failed or was unsafe, in seed order, so it can be replayed
    assert [f["seed"] for f in s["failures"]] == [5, 6] and s["failures"][1]["violation"] == "slip"


def test_a_short_run_writes_json_and_chart(tmp_path, monkeypatch):
    monkeypatch.setattr(expert_heldout, "RESULTS", tmp_path)
    monkeypatch.setattr(expert_heldout, "FIGURES", tmp_path)
    monkeypatch.setattr(sys, "argv", ["expert_heldout.py", "--tasks", "insert_tube", "--episodes", "2",
                                      "--without", "1", "--workers", "1", "--name", "t"])
    assert expert_heldout.main() == 0
    out = json.loads((tmp_path / "t.json").read_text())
    expert = out["tasks"]["insert_tube"]["expert"]
    assert expert["n"] == 2 and out["tasks"]["insert_tube"]["without_corrections"]["n"] == 1
    assert expert["successes"] == 2 and expert["unsafe"] == 0  # seeds 1,000,000 and 1,000,001: the expert succeeds
    assert (tmp_path / "t.png").stat().st_size > 0


def test_an_unknown_task_is_refused(monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", ["expert_heldout.py", "--tasks", "lift_cup"])
    assert expert_heldout.main() == 2
    assert "unknown task(s) lift_cup" in capsys.readouterr().err


@pytest.mark.parametrize("args,message", [(["--sensor", "digit"], "invalid choice: 'digit'"),
                                          (["--episodes", "0"], "--episodes must be at least 1"),
                                          (["--first", "-1"], "--first must be 0 or more")])
def test_bad_options_get_a_one_line_error(monkeypatch, capsys, args, message):
    monkeypatch.setattr(sys, "argv", ["expert_heldout.py", *args])
    with pytest.raises(SystemExit) as exit_info:
        expert_heldout.main()
    assert exit_info.value.code == 2 and message in capsys.readouterr().err
