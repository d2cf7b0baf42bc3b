"""The task rules of the validators catch what they name: a success flag the final state contradicts,
actions outside the action space, blank camera frames; a real expert episode passes them all."""

from __future__ import annotations

import os

import numpy as np
import pytest

from univtac_data import DatasetWriter
from univtac_data.episode import Episode
from univtac_data.generators.tasks.base import TaskConfig
from univtac_data.generators.tasks.collect import TaskEpisodeSpec, run_expert
from univtac_data.validators import validate

os.environ.setdefault("MUJOCO_GL", "egl")
TASK_RULES = ("physics.task_success_agrees", "schema.task_actions_in_bounds", "physics.camera_not_blank",
              "safety.task_in_hand_slip")


@pytest.fixture(scope="module")
def recorded() -> Episode:
    outcome = run_expert(TaskEpisodeSpec("lift_can", 2, TaskConfig(camera_size=(32, 24))))
    assert outcome.episode is not None and outcome.success
    return outcome.episode


def _variant(episode: Episode, episode_id: str, **changes: np.ndarray) -> Episode:
    arrays = dict(episode.arrays)
    arrays.update(changes)
    meta = episode.meta.model_copy(update={"episode_id": episode_id})
    return Episode(meta=meta, arrays=arrays)


def _status(report, episode_id: str) -> dict[str, str]:
    return {c.rule: c.status for c in report.episodes[episode_id].checks if c.rule in TASK_RULES}


def test_task_rules_catch_what_they_name(tmp_path, recorded):
    writer = DatasetWriter.open(tmp_path / "ds")
    writer.add(_variant(recorded, "good"))
    flipped = _variant(recorded, "flipped")
    flipped.meta = flipped.meta.model_copy(update={"success": False})
    writer.add(flipped)
    actions = recorded["robot/action"].copy()
    actions[5, 7] = 0.5  # a 50 cm opening: outside the action space
    writer.add(_variant(recorded, "wide", **{"robot/action": actions}))
    head = recorded["scene/cameras/head/rgb"].copy()
    head[3] = 128
    writer.add(_variant(recorded, "blank", **{"scene/cameras/head/rgb": head}))
    report = validate(str(tmp_path / "ds"))
    assert set(_status(report, "good").values()) == {"pass"}
    assert _status(report, "flipped")["physics.task_success_agrees"] == "fail"
    assert _status(report, "wide")["schema.task_actions_in_bounds"] == "fail"
    blank = report.episodes["blank"].check("physics.camera_not_blank")
    assert blank.status == "fail" and blank.findings[0].frames == [3]
