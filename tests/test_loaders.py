"""Loaders in one process: index tables and window edges, the split, statistics, samples and selection."""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import numpy as np
import pytest
import torch
from factories import make_dataset, make_episode

from univtac_data.loaders import (
    STATS_PATH,
    FieldStats,
    FrameTable,
    Normalizer,
    PolicyChunkDataset,
    Resize,
    SensorBatchSampler,
    TactileFrameDataset,
    WindowTable,
    split_episode_ids,
    split_of,
    to_float,
    window,
)
from univtac_data.loaders.frames import convert_target
from univtac_data.storage import Dataset, DatasetWriter


@pytest.fixture(scope="module")
def hdf5_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_dataset(tmp_path_factory.mktemp("loaders") / "h5", "hdf5", 3, n_frames=5, cameras=("head",))


@pytest.fixture(scope="module")
def gf_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_dataset(tmp_path_factory.mktemp("loaders") / "gf", "zarr", 1, sensor="gf225", n_frames=3)


# --- sampler: window edges ------------------------------------------------------------------------

def test_window_edges_match_the_documented_sequence() -> None:
    # T = 5, history 3, chunk 4: the table in sampler.py's docstring
    w0 = window(0, 5, 3, 4)
    assert w0.obs_frames.tolist() == [0, 0, 0] and w0.obs_is_pad.tolist() == [True, True, False]
    assert w0.action_frames.tolist() == [0, 1, 2, 3] and not w0.action_is_pad.any()
    w1 = window(1, 5, 3, 4)
    assert w1.obs_frames.tolist() == [0, 0, 1] and w1.obs_is_pad.tolist() == [True, False, False]
    w3 = window(3, 5, 3, 4)
    assert w3.obs_frames.tolist() == [1, 2, 3] and not w3.obs_is_pad.any()
    assert w3.action_frames.tolist() == [3, 4, 4, 4] and w3.action_is_pad.tolist() == [False, False, True, True]
    w4 = window(4, 5, 3, 4)
    assert w4.action_frames.tolist() == [4, 4, 4, 4] and w4.action_is_pad.tolist() == [False, True, True, True]
    with pytest.raises(IndexError, match=r"step must be in \[0, 4\]"):
        window(5, 5, 3, 4)


def test_window_table_rows_and_padding_columns() -> None:
    table = WindowTable([3, 2], history=2, chunk=3)
    assert len(table) == 5
    assert table.episode.tolist() == [0, 0, 0, 1, 1]
    assert table.step.tolist() == [0, 1, 2, 0, 1]
    assert table.pad_before.tolist() == [1, 0, 0, 1, 0]
    assert table.pad_after.tolist() == [0, 1, 2, 1, 2]
    episode, w = table.window(4)
    assert episode == 1 and w.obs_frames.tolist() == [0, 1] and w.action_frames.tolist() == [1, 1, 1]
    assert w.action_is_pad.sum() == table.pad_after[4] and w.obs_is_pad.sum() == table.pad_before[4]


def test_frame_table_is_episode_then_frame_then_pad() -> None:
    table = FrameTable([2, 1], [("left", "right"), ("right",)])
    assert table.pad_names == ["left", "right"]
    rows = [table.row(k) for k in range(len(table))]
    assert rows == [(0, 0, "left"), (0, 0, "right"), (0, 1, "left"), (0, 1, "right"), (1, 0, "right")]


# --- split ----------------------------------------------------------------------------------------

def test_split_is_deterministic_disjoint_and_stable_as_the_dataset_grows() -> None:
    ids = [f"episode_{k:04d}" for k in range(2000)]
    train, val = split_episode_ids(ids, val_fraction=0.2, seed=3)
    assert not set(train) & set(val) and sorted(train + val) == sorted(ids)
    assert 0.17 < len(val) / len(ids) < 0.23
    assert split_episode_ids(list(reversed(ids)), 0.2, 3) == (train, val)
    # an episode's side depends on its id only: a subset keeps every member on its side
    sub_train, sub_val = split_episode_ids(ids[:100], 0.2, 3)
    assert set(sub_val) == set(val) & set(ids[:100]) and set(sub_train) == set(train) & set(ids[:100])
    assert split_episode_ids(ids, 0.2, seed=4)[1] != val
    with pytest.raises(ValueError, match=r"val_fraction must be in \[0, 1\] \(got 1.5\)"):
        split_of("x", 1.5)


def test_dataset_split_is_by_episode(tmp_path: Path) -> None:
    root = make_dataset(tmp_path / "d", "hdf5", 6, n_frames=2)
    seed = next(s for s in range(100) if 0 < len(split_episode_ids([f"ep{k}" for k in range(6)], 0.5, s)[1]) < 6)
    train = TactileFrameDataset(root, split="train", val_fraction=0.5, split_seed=seed, fields=["object_pose"])
    val = TactileFrameDataset(root, split="val", val_fraction=0.5, split_seed=seed, fields=["object_pose"])
    train_ids = {train[k]["episode_id"] for k in range(len(train))}
    val_ids = {val[k]["episode_id"] for k in range(len(val))}
    assert not train_ids & val_ids and train_ids | val_ids == {f"ep{k}" for k in range(6)}
    assert (sorted(train_ids), sorted(val_ids)) == split_episode_ids([f"ep{k}" for k in range(6)], 0.5, seed)
    assert len(train) + len(val) == 6 * 2 * 2


# --- statistics -----------------------------------------------------------------------------------

def test_field_stats_merge_is_exact() -> None:
    rng = np.random.default_rng(0)
    data = rng.normal(3.0, 2.0, (57, 4))
    merged = FieldStats.of(data[:10]).merge(FieldStats.of(data[10:31])).merge(FieldStats.of(data[31:]))
    whole = FieldStats.of(data)
    for key in ("mean", "std", "min", "max"):
        np.testing.assert_allclose(getattr(merged, key), getattr(whole, key), rtol=1e-12)
    assert merged.count == 57


def test_stats_values_saved_reused_and_recomputed(tmp_path: Path) -> None:
    root = make_dataset(tmp_path / "d", "hdf5", 2, n_frames=4)
    first = PolicyChunkDataset(root, obs_keys=["robot/ee_pose"], chunk=2)
    assert first.stats_computed == [True]
    ds = Dataset.open(root)
    actions = np.concatenate([ds.load_episode(e)["robot/action"] for e in ds.episode_ids]).astype(np.float64)
    stats = first.stats["robot/action"]
    assert stats.count == 8
    np.testing.assert_allclose(stats.mean, actions.mean(0), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(stats.std, actions.std(0), rtol=1e-9, atol=1e-15)
    np.testing.assert_array_equal(stats.min, actions.min(0))
    np.testing.assert_array_equal(stats.max, actions.max(0))
    assert first.stats["robot/gripper_width_m"].mean.shape == ()
    saved = json.loads((root / STATS_PATH).read_text())
    assert saved["episodes"] == {e: ds.index[e].sha256 for e in ds.episode_ids}
    assert "scene/primitive" not in saved["fields"] and "tactile/left/markers_px" not in saved["fields"]

    again = PolicyChunkDataset(root, obs_keys=["robot/ee_pose"], chunk=2)
    assert again.stats_computed == [False]
    np.testing.assert_array_equal(again.stats["robot/action"].std, stats.std)

    writer = DatasetWriter.open(root, storage="hdf5")
    writer.add(make_episode("gelsight_mini", 6, "ep9", seed=9))
    changed = PolicyChunkDataset(root, obs_keys=["robot/ee_pose"], chunk=2)
    assert changed.stats_computed == [True] and changed.stats["robot/action"].count == 14
    assert "ep9" in json.loads((root / STATS_PATH).read_text())["episodes"]

    (root / STATS_PATH).write_text("{not json")
    assert PolicyChunkDataset(root, obs_keys=["robot/ee_pose"], chunk=2).stats_computed == [True]


def test_normalizer_modes_and_inverse() -> None:
    stats = {"a": FieldStats.of(np.array([[0.0, 1.0, 5.0], [2.0, 1.0, 9.0]]))}
    x = torch.tensor([[1.0, 1.0, 7.0], [3.0, 1.5, 9.0]])
    mean_std = Normalizer(stats, "mean_std")
    # component 1 never changes: centred only, so a test-time deviation of 0.5 stays 0.5
    np.testing.assert_allclose(mean_std.forward("a", x).numpy(), [[0.0, 0.0, 0.0], [2.0, 0.5, 1.0]])
    min_max = Normalizer(stats, "min_max")
    np.testing.assert_allclose(min_max.forward("a", x).numpy(), [[0.0, 0.0, 0.0], [2.0, 0.5, 1.0]])
    for norm in (mean_std, min_max):
        torch.testing.assert_close(norm.inverse("a", norm.forward("a", x)), x)
    with pytest.raises(KeyError, match="no statistics for 'b'"):
        mean_std.forward("b", x)
    with pytest.raises(ValueError, match="normalize must be one of"):
        Normalizer(stats, "zscore")  # type: ignore[arg-type]


# --- TactileFrameDataset --------------------------------------------------------------------------

def test_frame_sample_targets_shapes_units_and_values(hdf5_root: Path) -> None:
    ds = TactileFrameDataset(hdf5_root)
    assert len(ds) == 3 * 5 * 2
    sample = ds[3]  # episode ep0, frame 1, pad right
    assert (sample["episode_id"], sample["frame"], sample["pad"], sample["sensor"]) == ("ep0", 1, "right",
                                                                                        "gelsight_mini")
    raw = Dataset.open(hdf5_root).load_episode("ep0")
    for key in ("marked_rgb", "pure_rgb"):
        assert sample[key].shape == (3, 240, 320) and sample[key].dtype == torch.float32
        expected = torch.from_numpy(raw[f"tactile/right/{key}"][1]).permute(2, 0, 1).float() / 255
        torch.testing.assert_close(sample[key], expected)
    assert sample["depth_mm"].shape == (1, 240, 320)
    torch.testing.assert_close(sample["depth_mm"][0], torch.from_numpy(raw["tactile/right/depth_um"][1] / 1000.0).float())
    assert 0.25 < float(sample["depth_mm"].max()) <= 0.3  # the factory presses 300 um
    assert sample["markers"].shape == (63, 2)
    back = (sample["markers"].numpy() + 1) / 2 * np.array([319, 239])
    np.testing.assert_allclose(back, raw["tactile/right/markers_px"][1], atol=1e-3)
    pose = raw["tactile/right/object_pose"][1]
    np.testing.assert_allclose(sample["object_pose"].numpy(), [*(pose[:3] * 1000), *pose[3:]], rtol=1e-6)


def test_object_pose_quaternion_is_made_positive() -> None:
    name, pose = convert_target("object_pose", np.array([0.001, 0.0, -0.002, -0.5, 0.5, -0.5, 0.5]), 320, 240)
    assert name == "object_pose"
    np.testing.assert_allclose(pose.numpy(), [1.0, 0.0, -2.0, 0.5, -0.5, 0.5, -0.5], rtol=1e-6)


def test_fields_and_pads_selection(hdf5_root: Path) -> None:
    ds = TactileFrameDataset(hdf5_root, fields=["depth_mm", "contact_mask", "markers_ref"], pads="left",
                             episodes=["ep1", "ep2"])
    assert len(ds) == 2 * 5
    sample = ds[0]
    assert {k for k in sample if isinstance(sample[k], torch.Tensor)} == {"depth_mm", "contact_mask", "markers_ref"}
    assert sample["contact_mask"].dtype == torch.bool and sample["pad"] == "left" and sample["episode_id"] == "ep1"
    torch.testing.assert_close(sample["contact_mask"], sample["depth_mm"] > 0)
    with pytest.raises(ValueError, match="fields must be a non-empty subset"):
        TactileFrameDataset(hdf5_root, fields=["rgb"])
    with pytest.raises(TypeError, match=r"channels_last must be a bool \(got 'no'\)"):
        TactileFrameDataset(hdf5_root, channels_last="no")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"episodes not in any of the datasets: \['nope'\]"):
        TactileFrameDataset(hdf5_root, episodes=["nope"])
    with pytest.raises(ValueError, match="no episode has any of the pads"):
        TactileFrameDataset(hdf5_root, pads=["middle"])
    with pytest.raises(ValueError, match="no episode left after selection"):
        TactileFrameDataset(hdf5_root, names=["cube"])


def test_several_datasets_and_mixed_sensors(hdf5_root: Path, gf_root: Path) -> None:
    both = TactileFrameDataset([hdf5_root, gf_root])
    assert len(both) == 30 + 6 and both.sensors == ["gelsight_mini", "gf225"]
    last = both[len(both) - 1]
    assert (last["dataset"], last["episode_id"], last["sensor"]) == (1, "ep0", "gf225")
    assert last["marked_rgb"].shape == (3, 480, 480) and last["markers"].shape == (81, 2)
    only_gf = TactileFrameDataset([hdf5_root, gf_root], sensors="gf225")
    assert len(only_gf) == 6 and {only_gf[k]["sensor"] for k in range(6)} == {"gf225"}

    sampler = SensorBatchSampler(both, batch_size=4, seed=1)
    batches = list(sampler)
    assert sorted(k for b in batches for k in b) == list(range(len(both))) and len(batches) == len(sampler)
    assert all(len({both.sensor_of(k) for k in b}) == 1 for b in batches)
    loader = torch.utils.data.DataLoader(both, batch_sampler=sampler)
    shapes = {tuple(batch["marked_rgb"].shape[1:]) for batch in loader}
    assert shapes == {(3, 240, 320), (3, 480, 480)}


def test_compact_samples_convert_to_the_same_floats(hdf5_root: Path) -> None:
    full = torch.utils.data.default_collate([TactileFrameDataset(hdf5_root)[k] for k in (0, 7, 13)])
    compact_ds = TactileFrameDataset(hdf5_root, compact=True)
    compact = torch.utils.data.default_collate([compact_ds[k] for k in (0, 7, 13)])
    assert compact["marked_rgb"].dtype == torch.uint8 and compact["depth_um"].dtype == torch.int16
    converted = to_float(compact)
    for key in ("marked_rgb", "pure_rgb", "depth_mm", "markers", "object_pose"):
        torch.testing.assert_close(converted[key], full[key], rtol=0, atol=0)


def test_resize_transform(hdf5_root: Path) -> None:
    ds = TactileFrameDataset(hdf5_root, fields=["marked_rgb", "depth_mm", "contact_mask", "markers", "markers_px"],
                             transform=Resize(96, 128))
    sample = ds[4]
    assert sample["marked_rgb"].shape == (3, 96, 128) and sample["depth_mm"].shape == (1, 96, 128)
    assert sample["contact_mask"].dtype == torch.bool and sample["contact_mask"].shape == (1, 96, 128)
    plain = TactileFrameDataset(hdf5_root, fields=["marked_rgb", "markers", "markers_px"])[4]
    torch.testing.assert_close(sample["markers"], plain["markers"])
    torch.testing.assert_close(sample["markers_px"], plain["markers_px"] * torch.tensor([127 / 319, 95 / 239]))
    assert abs(float(sample["marked_rgb"].mean()) - float(plain["marked_rgb"].mean())) < 0.01


def test_reader_is_bounded_and_drops_handles_when_pickled(hdf5_root: Path) -> None:
    ds = TactileFrameDataset(hdf5_root, fields=["object_pose"], max_open_episodes=2)
    assert ds.reader.n_open == 0  # construction opens nothing that stays open
    for k in range(len(ds)):
        ds[k]
    assert ds.reader.n_open == 2 and ds.reader.opens == 3
    clone = pickle.loads(pickle.dumps(ds))
    assert clone.reader.n_open == 0
    torch.testing.assert_close(clone[len(ds) - 1]["object_pose"], ds[len(ds) - 1]["object_pose"])
    ds.reader.close()
    assert ds.reader.n_open == 0


# --- PolicyChunkDataset ---------------------------------------------------------------------------

def test_policy_first_and_last_steps_exact(hdf5_root: Path) -> None:
    ds = PolicyChunkDataset(hdf5_root, obs_keys=["robot/ee_pose", "robot/gripper_width_m", "scene/cameras/head/rgb",
                                                 "tactile/left/depth_um"], history=3, chunk=4, episodes=["ep1"])
    raw = Dataset.open(hdf5_root).load_episode("ep1")
    ee, width, action = raw["robot/ee_pose"], raw["robot/gripper_width_m"], raw["robot/action"]
    assert len(ds) == 5
    first = ds[0]
    assert first["obs_is_pad"].tolist() == [True, True, False] and first["step"] == 0
    np.testing.assert_array_equal(first["obs"]["robot/ee_pose"].numpy(), ee[[0, 0, 0]].astype(np.float32))
    assert first["obs"]["robot/gripper_width_m"].shape == (3, 1)
    assert first["obs"]["scene/cameras/head/rgb"].shape == (3, 3, 48, 64)
    assert first["obs"]["tactile/left/depth_mm"].shape == (3, 1, 240, 320)
    np.testing.assert_array_equal(first["action"].numpy(), action[[0, 1, 2, 3]])
    assert not first["action_is_pad"].any()
    last = ds[4]
    assert last["obs_is_pad"].tolist() == [False, False, False]
    np.testing.assert_array_equal(last["obs"]["robot/ee_pose"].numpy(), ee[[2, 3, 4]].astype(np.float32))
    np.testing.assert_array_equal(last["obs"]["robot/gripper_width_m"][:, 0].numpy(), width[[2, 3, 4]])
    np.testing.assert_array_equal(last["action"].numpy(), action[[4, 4, 4, 4]])
    assert last["action_is_pad"].tolist() == [False, True, True, True]

    zero = PolicyChunkDataset(hdf5_root, obs_keys=["robot/ee_pose"], history=2, chunk=3, episodes=["ep1"],
                              action_pad="zero", normalize="mean_std")
    step3 = zero[3]
    assert step3["action_is_pad"].tolist() == [False, False, True]
    assert (step3["action"][2] == 0).all()
    expected = zero.normalizer.forward("robot/action", torch.from_numpy(action[[3, 4]]))
    torch.testing.assert_close(step3["action"][:2], expected)
    torch.testing.assert_close(zero.normalizer.inverse("robot/action", step3["action"][:2]),
                               torch.from_numpy(action[[3, 4]]))


def test_policy_rejects_bad_keys(hdf5_root: Path) -> None:
    with pytest.raises(ValueError, match=r"episode ep0 has no \['scene/cameras/wrist/rgb'\]"):
        PolicyChunkDataset(hdf5_root, obs_keys=["scene/cameras/wrist/rgb"])
    with pytest.raises(ValueError, match="must be per-frame array paths"):
        PolicyChunkDataset(hdf5_root, obs_keys=["tactile/left/markers_ref_px"])
    with pytest.raises(ValueError, match="history and chunk must be >= 1"):
        PolicyChunkDataset(hdf5_root, chunk=0)


def test_policy_over_several_datasets_merges_stats(tmp_path: Path) -> None:
    a = make_dataset(tmp_path / "a", "hdf5", 2, n_frames=3)
    b = make_dataset(tmp_path / "b", "zarr", 1, n_frames=4)
    ds = PolicyChunkDataset([a, b], obs_keys=["robot/ee_pose"], chunk=2)
    assert len(ds) == 3 + 3 + 4 and ds[len(ds) - 1]["dataset"] == 1
    assert ds.stats["robot/action"].count == 10
    assert [s["robot/action"].count for s in ds.dataset_stats] == [6, 4]
    assert (a / STATS_PATH).exists() and (b / STATS_PATH).exists()
