"""Schema rules and dataset-level checks: files, versions, fields, index, manifest."""

from __future__ import annotations

import json
import shutil

import h5py
import numpy as np
import pytest
from factories import make_dataset, make_episode
from test_validate_support import (
    STORAGES,
    edit_meta,
    episode_files,
    episode_path,
    failing,
    flip_byte,
    hdf5_chunk_offset,
    replace_array,
    set_version_attr,
)

from univtac_data.storage import CorruptFileError, DatasetNotFoundError, FormatVersionError, NotADatasetError
from univtac_data.storage.index import read_index, write_index
from univtac_data.storage.fs import Location
from univtac_data.validators import validate


@pytest.fixture(params=STORAGES)
def storage(request):
    return request.param


@pytest.fixture
def root(tmp_path, storage):
    return make_dataset(tmp_path / "ds", storage=storage, n_episodes=2, n_frames=4)


def test_clean_dataset_validates_clean(root, storage):
    report = validate(root)
    assert report.ok and report.failed_episodes() == []
    assert report.storage == storage and sorted(report.episodes) == ["ep0", "ep1"]
    for episode in report.episodes.values():
        assert episode.n_frames == 4
        statuses = {c.rule: c.status for c in episode.checks}
        task_rules = {r for r in statuses if ".task_" in r or r == "physics.camera_not_blank"}
        # the factory's indenter episodes have scene objects: only the task rules are skipped
        assert {r for r, s in statuses.items() if s != "pass"} == task_rules, statuses
        assert all(statuses[r] == "skip" for r in task_rules)
    assert [c.rule for c in report.dataset_checks] == ["schema.field_table", "schema.manifest", "schema.orphan_files"]


def test_missing_required_field(root, storage):
    replace_array(root, storage, "ep1", "tactile/left/slip_mm", None)
    report = validate(root)
    assert {"schema.fields_present", "schema.checksums"} <= failing(report, "ep1")
    assert report.episodes["ep1"].check("safety.slip_while_held").status == "skip"
    assert report.episodes["ep0"].ok


def test_missing_group(root, storage):
    replace_array(root, storage, "ep1", "tactile/left", None)
    report = validate(root)
    finding_fields = {f.field for f in report.episodes["ep1"].check("schema.fields_present").findings}
    assert "tactile/left/depth_um" in finding_fields and "tactile/left/markers_px" in finding_fields
    assert report.failed_episodes() == ["ep1"]


def test_unknown_field(root, storage):
    replace_array(root, storage, "ep1", "extra/notes", np.zeros(4, np.float32))
    assert "schema.fields_present" in failing(validate(root), "ep1")


def test_wrong_shape(root, storage):
    markers = make_episode("gelsight_mini", 4, "ep1", seed=1)["tactile/right/markers_px"][:, :-1]
    replace_array(root, storage, "ep1", "tactile/right/markers_px", np.ascontiguousarray(markers))
    report = validate(root)
    (finding,) = report.episodes["ep1"].check("schema.shape").findings
    assert finding.field == "tactile/right/markers_px" and "(4, 63, 2)" in finding.message
    assert report.episodes["ep1"].check("physics.markers_at_rest").status == "skip"


def test_file_that_is_not_hdf5_or_zarr(root, storage):
    for path in episode_files(root, storage, "ep0"):
        path.write_bytes(b"this is not an episode\n")
    report = validate(root)
    assert {"schema.readable", "schema.checksums"} <= failing(report, "ep0")
    assert report.failed_episodes() == ["ep0"]


def test_episode_missing_on_disk(root, storage):
    shutil.rmtree(episode_path(root, storage, "ep1")) if storage == "zarr" else \
        episode_path(root, storage, "ep1").unlink()
    report = validate(root)
    assert failing(report, "ep1") == {"schema.index_row"}
    assert "missing on disk" in report.episodes["ep1"].check("schema.index_row").findings[0].message
    assert report.episodes["ep1"].check("physics.finite").status == "skip"
    assert report.episodes["ep0"].ok


def test_orphan_episode_file(root, storage):
    source = episode_path(root, storage, "ep0")
    target = source.with_name("stray" + source.suffix)
    shutil.copytree(source, target) if storage == "zarr" else shutil.copy(source, target)
    report = validate(root)
    assert not report.ok and report.failed_episodes() == []
    (check,) = [c for c in report.dataset_checks if c.rule == "schema.orphan_files"]
    assert check.status == "fail" and "stray" in check.findings[0].message


def test_index_row_disagrees_with_metadata(root):
    loc = Location.parse(str(root))
    rows = read_index(loc)
    rows["ep1"] = rows["ep1"].model_copy(update={"n_frames": 5, "max_slip_mm": 3.0})
    write_index(loc, list(rows.values()))
    report = validate(root)
    fields = {f.field for f in report.episodes["ep1"].check("schema.index_row").findings}
    assert fields == {"index.n_frames", "index.max_slip_mm"}
    assert report.failed_episodes() == ["ep1"]


def test_file_changed_after_writing(root, storage):
    path = episode_files(root, storage, "ep0")[-1]
    path.write_bytes(path.read_bytes() + b"\0")
    assert "schema.checksums" in failing(validate(root), "ep0")


def test_unreadable_manifest(root):
    (root / "meta" / "manifest.json").write_text("{ not json")
    report = validate(root)
    (check,) = [c for c in report.dataset_checks if c.rule == "schema.manifest"]
    assert check.status == "fail" and "manifest.json" in check.findings[0].message
    assert report.failed_episodes() == ["ep0", "ep1"]  # nothing to verify their files against


def test_field_table_drift(root):
    info = json.loads((root / "meta" / "info.json").read_text())
    for spec in info["fields"]:
        if spec["path"] == "tactile/{pad}/depth_um":
            spec["unit"] = "mm"
    (root / "meta" / "info.json").write_text(json.dumps(info))
    report = validate(root)
    (check,) = [c for c in report.dataset_checks if c.rule == "schema.field_table"]
    assert check.status == "fail" and "unit" in check.findings[0].message
    assert not report.ok


def test_sensor_without_profile(root):
    info = json.loads((root / "meta" / "info.json").read_text())
    info["sensors"] = {}
    (root / "meta" / "info.json").write_text(json.dumps(info))
    report = validate(root)
    assert failing(report, "ep0") == {"schema.episode_meta"}


def test_episode_of_another_major_version(root, storage):
    edit_meta(root, storage, "ep1", format_version="3.0")
    report = validate(root)
    assert {"schema.format_version", "schema.checksums"} == failing(report, "ep1")
    assert "3.0" in report.episodes["ep1"].check("schema.format_version").findings[0].message
    assert report.episodes["ep0"].ok


@pytest.mark.parametrize("attr", [None, "1.0"])
def test_the_files_own_format_version_attribute_is_checked(root, storage, attr):
    set_version_attr(root, storage, "ep1", attr)
    report = validate(root)
    assert "schema.format_version" in failing(report, "ep1") and report.episodes["ep0"].ok  # (and checksums)
    message = report.episodes["ep1"].check("schema.format_version").findings[0].message
    assert ("no format_version attribute" if attr is None else
            "format_version attribute is '1.0', its metadata says '2.0'") in message, message


def test_episode_of_a_newer_minor_version_is_read(root, storage):
    edit_meta(root, storage, "ep1", format_version="1.9", future_key="ignored")
    report = validate(root)
    assert report.episodes["ep1"].check("schema.format_version").status == "pass"
    assert failing(report, "ep1") == {"schema.checksums", "schema.index_row"}  # bytes and row's version changed


def test_garbled_metadata(root, storage):
    edit_meta(root, storage, "ep0", n_frames="many")
    report = validate(root)
    assert "schema.readable" in failing(report, "ep0") and report.failed_episodes() == ["ep0"]


def test_damaged_chunk_is_located_to_its_frame(tmp_path):
    root = make_dataset(tmp_path / "ds", storage="hdf5", n_episodes=2, n_frames=4)
    flip_byte(episode_path(root, "hdf5", "ep1"), hdf5_chunk_offset(root, "ep1", "tactile/left/depth_um", 2))
    report = validate(root)
    readable = report.episodes["ep1"].check("schema.readable")
    (finding,) = readable.findings
    assert finding.field == "tactile/left/depth_um" and finding.frames == [2]
    assert report.episodes["ep1"].check("safety.max_indentation").status == "pass"  # other frames still checked


def test_damaged_zarr_chunk(tmp_path):
    root = make_dataset(tmp_path / "ds", storage="zarr", n_episodes=2, n_frames=4)
    shard = episode_path(root, "zarr", "ep0") / "tactile" / "right" / "marked_rgb" / "c" / "0" / "0" / "0" / "0"
    flip_byte(shard, shard.stat().st_size // 3)
    report = validate(root)
    readable = report.episodes["ep0"].check("schema.readable")
    assert readable.status == "fail" and readable.findings[0].field == "tactile/right/marked_rgb"
    assert report.failed_episodes() == ["ep0"]


def test_hdf5_dataset_with_bool_stored_as_float(tmp_path):
    root = make_dataset(tmp_path / "ds", storage="hdf5", n_episodes=1, n_frames=4)
    with h5py.File(episode_path(root, "hdf5", "ep0"), "r+") as handle:
        mask = handle["tactile/left/contact_mask"][...]
        del handle["tactile/left/contact_mask"]
        handle["tactile/left/contact_mask"] = mask.astype(np.float32)
    (finding,) = validate(root).episodes["ep0"].check("schema.dtype").findings
    assert "must be bool (got float32)" in finding.message


@pytest.mark.parametrize("make, error", [
    (lambda p: None, DatasetNotFoundError),
    (lambda p: p.mkdir(), NotADatasetError),
    (lambda p: (p / "meta").mkdir(parents=True) or (p / "meta" / "info.json").write_text("{oops"), CorruptFileError),
])
def test_unusable_input_raises_one_clear_error(tmp_path, make, error):
    path = tmp_path / "ds"
    make(path)
    with pytest.raises(error) as info:
        validate(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_dataset_of_another_major_version_is_refused(root):
    info = json.loads((root / "meta" / "info.json").read_text())
    info["format_version"] = "3.0"
    (root / "meta" / "info.json").write_text(json.dumps(info))
    with pytest.raises(FormatVersionError, match="info.json"):
        validate(root)
