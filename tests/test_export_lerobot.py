"""``univtac-data export lerobot``: the LeRobot v3.0 export, read back by Hugging Face ``datasets`` (LeRobot's
own table reader), by PyAV for the videos, and checked by ``lerobot-doctor``; values compared with the source."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from factories import make_dataset

from univtac_data import Dataset
from univtac_data.export import export_lerobot
from univtac_data.storage.errors import DatasetError


def cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "univtac_data.cli.main", *args], capture_output=True, text=True,
                          timeout=300)


def load_frames(root: Path):
    """The data Parquet files as LeRobot loads them: ``datasets.Dataset.from_parquet`` with the features the
    files declare, images decoded to PIL."""
    datasets = pytest.importorskip("datasets", reason="the [lerobot] extra (Hugging Face datasets) is not installed")
    paths = sorted(str(p) for p in (root / "data").glob("chunk-*/file-*.parquet"))
    features = datasets.Features.from_arrow_schema(pq.read_schema(paths[0]))
    # python values, not the "numpy" format: that one narrows float64 to float32 and widens ints to int64
    return datasets.Dataset.from_parquet(paths, features=features)


def episode_rows(root: Path) -> list[dict]:
    rows = pq.read_table(root / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    return sorted(rows, key=lambda r: r["episode_index"])


def source_expectations(src: Path) -> list[dict[str, np.ndarray]]:
    """Per episode (in export order): every exported feature computed from the source arrays."""
    dataset = Dataset.open(src)
    out = []
    for episode_id in dataset.episode_ids:
        ep = dataset.load_episode(episode_id)
        a = ep.arrays
        values = {
            "observation.state": np.concatenate([a["robot/ee_pose"], a["robot/gripper_width_m"][:, None],
                                                 a["robot/finger_pos_m"]], axis=1).astype(np.float32),
            "action": a["robot/action"],
            "observation.primitive": a["scene/primitive"].astype(np.int64),  # int16 widened
            "observation.timestamp_ns": a["timestamps_ns"],
        }
        for camera in ep.meta.cameras:
            values[f"observation.images.{camera.name}"] = a[f"scene/cameras/{camera.name}/rgb"]
            if camera.depth:
                values[f"observation.depth.{camera.name}"] = a[f"scene/cameras/{camera.name}/depth_m"]
        for pad in ep.meta.pads:
            t = f"tactile/{pad}/"
            values[f"observation.images.tactile_{pad}"] = a[t + "marked_rgb"]
            values[f"observation.images.tactile_{pad}_pure"] = a[t + "pure_rgb"]
            for name in ("depth_um", "markers_px", "object_pose", "normal_force_n", "shear_force_n", "slip_mm"):
                values[f"observation.tactile.{pad}.{name}"] = a[t + name]
        for obj in ep.meta.objects:
            values[f"observation.objects.{obj}.pose"] = a[f"scene/objects/{obj}/pose"]
        out.append(values)
    return out


def check_against_source(src: Path, dst: Path, *, video: bool) -> None:
    info = json.loads((dst / "meta/info.json").read_text())
    expected = source_expectations(src)
    lengths = [len(e["action"]) for e in expected]
    assert info["codebase_version"] == "v3.0"
    assert info["total_episodes"] == len(expected) and info["total_frames"] == sum(lengths)
    assert set(info["features"]) == set(expected[0]) | {"timestamp", "frame_index", "episode_index", "index",
                                                          "task_index"}
    image_keys = [k for k, f in info["features"].items() if f["dtype"] in ("image", "video")]
    assert all(info["features"][k]["dtype"] == ("video" if video else "image") for k in image_keys)

    # episode boundaries: contiguous global index ranges, in source order, with the source's episode ids
    rows = episode_rows(dst)
    source_ids = Dataset.open(src).episode_ids
    starts = np.concatenate([[0], np.cumsum(lengths)])
    assert [r["univtac/episode_id"] for r in rows] == source_ids
    assert [(r["dataset_from_index"], r["dataset_to_index"], r["length"]) for r in rows] == \
        [(int(starts[k]), int(starts[k + 1]), lengths[k]) for k in range(len(lengths))]

    frames = load_frames(dst)
    assert len(frames) == info["total_frames"]
    schema = pq.read_schema(next((dst / "data").glob("chunk-*/file-*.parquet")))
    for key, feature in info["features"].items():  # the stored Arrow type is the declared dtype, not wider
        if feature["dtype"] not in ("image", "video"):
            leaf = schema.field(key).type
            while hasattr(leaf, "value_type"):
                leaf = leaf.value_type
            assert leaf.to_pandas_dtype() == np.dtype(feature["dtype"]), key
    fps = info["fps"]
    for k, values in enumerate(expected):
        rows_k = frames[int(starts[k]):int(starts[k + 1])]
        part = {key: np.array(column) for key, column in rows_k.items() if key not in image_keys}
        assert (part["episode_index"] == k).all()
        np.testing.assert_array_equal(part["frame_index"], np.arange(lengths[k]))
        np.testing.assert_array_equal(part["index"], np.arange(starts[k], starts[k + 1]))
        np.testing.assert_allclose(part["timestamp"], np.arange(lengths[k]) / fps, atol=1e-6)
        for key, want in values.items():
            if key in image_keys:
                continue
            got = part[key]
            want = want.reshape(got.shape)  # (T,) scalars are (T,) columns; everything else keeps its shape
            assert np.dtype(info["features"][key]["dtype"]) == want.dtype, key
            np.testing.assert_array_equal(got, want, err_msg=key)  # lossless: exactly the source values
        if not video:
            for key in image_keys:
                got = np.stack([np.asarray(img) for img in rows_k[key]])
                np.testing.assert_array_equal(got, values[key], err_msg=key)  # PNG: lossless

    if video:
        from univtac_data.export.video import read_mp4

        for key in image_keys:
            decoded = read_mp4(str(dst / f"videos/{key}/chunk-000/file-000.mp4"))
            assert decoded.shape[0] == info["total_frames"], key
            assert decoded.shape[1:] == tuple(info["features"][key]["shape"]), key
            for k, row in enumerate(rows):
                first, last = round(row[f"videos/{key}/from_timestamp"] * fps), \
                    round(row[f"videos/{key}/to_timestamp"] * fps)
                assert (first, last) == (starts[k], starts[k + 1]), key
                error = np.abs(decoded[first:last].astype(np.int16) - expected[k][key].astype(np.int16))
                # H.264 at CRF 18 is lossy: the smooth tactile images come back within a few levels; the
                # factory's camera images are uniform noise, H.264's worst case (two unrelated noise images
                # differ by 85 on average)
                limit = 3.0 if "tactile" in key else 60.0
                assert error.mean() < limit, (key, error.mean())


@pytest.fixture
def camera_dataset(tmp_path: Path) -> Path:
    return make_dataset(tmp_path / "src", "zarr", 2, n_frames=6, cameras=("head", "wrist"), camera_depth=True)


def test_export_as_images_matches_the_source_exactly(tmp_path, camera_dataset):
    result = cli("export", "lerobot", str(camera_dataset), str(tmp_path / "lr"))
    assert result.returncode == 0, result.stderr
    assert "exported 2 episodes (12 frames at 60 fps" in result.stdout
    check_against_source(camera_dataset, tmp_path / "lr", video=False)
    stats = json.loads((tmp_path / "lr/meta/stats.json").read_text())
    assert np.array(stats["observation.images.head"]["mean"]).shape == (3, 1, 1)
    action = source_expectations(camera_dataset)
    all_actions = np.concatenate([e["action"] for e in action]).astype(np.float64)
    np.testing.assert_allclose(stats["action"]["mean"], all_actions.mean(0), rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(stats["action"]["std"], all_actions.std(0), rtol=1e-6, atol=1e-9)
    assert stats["action"]["count"] == [12]


def test_export_as_video_decodes_to_the_source(tmp_path, camera_dataset):
    pytest.importorskip("av", reason="the [video] extra (PyAV) is not installed")
    result = cli("export", "lerobot", str(camera_dataset), str(tmp_path / "lr"), "--video")
    assert result.returncode == 0, result.stderr
    check_against_source(camera_dataset, tmp_path / "lr", video=True)


def test_export_of_generated_indenter_episodes(tmp_path):
    """Real indenter episodes (no scene cameras), exported with --fps at half the recorded rate."""
    src = tmp_path / "ind"
    made = cli("generate", "indenters", "--shapes", "sphere,cross", "--episodes-per-shape", "1",
               "--frames-per-episode", "8", "--out", str(src))
    assert made.returncode == 0, made.stderr
    rate = Dataset.open(src).index[Dataset.open(src).episode_ids[0]].nominal_rate_hz
    half = cli("export", "lerobot", str(src), str(tmp_path / "half"), "--fps", str(int(rate) // 2))
    assert half.returncode == 0, half.stderr
    info = json.loads((tmp_path / "half/meta/info.json").read_text())
    assert info["fps"] == int(rate) // 2 and info["total_frames"] == 8  # every other frame of 2 x 8
    assert not any(k.startswith("observation.images.") and "tactile" not in k for k in info["features"])
    full = cli("export", "lerobot", str(src), str(tmp_path / "full"))
    assert full.returncode == 0, full.stderr
    check_against_source(src, tmp_path / "full", video=False)
    frames = load_frames(tmp_path / "half")
    want = source_expectations(src)[0]["observation.tactile.left.depth_um"][::2]
    np.testing.assert_array_equal(np.array(frames[:4]["observation.tactile.left.depth_um"]), want)


DOCTOR_CHECKS = "metadata,temporal,actions,videos,statistics,episodes,consistency,training,portability,per_episode"


@pytest.mark.parametrize("video", [False, True])
def test_lerobot_doctor_finds_no_failure(tmp_path, camera_dataset, video):
    """lerobot-doctor's checks, all but "anomalies": lerobot-doctor 0.2.0's anomaly check raises TypeError on any
    feature of more than one dimension (our depth maps and marker arrays), which LeRobot's format allows.
    Warnings are about the content (6-frame synthetic episodes are "too short" for ACT) and are allowed."""
    doctor = shutil.which("lerobot-doctor")
    if doctor is None:
        pytest.skip("the [lerobot] extra (lerobot-doctor) is not installed")
    if video:
        pytest.importorskip("av", reason="the [video] extra (PyAV) is not installed")
    export_lerobot(str(camera_dataset), tmp_path / "lr", video=video)
    result = subprocess.run([doctor, "check", str(tmp_path / "lr"), "--checks", DOCTOR_CHECKS, "--json"],
                            capture_output=True, text=True, timeout=300)
    report = json.loads(result.stdout)
    assert report["codebase_version"] == "v3.0" and report["total_frames"] == 12
    assert report["summary"]["FAIL"] == 0, [c for c in report["checks"] if c["severity"] == "FAIL"]
    passed = {c["name"] for c in report["checks"] if c["severity"] == "PASS"}
    assert {"Metadata & Format Compliance", "Temporal Consistency", "Feature Consistency"} <= passed
    if video:
        assert "Video Integrity" in passed


def lerobot_dataset_class():
    try:
        from lerobot.datasets.lerobot_dataset import LeRobotDataset
    except ImportError as error:
        pytest.skip(f"lerobot is not installed ({error})")
    except RuntimeError as error:  # torchvision built for another torch: "operator torchvision::nms does not exist"
        pytest.skip(f"lerobot is installed but cannot import beside this torch ({error})")
    return LeRobotDataset


def test_lerobot_dataset_class_reads_the_export(tmp_path, camera_dataset):
    """LeRobot's own ``LeRobotDataset`` (lerobot 0.4.4) on the export: frame count, episode boundaries, values."""
    LeRobotDataset = lerobot_dataset_class()
    export_lerobot(str(camera_dataset), tmp_path / "lr")
    dataset = LeRobotDataset("univtac/export-test", root=tmp_path / "lr")
    expected = source_expectations(camera_dataset)
    assert dataset.num_frames == 12 and dataset.num_episodes == 2
    for k, values in enumerate(expected):
        first = dataset.meta.episodes[k]["dataset_from_index"]
        for t in range(len(values["action"])):
            item = dataset[first + t]
            assert int(item["episode_index"]) == k and int(item["frame_index"]) == t
            np.testing.assert_array_equal(item["action"].numpy(), values["action"][t])
            np.testing.assert_array_equal(item["observation.state"].numpy(), values["observation.state"][t])
            image = (item["observation.images.tactile_left"].numpy() * 255).round().astype(np.uint8)
            np.testing.assert_array_equal(image.transpose(1, 2, 0), values["observation.images.tactile_left"][t])


def test_bad_input_is_one_line_and_leaves_nothing(tmp_path, camera_dataset):
    taken = tmp_path / "taken"
    taken.mkdir()
    (taken / "x").write_text("mine")
    result = cli("export", "lerobot", str(camera_dataset), str(taken))
    assert result.returncode == 2 and "already exists and is not empty" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and (taken / "x").read_text() == "mine"
    odd = cli("export", "lerobot", str(camera_dataset), str(tmp_path / "odd"), "--fps", "7")
    assert odd.returncode == 2 and "--fps 7 does not divide the recorded rate 60.0 Hz" in odd.stderr
    missing = cli("export", "lerobot", str(tmp_path / "nope"), str(tmp_path / "out"))
    assert missing.returncode == 2 and len(missing.stderr.strip().splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["src", "taken"]


def test_an_interrupted_export_leaves_no_dataset(tmp_path, camera_dataset):
    def interrupt(done: int, total: int, episode_id: str) -> None:
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        export_lerobot(str(camera_dataset), tmp_path / "lr", progress=interrupt)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["src"]


def test_episodes_of_different_layouts_are_refused(tmp_path):
    from factories import make_episode

    from univtac_data.storage import DatasetWriter

    writer = DatasetWriter.open(tmp_path / "mixed", storage="hdf5", sensors=["gelsight_mini"])
    writer.add(make_episode(n_frames=4, episode_id="a"))
    writer.add(make_episode(n_frames=4, episode_id="b", cameras=("head",)))
    with pytest.raises(DatasetError, match="episode b has cameras"):
        export_lerobot(str(tmp_path / "mixed"), tmp_path / "lr")
    assert not (tmp_path / "lr").exists()
