"""The univtac-data command line, end to end in subprocesses."""

from __future__ import annotations

import json
import subprocess
import sys

from factories import make_dataset

from univtac_data import Dataset, content_hash


def cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "univtac_data.cli.main", *args], capture_output=True, text=True,
                          timeout=300)


def test_info_summarises(tmp_path):
    root = make_dataset(tmp_path / "ds", "hdf5", 3, n_frames=5)
    result = cli("info", str(root))
    assert result.returncode == 0, result.stderr
    assert "episodes        3" in result.stdout and "frames          15" in result.stdout
    assert "gelsight_mini (3)" in result.stdout and "2.0 (hdf5)" in result.stdout
    summary = json.loads(cli("info", str(root), "--json").stdout)
    assert summary["episodes"] == 3 and summary["frames"] == 15
    assert summary["bytes"] == sum(r.bytes for r in Dataset.open(root).index.values())
    assert summary["bytes_per_frame"] == round(summary["bytes"] / 15)
    assert summary["sensors"] == {"gelsight_mini": 3} and summary["names"] == {"sphere": 3}


def test_convert_round_trip_and_resume(tmp_path):
    src = make_dataset(tmp_path / "h5", "hdf5", 2, cameras=("head",))
    result = cli("convert", str(src), str(tmp_path / "z"), "--to", "zarr")
    assert result.returncode == 0, result.stderr
    assert "content hashes verified" in result.stdout
    again = cli("convert", str(src), str(tmp_path / "z"), "--to", "zarr")  # resumes: nothing to do, still verified
    assert again.returncode == 0, again.stderr
    back = cli("convert", str(tmp_path / "z"), str(tmp_path / "h5b"), "--to", "hdf5")
    assert back.returncode == 0, back.stderr
    a, b = Dataset.open(src), Dataset.open(tmp_path / "h5b")
    assert [content_hash(a.load_episode(e)) for e in a.episode_ids] == \
        [content_hash(b.load_episode(e)) for e in b.episode_ids]


def test_convert_into_a_dataset_of_another_backend_is_refused(tmp_path):
    src = make_dataset(tmp_path / "h5", "hdf5", 1)
    other = make_dataset(tmp_path / "h5other", "hdf5", 1)
    result = cli("convert", str(src), str(other), "--to", "zarr")
    assert result.returncode == 2 and "holds a hdf5 dataset, not zarr" in result.stderr


def test_reindex(tmp_path):
    root = make_dataset(tmp_path / "ds", "zarr", 2)
    (root / "meta/episodes.parquet").unlink()
    result = cli("reindex", str(root))
    assert result.returncode == 0, result.stderr
    assert "indexed 2 episodes" in result.stdout
    assert Dataset.open(root).episode_ids == ["ep0", "ep1"]


def test_usage_errors_exit_non_zero():
    assert cli().returncode == 2
    assert cli("convert", "a", "b").returncode == 2  # --to is required
    version = cli("--version")
    assert version.returncode == 0 and "format 2.0" in version.stdout


def test_a_closed_stdout_is_not_an_error(tmp_path):
    """`univtac-data info PATH | head -1`: the reader leaves early; no traceback, exit 0."""
    root = make_dataset(tmp_path / "ds", "hdf5", 1, n_frames=2)
    proc = subprocess.Popen([sys.executable, "-m", "univtac_data.cli.main", "info", str(root)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    proc.stdout.close()  # before the command prints (importing takes far longer than this)
    with proc.stderr:
        stderr = proc.stderr.read()
    assert proc.wait(timeout=120) == 0 and "Traceback" not in stderr, stderr
