"""Bad input: one clear line naming the file, a non-zero exit, never a traceback."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import h5py
import pytest
from factories import make_dataset

from univtac_data import CorruptFileError, Dataset, FormatVersionError, NotADatasetError
from univtac_data.storage import DatasetNotFoundError


def cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "univtac_data.cli.main", *args], capture_output=True, text=True,
                          timeout=120)


def assert_one_line_error(result: subprocess.CompletedProcess[str], *needles: str) -> None:
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("univtac-data: error: ")
    assert "Traceback" not in result.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]


def episode_file(root: Path, storage: str, eid: str = "ep0") -> Path:
    return root / "episodes" / (f"{eid}.h5" if storage == "hdf5" else f"{eid}.zarr")


def test_missing_path(tmp_path):
    with pytest.raises(DatasetNotFoundError, match="no such file"):
        Dataset.open(tmp_path / "nope")
    assert_one_line_error(cli("info", str(tmp_path / "nope")), str(tmp_path / "nope"), "no such file")


def test_directory_that_is_not_a_dataset(tmp_path):
    (tmp_path / "x.txt").write_text("hello")
    with pytest.raises(NotADatasetError):
        Dataset.open(tmp_path)
    assert_one_line_error(cli("info", str(tmp_path)), str(tmp_path), "not a univtac-data dataset")
    assert_one_line_error(cli("reindex", str(tmp_path)), "not a univtac-data dataset")


@pytest.mark.parametrize("storage", ["hdf5", "zarr"])
def test_newer_major_version_in_info_json(tmp_path, storage):
    root = make_dataset(tmp_path / "ds", storage, 1)
    info = json.loads((root / "meta/info.json").read_text())
    info["format_version"] = "3.0"
    (root / "meta/info.json").write_text(json.dumps(info))
    with pytest.raises(FormatVersionError, match=r"format 3\.0.*reads format 1\.x and 2\.x"):
        Dataset.open(root)
    assert_one_line_error(cli("info", str(root)), "info.json", "3.0", "2.x")


def test_newer_minor_version_is_read(tmp_path):
    root = make_dataset(tmp_path / "ds", "hdf5", 1)
    info = json.loads((root / "meta/info.json").read_text())
    info["format_version"] = "1.7"
    info["a_key_from_the_future"] = {"x": 1}
    (root / "meta/info.json").write_text(json.dumps(info))
    path = episode_file(root, "hdf5")
    with h5py.File(path, "r+") as f:
        meta = json.loads(f.attrs["univtac_meta"])
        meta["format_version"] = "1.7"
        meta["new_optional_key"] = [1, 2]
        meta["safety"]["new_nested_key"] = 3.0
        f.attrs["univtac_meta"] = json.dumps(meta)
        f.create_dataset("tactile/left/a_new_array", data=[1, 2, 3])
    ds = Dataset.open(root)
    episode = ds.load_episode("ep0")
    assert episode.meta.format_version == "1.7"
    assert "tactile/left/a_new_array" not in episode.arrays


def test_newer_major_version_in_an_episode(tmp_path):
    root = make_dataset(tmp_path / "ds", "hdf5", 1)
    path = episode_file(root, "hdf5")
    with h5py.File(path, "r+") as f:
        meta = json.loads(f.attrs["univtac_meta"])
        meta["format_version"] = "3.1"
        f.attrs["univtac_meta"] = json.dumps(meta)
    with pytest.raises(FormatVersionError, match=rf"{path}.*3\.1"):
        Dataset.open(root).load_episode("ep0")


@pytest.mark.parametrize("storage", ["hdf5", "zarr"])
def test_flipped_bytes_in_a_chunk_are_caught(tmp_path, storage):
    root = make_dataset(tmp_path / "ds", storage, 1, n_frames=3)
    if storage == "hdf5":
        target = episode_file(root, storage)
        with h5py.File(target, "r") as f:
            offset = f["tactile/left/marked_rgb"].id.get_chunk_info(1).byte_offset + 40
    else:
        target = episode_file(root, storage) / "tactile/left/marked_rgb/c/0/0/0/0"
        offset = 40
    data = bytearray(target.read_bytes())
    data[offset] ^= 0xFF
    target.write_bytes(bytes(data))
    with pytest.raises(CorruptFileError, match="tactile/left/marked_rgb") as error:
        Dataset.open(root).load_episode("ep0")
    assert str(episode_file(root, storage)) in str(error.value)
    problems = Dataset.open(root).verify_checksums()
    assert len(problems) == 1 and "SHA-256 differs" in problems[0] and str(target) in problems[0]


def test_truncated_hdf5_file(tmp_path):
    root = make_dataset(tmp_path / "ds", "hdf5", 2)
    path = episode_file(root, "hdf5")
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 3])
    with pytest.raises(CorruptFileError, match=rf"{path}: not a readable HDF5 file"):
        Dataset.open(root).load_episode("ep0")
    assert Dataset.open(root).load_episode("ep1").meta.episode_id == "ep1"  # the rest still reads


def test_a_file_that_is_not_hdf5(tmp_path):
    root = make_dataset(tmp_path / "ds", "hdf5", 1)
    episode_file(root, "hdf5").write_text("this is not an HDF5 file\n")
    with pytest.raises(CorruptFileError, match="not a readable HDF5 file"):
        Dataset.open(root).open_episode("ep0")


def test_missing_zarr_group_metadata(tmp_path):
    root = make_dataset(tmp_path / "ds", "zarr", 1)
    (episode_file(root, "zarr") / "zarr.json").unlink()
    with pytest.raises(CorruptFileError, match="ep0.zarr"):
        Dataset.open(root).open_episode("ep0")


def test_corrupt_index_names_the_file_and_the_fix(tmp_path):
    root = make_dataset(tmp_path / "ds", "hdf5", 1)
    (root / "meta/episodes.parquet").write_bytes(b"PAR1 garbage")
    assert_one_line_error(cli("info", str(root)), "episodes.parquet", "reindex")
    result = cli("reindex", str(root))
    assert result.returncode == 0, result.stderr
    assert len(Dataset.open(root)) == 1


def test_broken_info_json(tmp_path):
    root = make_dataset(tmp_path / "ds", "hdf5", 1)
    (root / "meta/info.json").write_text("{not json")
    assert_one_line_error(cli("info", str(root)), "info.json", "not valid JSON")


def test_reindex_reports_an_unreadable_episode_and_keeps_the_rest(tmp_path):
    root = make_dataset(tmp_path / "ds", "hdf5", 2)
    episode_file(root, "hdf5", "ep1").write_bytes(b"\x00" * 100)
    result = cli("reindex", str(root))
    assert result.returncode == 1
    assert "ep1.h5" in result.stderr and "Traceback" not in result.stderr
    assert Dataset.open(root).episode_ids == ["ep0"]


def test_convert_skips_a_corrupt_source_episode_and_exits_1(tmp_path):
    root = make_dataset(tmp_path / "ds", "hdf5", 3)
    episode_file(root, "hdf5", "ep1").write_bytes(b"junk")
    result = cli("convert", str(root), str(tmp_path / "out"), "--to", "zarr")
    assert result.returncode == 1 and "Traceback" not in result.stderr, result.stderr
    failed = [line for line in result.stderr.splitlines() if line.startswith("failed: ")]
    assert len(failed) == 1 and "ep1.h5: not a readable HDF5 file" in failed[0], result.stderr
    assert "2 converted, 0 already converted, 1 failed" in result.stdout
    assert Dataset.open(tmp_path / "out").episode_ids == ["ep0", "ep2"]  # the rest converted, complete only
