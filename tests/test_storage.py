"""The storage contract, run against both backends: round trips, partial reads, visibility, recovery."""

from __future__ import annotations

import json

import numpy as np
import pytest
from factories import make_dataset, make_episode, stored_blosc_levels

from univtac_data import Dataset, DatasetWriter, EpisodeError, content_hash
from univtac_data.storage import EpisodeExistsError, write_episode_file
from univtac_data.storage.fs import Location
from univtac_data.storage.index import INDEX_PATH, MANIFEST_PATH

BACKENDS = ["hdf5", "zarr"]


@pytest.fixture(params=BACKENDS)
def storage(request: pytest.FixtureRequest) -> str:
    return str(request.param)


def test_every_field_round_trips_bit_exactly(tmp_path, storage):
    episode = make_episode("gelsight_mini", 5, "rt", seed=3, cameras=("head", "wrist"), camera_depth=True,
                           objects=("indenter", "base"))
    DatasetWriter.open(tmp_path / "ds", storage=storage).add(episode)
    loaded = Dataset.open(tmp_path / "ds").load_episode("rt")
    assert loaded.meta == episode.meta
    assert sorted(loaded.arrays) == sorted(episode.arrays)
    for path, array in episode.arrays.items():
        got = loaded.arrays[path]
        assert got.dtype == array.dtype, path
        assert got.shape == array.shape, path
        assert got.tobytes() == array.tobytes(), path
    assert content_hash(loaded) == content_hash(episode)


@pytest.mark.parametrize("sensor", ["gelsight_mini", "gf225", "xense_ws"])
def test_each_sensor_round_trips(tmp_path, storage, sensor):
    episode = make_episode(sensor, 2, "s", seed=1)
    DatasetWriter.open(tmp_path / "ds", storage=storage).add(episode)
    ds = Dataset.open(tmp_path / "ds")
    assert content_hash(ds.load_episode("s")) == content_hash(episode)
    assert sensor in ds.info.sensors


def test_single_frame_reads_match(tmp_path, storage):
    episode = make_episode("gelsight_mini", 6, "e", seed=2)
    make_dataset(tmp_path / "ds", storage, 0)
    DatasetWriter.open(tmp_path / "ds", storage=storage).add(episode)
    with Dataset.open(tmp_path / "ds").open_episode("e") as handle:
        for path in ("tactile/left/marked_rgb", "tactile/right/depth_um", "tactile/left/contact_mask"):
            assert np.array_equal(handle.read(path, 3), episode.arrays[path][3])
        assert np.array_equal(handle.read("robot/action", slice(1, 4)), episode.arrays["robot/action"][1:4])
        assert handle.read("tactile/left/contact_mask", 1).dtype == np.bool_


def test_hdf5_to_zarr_to_hdf5_is_the_identity(tmp_path):
    from univtac_data.cli.convert import convert

    src = make_dataset(tmp_path / "h5", "hdf5", 3, cameras=("head",))
    assert convert(str(src), str(tmp_path / "zarr"), "zarr", progress=False) == 3
    assert convert(str(tmp_path / "zarr"), str(tmp_path / "h5b"), "hdf5", progress=False) == 3
    a, b = Dataset.open(src), Dataset.open(tmp_path / "h5b")
    assert a.episode_ids == b.episode_ids
    for eid in a.episode_ids:
        assert content_hash(a.load_episode(eid)) == content_hash(b.load_episode(eid))
        # the HDF5 writer is deterministic: the files themselves are identical
        assert a.index[eid].sha256 == b.index[eid].sha256


def test_same_episode_gives_same_bytes(tmp_path, storage):
    for name in ("a", "b"):
        DatasetWriter.open(tmp_path / name, storage=storage).add(make_episode("gf225", 3, "x", seed=9))
    assert Dataset.open(tmp_path / "a").index["x"].sha256 == Dataset.open(tmp_path / "b").index["x"].sha256


def test_index_rows_carry_ids_and_summaries(tmp_path, storage):
    ds = Dataset.open(make_dataset(tmp_path / "ds", storage, 3, n_frames=5))
    assert ds.episode_ids == ["ep0", "ep1", "ep2"]
    row = ds.index["ep1"]
    assert (row.episode_id, row.n_frames, row.sensor, row.kind) == ("ep1", 5, "gelsight_mini", "indenter")
    assert row.duration_ns == 4 * int(1e9 / 60)
    assert row.bytes == sum(e.bytes for e in ds.manifest().files.values() if e.episode_id == "ep1")
    assert ds.verify_checksums() == []


def test_a_duplicate_episode_id_is_refused(tmp_path, storage):
    writer = DatasetWriter.open(tmp_path / "ds", storage=storage)
    writer.add(make_episode(episode_id="dup"))
    with pytest.raises(EpisodeExistsError, match="dup"):
        writer.add(make_episode(episode_id="dup", seed=1))


def test_non_conforming_episodes_are_refused_before_writing(tmp_path, storage):
    writer = DatasetWriter.open(tmp_path / "ds", storage=storage)
    episode = make_episode(episode_id="bad")
    episode.arrays["tactile/left/depth_um"] = episode.arrays["tactile/left/depth_um"].astype(np.float32)
    with pytest.raises(EpisodeError, match=r"tactile/left/depth_um must be uint16 \(got float32\)"):
        writer.add(episode)
    episode = make_episode(episode_id="bad")
    del episode.arrays["robot/action"]
    with pytest.raises(EpisodeError, match="required field robot/action is missing"):
        writer.add(episode)
    episode = make_episode(episode_id="bad")
    episode.arrays["tactile/left/markers_px"] = episode.arrays["tactile/left/markers_px"][:, :5]
    with pytest.raises(EpisodeError, match="must have shape"):
        writer.add(episode)
    episode = make_episode(episode_id="bad")
    episode.arrays["tactile/left/extra"] = np.zeros(3)
    with pytest.raises(EpisodeError, match="not a field of the format"):
        writer.add(episode)
    assert Location.parse(tmp_path / "ds").listdir("episodes") == []
    assert len(Dataset.open(tmp_path / "ds")) == 0


def test_recover_indexes_a_finished_episode_that_missed_the_index(tmp_path, storage):
    loc = Location.parse(tmp_path / "ds")
    DatasetWriter.open(tmp_path / "ds", storage=storage).add(make_episode(episode_id="a"))
    write_episode_file(loc, storage, make_episode(episode_id="b", seed=1))  # killed before commit
    (tmp_path / "ds" / "episodes" / ".tmp-c-1234").mkdir()  # killed mid-write
    assert Dataset.open(tmp_path / "ds").episode_ids == ["a"]
    report = DatasetWriter.open(tmp_path / "ds", storage=storage, recover=False).recover()
    assert report.indexed == ["b"]
    assert report.removed_temporaries == ["episodes/.tmp-c-1234"]
    ds = Dataset.open(tmp_path / "ds")
    assert ds.episode_ids == ["a", "b"]
    assert ds.verify_checksums() == []
    assert not any(n.startswith(".tmp-") for n in loc.listdir("episodes"))


def test_reindex_rebuilds_index_and_manifest(tmp_path, storage):
    root = make_dataset(tmp_path / "ds", storage, 3)
    before = Dataset.open(root)
    (root / INDEX_PATH).unlink()
    (root / MANIFEST_PATH).unlink()
    assert len(Dataset.open(root)) == 0
    report = DatasetWriter.reindex_dataset(root)
    assert report.indexed == ["ep0", "ep1", "ep2"] and report.skipped == []
    after = Dataset.open(root)
    assert {k: v.model_dump() for k, v in after.index.items()} == {k: v.model_dump() for k, v in before.index.items()}
    assert after.manifest() == before.manifest()


def test_zarr_dataset_on_an_fsspec_url():
    import fsspec

    url = "memory://univtac-test/ds"
    fsspec.filesystem("memory").rm("/univtac-test", recursive=True) if fsspec.filesystem("memory").exists(
        "/univtac-test") else None
    episode = make_episode(episode_id="remote", cameras=("head",))
    writer = DatasetWriter.open(url, storage="zarr")
    writer.add(episode)
    ds = Dataset.open(url)
    assert ds.episode_ids == ["remote"]
    assert content_hash(ds.load_episode("remote")) == content_hash(episode)
    assert ds.verify_checksums() == []
    assert not [n for n in ds.loc.listdir("episodes") if n.startswith(".tmp-")]


def test_hdf5_refuses_urls():
    from univtac_data import DatasetError

    with pytest.raises(DatasetError, match="HDF5 datasets need a local path"):
        DatasetWriter.open("memory://univtac-test/h5", storage="hdf5").add(make_episode())


def test_info_json_lists_profiles_and_fields(tmp_path, storage):
    root = make_dataset(tmp_path / "ds", storage, 1, sensor="xense_ws")
    info = json.loads((root / "meta" / "info.json").read_text())
    assert info["format_version"] == "2.0" and info["storage"] == storage
    assert info["sensors"]["xense_ws"]["n_markers"] == 220
    assert {f["path"] for f in info["fields"]} >= {"tactile/{pad}/depth_um", "robot/action"}


def test_depth_and_masks_written_bit_shuffled_read_the_same(tmp_path, storage, monkeypatch):
    """Early development builds bit-shuffled depth and contact masks; the shuffle lives in each chunk's Blosc
    header, so such files must read exactly like today's byte-shuffled ones (and validate, and load)."""
    import dataclasses

    from univtac_data.loaders import TactileFrameDataset
    from univtac_data.storage import encoding

    current = encoding.encoding_for
    episode = make_episode("gelsight_mini", 4, "ep0", seed=5)
    DatasetWriter.open(tmp_path / "byte", storage=storage).add(episode)

    def bit_shuffled(spec, shape, level=encoding.ZSTD_LEVEL):  # the first release's choice for "depth"
        enc = current(spec, shape, level)
        return dataclasses.replace(enc, shuffle="bit") if spec.codec == "depth" else enc

    monkeypatch.setattr(encoding, "encoding_for", bit_shuffled)
    DatasetWriter.open(tmp_path / "bit", storage=storage).add(episode)
    monkeypatch.undo()
    old, new = Dataset.open(tmp_path / "bit").load_episode("ep0"), Dataset.open(tmp_path / "byte").load_episode("ep0")
    for path in ("tactile/left/depth_um", "tactile/right/contact_mask"):
        assert old.arrays[path].tobytes() == new.arrays[path].tobytes() == episode.arrays[path].tobytes(), path
    if storage == "hdf5":
        import h5py

        with h5py.File(tmp_path / "bit" / "episodes" / "ep0.h5", "r") as f:
            assert tuple(f["tactile/left/depth_um"]._filters["32001"])[5] == 2   # Blosc's BITSHUFFLE flag
    old_ds = TactileFrameDataset(tmp_path / "bit", compact=True)
    new_ds = TactileFrameDataset(tmp_path / "byte", compact=True)
    batch_old, batch_new = old_ds.read_batch(range(len(old_ds))), new_ds.read_batch(range(len(new_ds)))
    assert np.array_equal(batch_old["depth_um"].numpy(), batch_new["depth_um"].numpy())


def test_compression_level_is_the_writers_choice_and_reads_the_same(tmp_path, storage):
    episode = make_episode("gelsight_mini", 4, "e", seed=5)
    for level in (1, 9):
        writer = DatasetWriter.open(tmp_path / f"l{level}", storage=storage)
        written = write_episode_file(writer.loc, storage, episode, compression_level=level)
        writer.commit([written])
        assert stored_blosc_levels(tmp_path / f"l{level}" / written.row.path) == {level}
        dataset = Dataset.open(tmp_path / f"l{level}")
        assert dataset.verify_checksums() == []
        assert content_hash(dataset.load_episode("e")) == content_hash(episode)
    for level in (0, 10):
        with pytest.raises(ValueError, match=f"compression level must be 1 to 9 \\(got {level}\\)"):
            write_episode_file(Location.parse(tmp_path / "bad"), storage, episode, compression_level=level)
    assert not (tmp_path / "bad").exists()
