"""benchmarks/pivot_stability.py: every solver case reaches the compiled scene, and the whole-expert run under a
case is the task's own expert."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from pivot_stability import SweptTask, cases, label, run_expert_seed  # noqa: E402

os.environ.setdefault("MUJOCO_GL", "egl")

CASES = {label(case): case for case in cases()}


@pytest.mark.parametrize(("case_label", "timestep_s", "cone", "noslip", "impratio"), [
    ("default (1 ms, noslip 4, elliptic, impratio 1, press 0.09 mm)", 0.001, mujoco.mjtCone.mjCONE_ELLIPTIC, 4, 1.0),
    ("0.5 ms", 0.0005, mujoco.mjtCone.mjCONE_ELLIPTIC, 4, 1.0),
    ("noslip 0", 0.001, mujoco.mjtCone.mjCONE_ELLIPTIC, 0, 1.0),
    ("pyramidal", 0.001, mujoco.mjtCone.mjCONE_PYRAMIDAL, 4, 1.0),
    ("impratio 10", 0.001, mujoco.mjtCone.mjCONE_ELLIPTIC, 4, 10.0),
])
def test_each_solver_case_reaches_the_compiled_model(case_label, timestep_s, cone, noslip, impratio):
    task = SweptTask(CASES[case_label])
    model = mujoco.MjModel.from_xml_string(task.scene_xml(task.sample_layout(np.random.default_rng(0))))
    assert model.opt.timestep == pytest.approx(timestep_s)
    assert model.opt.cone == cone
    assert model.opt.noslip_iterations == noslip
    assert model.opt.impratio == pytest.approx(impratio)


def test_the_expert_under_the_kits_settings_succeeds_safely():
    run = run_expert_seed(CASES["default (1 ms, noslip 4, elliptic, impratio 1, press 0.09 mm)"], 0)
    assert run == {"seed": 0, "success": True, "safe": True, "finite": True, "first_violation": None}


def test_without_noslip_the_expert_loses_the_bottle():
    run = run_expert_seed(CASES["noslip 0"], 0)
    assert not run["success"] and not run["safe"]
    assert run["first_violation"].startswith("in-hand slip")
