"""``univtac-data preview PATH --video OUT.mp4`` and ``--rerun FILE.rrd``: one episode to watch."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from factories import make_dataset

from univtac_data import Dataset
from univtac_data.export.episode_video import BAND_PX


def cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "univtac_data.cli.main", *args], capture_output=True, text=True,
                          timeout=300)


@pytest.fixture
def dataset(tmp_path: Path) -> Path:
    return make_dataset(tmp_path / "src", "hdf5", 2, n_frames=5, cameras=("head",), camera_depth=True)


def test_video_decodes_to_every_frame_of_the_episode(tmp_path, dataset):
    pytest.importorskip("av", reason="the [video] extra (PyAV) is not installed")
    from univtac_data.export.video import read_mp4

    out = tmp_path / "ep1.mp4"
    result = cli("preview", str(dataset), "--video", str(out), "--episode", "ep1")
    assert result.returncode == 0, result.stderr
    assert "ep1: 5 frames" in result.stdout
    frames = read_mp4(str(out))
    episode = Dataset.open(dataset).load_episode("ep1")
    h, w = episode["tactile/left/marked_rgb"].shape[1:3]
    camera_w = round(64 * h / 48)  # the 64 x 48 camera scaled to the tactile height
    assert frames.shape == (5, h + BAND_PX, camera_w + 4 * w, 3)  # camera, 2 x I_marked, 2 x depth
    # the left pad's I_marked is where the layout puts it, within H.264's loss
    for t in range(5):
        tile = frames[t, BAND_PX:, camera_w:camera_w + w].astype(np.int16)
        assert np.abs(tile - episode["tactile/left/marked_rgb"][t]).mean() < 3.0
    # the caption band carries text (white pixels) and the tiles are not blank
    assert (frames[:, :BAND_PX] > 200).any() and frames[:, BAND_PX:].std() > 10


def test_episode_without_cameras(tmp_path):
    pytest.importorskip("av", reason="the [video] extra (PyAV) is not installed")
    from univtac_data.export.video import read_mp4

    src = make_dataset(tmp_path / "plain", "zarr", 1, n_frames=3)
    result = cli("preview", str(src), "--video", str(tmp_path / "v.mp4"))
    assert result.returncode == 0, result.stderr
    assert read_mp4(str(tmp_path / "v.mp4")).shape[:2] == (3, 240 + BAND_PX)


def test_rerun_recording_holds_every_stream(tmp_path, dataset):
    pytest.importorskip("rerun", reason="the [rerun] extra (rerun-sdk) is not installed")
    from rerun.chunk import RrdReader

    out = tmp_path / "ep0.rrd"
    result = cli("preview", str(dataset), "--rerun", str(out))
    assert result.returncode == 0, result.stderr
    reader = RrdReader(out)
    assert [(r.application_id, r.recording_id) for r in reader.recordings()] == [("univtac_data", "ep0")]
    rows = {m.group(1): int(m.group(2)) for m in re.finditer(r"^(/\S+) rows=(\d+)", reader.store().summary(), re.M)}
    per_frame = ["/cameras/head/rgb", "/cameras/head/depth", "/world/ee", "/world/objects/indenter"]
    for pad in ("left", "right"):
        per_frame += [f"/tactile/{pad}/{n}" for n in ("marked", "marked/markers", "depth", "normal_force_n",
                                                       "slip_mm")]
    assert {path: rows.get(path) for path in per_frame} == {path: 5 for path in per_frame}
    assert rows["/primitive"] == 2  # logged when it changes: grasp, then rotate
    viewer = shutil.which("rerun")
    if viewer is not None:  # the viewer's own loader
        verify = subprocess.run([viewer, "rrd", "verify", str(out)], capture_output=True, text=True, timeout=120)
        assert verify.returncode == 0, verify.stderr


def test_bad_requests_are_one_line_and_write_nothing(tmp_path, dataset):
    for args, message in [
        (["--video", str(tmp_path / "a.mp4"), "--episode", "nope"], "no episode 'nope'"),
        (["--video", str(tmp_path / "a.mp4"), "--gallery"], "do not combine with --gallery"),
        (["--video", str(tmp_path / "missing" / "a.mp4")], "cannot write there"),
        (["--video", str(tmp_path / "a.mp4"), "--out", str(tmp_path / "a.png")], "separate run"),
        ([], "give --out FILE.png, --video OUT.mp4 or --rerun FILE.rrd"),
    ]:
        result = cli("preview", str(dataset), *args)
        assert result.returncode == 2, (args, result.stderr)
        assert message in result.stderr and len(result.stderr.strip().splitlines()) == 1, (args, result.stderr)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["src"]


def test_a_failed_video_leaves_no_file(tmp_path, dataset, monkeypatch):
    pytest.importorskip("av", reason="the [video] extra (PyAV) is not installed")
    from univtac_data.cli import main as cli_main
    from univtac_data.export import episode_video

    def broken(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(episode_video, "compose_frame", broken)
    assert cli_main.main(["preview", str(dataset), "--video", str(tmp_path / "x.mp4")]) == 130
    assert sorted(p.name for p in tmp_path.iterdir()) == ["src"]
