"""benchmarks/pad_force_ratio.py: on a held can, MuJoCo's pad force and the tactile model's are both read on
the same frames, and a task the script does not know is refused in one line."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"
sys.path.insert(0, str(BENCHMARKS))

import pad_force_ratio  # noqa: E402

os.environ.setdefault("MUJOCO_GL", "egl")


def test_a_held_can_is_pressed_on_both_pads_in_both_models():
    row = pad_force_ratio.held_frames("lift_can", "gelsight_mini", 100)
    assert row["held_frames"] > 50  # the lift, the turn and the hold
    # the expert grasps to 0.5 mm on the Mini; both models give a force, MuJoCo's the larger
    assert row["indentation_mm_median"] == pytest.approx(0.5, abs=0.05)
    assert row["tactile_n_median"] > 2 * pad_force_ratio.HELD_FORCE_N
    lo, hi = row["ratio_p10_p90"]
    assert 1.0 < lo <= row["ratio_median"] <= hi


def test_an_unknown_task_is_refused_in_one_line():
    run = subprocess.run([sys.executable, str(BENCHMARKS / "pad_force_ratio.py"), "--tasks", "lift_cat"],
                         capture_output=True, text=True, cwd=BENCHMARKS)
    assert run.returncode == 2
    assert "unknown task(s) lift_cat" in run.stderr.strip().splitlines()[-1]
