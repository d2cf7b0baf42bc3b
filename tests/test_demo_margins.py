"""benchmarks/demo_margins.py: the expert's margin to the safe indentation and the closing step before contact,
from synthetic arrays with known answers and from a recorded Lift Can episode."""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

import numpy as np
import pytest

from univtac_data import DatasetWriter
from univtac_data.generators.tasks.base import TaskConfig
from univtac_data.generators.tasks.collect import TaskEpisodeSpec, run_expert

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

from demo_margins import approach_margin, dataset_margins, json_number, main  # noqa: E402

os.environ.setdefault("MUJOCO_GL", "egl")


def test_margin_and_closing_step_from_known_arrays():
    opening_m = np.array([0.080, 0.078, 0.0765, 0.0764, 0.0763])
    left = np.array([0.0, 0.0, 0.0, 1.0, 2.0])
    right = np.array([0.0, 0.0, 0.5, 1.0, 2.0])  # one pad touches a step earlier: both touch at frame 3
    margin = approach_margin(opening_m, left, right, peak_indentation_mm=0.7, safe_indentation_mm=1.5)
    assert margin.margin_mm == pytest.approx(0.8)
    assert margin.closing_mm_per_step == pytest.approx(1.5)  # frame 1 -> 2, the step before both touch
    assert margin.late_steps_to_unsafe == pytest.approx(0.8 / 0.75)


def test_an_episode_that_starts_in_contact_has_no_approach():
    forces = np.ones(4)
    margin = approach_margin(np.full(4, 0.03), forces, forces, 0.3, 1.5)
    assert margin.closing_mm_per_step is None and margin.late_steps_to_unsafe is None
    still = approach_margin(np.full(4, 0.03), np.array([0, 0, 1, 1.0]), np.array([0, 0, 1, 1.0]), 0.3, 1.5)
    assert still.closing_mm_per_step == 0 and math.isinf(still.late_steps_to_unsafe)
    assert json_number(still.late_steps_to_unsafe) is None and json_number(1.5) == 1.5  # the JSON stays standard


def test_a_recorded_lift_can_episode(tmp_path):
    outcome = run_expert(TaskEpisodeSpec("lift_can", 0, TaskConfig(camera_size=(32, 24))))
    assert outcome.episode is not None
    root = tmp_path / "ds"
    DatasetWriter.open(root).add(outcome.episode)
    row = dataset_margins(root)
    episode = row["per_episode"][0]
    assert row["task"] == "lift_can" and row["episodes"] == 1
    assert episode["peak_indentation_mm"] == pytest.approx(outcome.episode.meta.safety.max_indentation_mm)
    assert 0 < episode["margin_mm"] < 1.5
    assert episode["closing_mm_per_step"] > 0  # the fingers were closing when they touched the can
    assert main([str(root), "--json", str(tmp_path / "m.json"), "--chart", str(tmp_path / "m.png")]) == 0
    assert (tmp_path / "m.png").stat().st_size > 0


def test_an_empty_dataset_is_refused(tmp_path):
    DatasetWriter.open(tmp_path / "empty")
    with pytest.raises(SystemExit, match="no episodes"):
        dataset_margins(tmp_path / "empty")


def test_a_missing_dataset_is_one_line(tmp_path):
    with pytest.raises(SystemExit, match="demo_margins: .*nowhere.*no such file"):
        main([str(tmp_path / "nowhere"), "--json", str(tmp_path / "m.json"), "--chart", str(tmp_path / "m.png")])
    assert not (tmp_path / "m.json").exists()
