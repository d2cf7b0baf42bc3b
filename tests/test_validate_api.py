"""The validators' public API: exports, rule registry and docs, report JSON, groups, episodes, workers."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from factories import make_dataset, make_episode
from pydantic import ValidationError
from test_validate_support import clean_and_broken, failing, refresh_safety

import univtac_data.validators as validators
from univtac_data.schema.sensors import SensorProfile
from univtac_data.validators import (
    GROUPS,
    RULES,
    Report,
    ValidationConfig,
    parse_groups,
    rule_table_markdown,
    rules_in,
    validate,
)

DOCS = Path(__file__).resolve().parents[1] / "spec" / "validation.md"


def test_exported_members():
    assert sorted(validators.__all__) == sorted(set(validators.__all__))
    for name in validators.__all__:
        assert getattr(validators, name) is not None, name
    public = {n for n in dir(validators) if not n.startswith("_")}
    assert {"validate", "Report", "ValidationConfig", "GROUPS"} <= public


def test_every_rule_is_documented_and_its_threshold_exists():
    rules = rules_in(GROUPS) + rules_in(GROUPS, scope="dataset")
    assert {r.name for r in rules} == set(RULES)
    for rule in rules:
        assert rule.name.split(".")[0] == rule.group and rule.doc.endswith(".")
        if rule.threshold is None:
            continue
        if rule.threshold.startswith("profile."):
            assert rule.threshold.split(".", 1)[1] in SensorProfile.model_fields
        else:
            assert rule.threshold in ValidationConfig.model_fields


def test_docs_quote_the_generated_rule_table():
    assert rule_table_markdown() in DOCS.read_text(), "regenerate the table in spec/validation.md"


def test_docs_list_every_config_default():
    text = DOCS.read_text()
    for name, field in ValidationConfig.model_fields.items():
        assert f"`{name}`" in text and f"| {field.default} |" in text, name


def test_config_is_typed_and_frozen():
    config = ValidationConfig(max_slip_held_mm=2.0)
    with pytest.raises(ValidationError):
        ValidationConfig(max_slip_held_mm=-1.0)
    with pytest.raises(ValidationError):
        config.max_slip_held_mm = 3.0  # type: ignore[misc]


def test_parse_groups():
    assert parse_groups(None) == GROUPS
    assert parse_groups("physics, schema") == ("schema", "physics")
    with pytest.raises(ValueError, match="chemistry"):
        parse_groups(("schema", "chemistry"))
    with pytest.raises(ValueError):
        parse_groups("")


@pytest.fixture(scope="module")
def broken_root(tmp_path_factory):
    episode = make_episode("gelsight_mini", 4, "ep1", seed=1)
    episode["tactile/left/normal_force_n"][2] = np.nan
    episode["robot/ee_pose"][1, 3] = 1.2
    refresh_safety(episode)
    return clean_and_broken(tmp_path_factory.mktemp("api") / "ds", episode)


def test_report_json_round_trip_is_strict(broken_root):
    report = validate(broken_root)
    text = report.to_json()
    data = json.loads(text)  # strict: NaN is the string "nan"
    assert data["ok"] is False and data["failed_episodes"] == ["ep1"]
    assert data["report_version"] == "1.0" and data["groups"] == list(GROUPS)
    finite = [c for c in data["episodes"]["ep1"]["checks"] if c["rule"] == "physics.finite"][0]
    assert finite["status"] == "fail" and finite["findings"][0]["values"] == ["nan"]
    assert finite["findings"][0]["frames"] == [2]
    assert Report.from_json(text) == report


def test_groups_select_rules(broken_root):
    report = validate(broken_root, groups=("safety",))
    rules = {c.rule for c in report.episodes["ep1"].checks}
    assert rules == {r.name for r in rules_in(("safety",))} | {"schema.readable"}
    assert report.dataset_checks == []
    assert failing(report, "ep1") == {"safety.grasp_force"}  # NaN force is not a safe force
    physics = validate(broken_root, groups="physics")
    assert failing(physics, "ep1") == {"physics.finite", "physics.quaternion_norm"}


def test_episode_selection(broken_root):
    report = validate(broken_root, episodes=["ep0"])
    assert list(report.episodes) == ["ep0"] and report.ok
    report = validate(broken_root, episodes=["ep0", "nope"])
    assert report.failed_episodes() == ["nope"]
    assert "not in the index" in report.episodes["nope"].check("schema.index_row").findings[0].message


def test_two_workers_give_the_same_report(tmp_path):
    root = make_dataset(tmp_path / "ds", storage="zarr", n_episodes=3, n_frames=3)
    (root / "episodes" / "ep2.zarr" / "zarr.json").write_text("{}")
    one = validate(root, workers=1)
    two = validate(root, workers=2)
    assert one == two and one.failed_episodes() == ["ep2"]


def test_workers_must_be_positive(broken_root):
    with pytest.raises(ValueError, match="workers"):
        validate(broken_root, workers=0)
