"""Format 2.0 residual coding: tactile images stored relative to another array, read back exactly; 1.0 data
still read; damaged residual attributes refused with one line naming the file."""

from __future__ import annotations

import json

import h5py
import hdf5plugin  # noqa: F401  (registers the Blosc filter for the raw h5py reads below)
import numpy as np
import pytest
import zarr

from factories import make_dataset, make_episode
from test_errors import assert_one_line_error, cli
from univtac_data.cli.convert import convert
from univtac_data.storage import CorruptFileError, Dataset, DatasetWriter, FormatVersionError

PAD = "tactile/left/"


def _raw(root, storage: str, episode_id: str, path: str) -> tuple[np.ndarray, object]:
    """The stored values of ``path`` and its ``residual_of`` attribute, bypassing the package's reader."""
    if storage == "hdf5":
        with h5py.File(root / "episodes" / f"{episode_id}.h5", "r") as handle:
            return handle[path][...], handle[path].attrs.get("residual_of")
    array = zarr.open_group(str(root / "episodes" / f"{episode_id}.zarr"), mode="r")[path]
    return np.asarray(array[...]), array.attrs.get("residual_of")


def _random_images(episode, seed: int = 7) -> None:
    """Full-range random images, so that every subtraction wraps somewhere."""
    rng = np.random.default_rng(seed)
    for pad in ("left", "right"):
        for key in ("marked_rgb", "pure_rgb", "pure_ref_rgb"):
            path = f"tactile/{pad}/{key}"
            episode.arrays[path] = rng.integers(0, 256, episode.arrays[path].shape, dtype=np.uint8)


def _written_random_episode(tmp_path, storage: str):
    episode = make_episode(n_frames=3)
    _random_images(episode)
    root = tmp_path / "ds"
    DatasetWriter.open(root, storage=storage, sensors=["gelsight_mini"]).add(episode)
    return episode, root


@pytest.mark.parametrize("storage", ["hdf5", "zarr"])
def test_images_are_stored_as_residuals_and_read_back_exactly(tmp_path, storage):
    episode, root = _written_random_episode(tmp_path, storage)

    marked, marked_base = _raw(root, storage, "ep0", PAD + "marked_rgb")
    pure, pure_base = _raw(root, storage, "ep0", PAD + "pure_rgb")
    assert marked_base == PAD + "pure_rgb" and pure_base == PAD + "pure_ref_rgb"
    ref = episode.arrays[PAD + "pure_ref_rgb"]
    np.testing.assert_array_equal(pure, (episode.arrays[PAD + "pure_rgb"].astype(int) - ref) % 256)
    np.testing.assert_array_equal(marked, (episode.arrays[PAD + "marked_rgb"].astype(int)
                                           - episode.arrays[PAD + "pure_rgb"]) % 256)
    assert _raw(root, storage, "ep0", PAD + "depth_um")[1] is None

    with Dataset.open(root).open_episode("ep0") as handle:
        for key in ("marked_rgb", "pure_rgb", "pure_ref_rgb"):
            np.testing.assert_array_equal(handle.read(PAD + key), episode.arrays[PAD + key])
        # frame reads and slices resolve the chain per frame, against the per-episode reference too
        np.testing.assert_array_equal(handle.read(PAD + "marked_rgb", 1), episode.arrays[PAD + "marked_rgb"][1])
        np.testing.assert_array_equal(handle.read(PAD + "pure_rgb", slice(1, 3)),
                                      episode.arrays[PAD + "pure_rgb"][1:3])
        np.testing.assert_array_equal(handle.read(PAD + "pure_rgb", (2, slice(5, 9), 3)),
                                      episode.arrays[PAD + "pure_rgb"][2, 5:9, 3])
        assert handle.residual_base(PAD + "marked_rgb") == PAD + "pure_rgb"
        assert handle.residual_base(PAD + "depth_um") is None


def test_without_a_reference_pure_rgb_is_stored_as_is(tmp_path):
    episode = make_episode(n_frames=2, reference=False)
    root = make_dataset(tmp_path / "ds", "hdf5", 1, n_frames=2, reference=False)
    pure, base = _raw(root, "hdf5", "ep0", PAD + "pure_rgb")
    assert base is None
    np.testing.assert_array_equal(pure, episode.arrays[PAD + "pure_rgb"])
    assert _raw(root, "hdf5", "ep0", PAD + "marked_rgb")[1] == PAD + "pure_rgb"
    loaded = Dataset.open(root).load_episode("ep0")
    np.testing.assert_array_equal(loaded.arrays[PAD + "marked_rgb"], episode.arrays[PAD + "marked_rgb"])


def test_residuals_make_generated_like_images_small(tmp_path):
    """The reason for the encoding: an image that differs from its base in a few pixels costs little."""
    root = make_dataset(tmp_path / "ds", "hdf5", 1, n_frames=4)
    with h5py.File(root / "episodes" / "ep0.h5", "r") as handle:
        marked = handle[PAD + "marked_rgb"].id.get_storage_size()
    plain = make_dataset(tmp_path / "plain", "hdf5", 1, n_frames=4)
    with h5py.File(plain / "episodes" / "ep0.h5", "r+") as handle:  # the same array stored as is
        data = Dataset.open(root).load_episode("ep0").arrays[PAD + "marked_rgb"]
        del handle[PAD + "marked_rgb"]
        handle.create_dataset(PAD + "marked_rgb", data=data, chunks=(1, *data.shape[1:]),
                              **hdf5plugin.Blosc(cname="zstd", clevel=1))
        stored_plain = handle[PAD + "marked_rgb"].id.get_storage_size()
    assert marked < stored_plain / 2


def _make_format_1_0(root, storage: str) -> None:
    """Turn a freshly written dataset into what univtac-data 0.1.0 wrote: images stored as is, no
    pure_ref_rgb, version 1.0 everywhere."""
    dataset = Dataset.open(root)
    for episode_id in dataset.episode_ids:
        episode = dataset.load_episode(episode_id)
        if storage == "hdf5":
            with h5py.File(root / "episodes" / f"{episode_id}.h5", "r+") as handle:
                for pad in ("left", "right"):
                    for key in ("marked_rgb", "pure_rgb"):
                        path = f"tactile/{pad}/{key}"
                        del handle[path]
                        handle.create_dataset(path, data=episode.arrays[path],
                                              chunks=(1, *episode.arrays[path].shape[1:]), fletcher32=True,
                                              **hdf5plugin.Blosc(cname="zstd", clevel=1))
                    del handle[f"tactile/{pad}/pure_ref_rgb"]
                meta = json.loads(handle.attrs["univtac_meta"])
                meta["format_version"] = "1.0"
                handle.attrs["univtac_meta"] = json.dumps(meta, sort_keys=True)
                handle.attrs["format_version"] = "1.0"
        else:
            group = zarr.open_group(str(root / "episodes" / f"{episode_id}.zarr"), mode="r+")
            for pad in ("left", "right"):
                for key in ("marked_rgb", "pure_rgb"):
                    path = f"tactile/{pad}/{key}"
                    group[path][...] = episode.arrays[path]
                    del group[path].attrs["residual_of"]
                del group[f"tactile/{pad}/pure_ref_rgb"]
            meta = dict(group.attrs["univtac_meta"])
            meta["format_version"] = "1.0"
            group.attrs.update({"univtac_meta": meta, "format_version": "1.0"})
    info = json.loads((root / "meta/info.json").read_text())
    info["format_version"] = "1.0"
    info["fields"] = [f for f in info["fields"] if not f["path"].endswith("pure_ref_rgb")]
    for field in info["fields"]:
        field.pop("residual_of"), field.pop("since")
    (root / "meta/info.json").write_text(json.dumps(info))
    DatasetWriter.reindex_dataset(root)


@pytest.mark.parametrize("storage", ["hdf5", "zarr"])
def test_format_1_0_datasets_read_validate_and_convert(tmp_path, storage):
    root = make_dataset(tmp_path / "old", storage, 2, n_frames=3)
    expected = {eid: make_episode(n_frames=3, episode_id=eid, seed=k) for k, eid in enumerate(("ep0", "ep1"))}
    _make_format_1_0(root, storage)

    old = Dataset.open(root)
    assert old.info.format_version == "1.0" and old.index["ep0"].format_version == "1.0"
    for episode_id, episode in expected.items():
        loaded = old.load_episode(episode_id)
        assert loaded.meta.format_version == "1.0" and PAD + "pure_ref_rgb" not in loaded.arrays
        for key in ("marked_rgb", "pure_rgb", "depth_um"):
            np.testing.assert_array_equal(loaded.arrays[PAD + key], episode.arrays[PAD + key])
    result = cli("validate", str(root), "--json")
    assert result.returncode == 0, result.stdout + result.stderr
    checks = {c["rule"]: c["status"] for c in json.loads(result.stdout)["episodes"]["ep0"]["checks"]}
    assert checks["physics.reference_untouched"] == "skip"  # 1.0 episodes hold no pure_ref_rgb

    # a 2.0 writer does not mix versions in one dataset; convert is the way
    with pytest.raises(FormatVersionError, match=r"format 1\.0 dataset.*univtac-data convert"):
        DatasetWriter.open(root, storage=storage)
    assert convert(str(root), str(tmp_path / "new"), storage, progress=False) == 2
    new = Dataset.open(tmp_path / "new")
    assert new.info.format_version == "2.0" and new.index["ep0"].format_version == "2.0"
    assert _raw(tmp_path / "new", storage, "ep0", PAD + "marked_rgb")[1] == PAD + "pure_rgb"
    assert _raw(tmp_path / "new", storage, "ep0", PAD + "pure_rgb")[1] is None  # no reference to invent
    converted = new.load_episode("ep1")
    assert converted.meta.format_version == "2.0"
    np.testing.assert_array_equal(converted.arrays[PAD + "marked_rgb"], expected["ep1"].arrays[PAD + "marked_rgb"])


def _set_residual_of(root, storage: str, path: str, value: str) -> None:
    if storage == "hdf5":
        with h5py.File(root / "episodes" / "ep0.h5", "r+") as handle:
            handle[path].attrs["residual_of"] = value
    else:
        zarr.open_group(str(root / "episodes" / "ep0.zarr"), mode="r+")[path].attrs["residual_of"] = value


@pytest.mark.parametrize("storage", ["hdf5", "zarr"])
@pytest.mark.parametrize(("path", "value", "problem"), [
    (PAD + "marked_rgb", PAD + "gone_rgb", "which is missing"),
    (PAD + "marked_rgb", PAD + "marked_rgb", "not another array"),
    (PAD + "marked_rgb", PAD + "depth_um", "dtype"),
    (PAD + "marked_rgb", PAD + "contact_mask", "shape"),
    (PAD + "pure_rgb", PAD + "marked_rgb", "a cycle"),  # marked -> pure -> marked -> ...
])
def test_damaged_residual_attributes_are_refused_with_one_line(tmp_path, storage, path, value, problem):
    root = make_dataset(tmp_path / "ds", storage, 1, n_frames=2)
    _set_residual_of(root, storage, path, value)
    with Dataset.open(root).open_episode("ep0") as handle, pytest.raises(CorruptFileError) as caught:
        handle.read(PAD + "marked_rgb", 0)
    message = str(caught.value)
    assert "ep0" in message and problem in message and "\n" not in message
    result = cli("validate", str(root))
    assert result.returncode != 0 and problem in result.stdout + result.stderr


def test_info_of_a_damaged_episode_still_exits_cleanly(tmp_path):
    root = make_dataset(tmp_path / "ds", "hdf5", 1, n_frames=2)
    _set_residual_of(root, "hdf5", PAD + "marked_rgb", PAD + "gone_rgb")
    assert_one_line_error(cli("preview", str(root), "--episode", "ep0", "--out", str(tmp_path / "p.png")),
                          "ep0", "gone_rgb")


@pytest.mark.parametrize("storage", ["hdf5", "zarr"])
def test_a_base_frame_read_for_a_residual_is_reused_but_never_shared(tmp_path, storage):
    episode, root = _written_random_episode(tmp_path, storage)
    with Dataset.open(root).open_episode("ep0") as handle:
        calls: list[str] = []
        raw = handle._read_raw
        handle._read_raw = lambda path, index: (calls.append(path), raw(path, index))[1]  # type: ignore[method-assign]
        handle.read(PAD + "marked_rgb", 1)             # decodes pure_rgb at frame 1 as its base
        pure = handle.read(PAD + "pure_rgb", 1)        # the same frame again: no second decode
        assert calls == [PAD + "marked_rgb", PAD + "pure_rgb", PAD + "pure_ref_rgb"]
        np.testing.assert_array_equal(pure, episode.arrays[PAD + "pure_rgb"][1])
        pure[...] = 0                                  # the caller owns what it gets
        np.testing.assert_array_equal(handle.read(PAD + "pure_rgb", 1), episode.arrays[PAD + "pure_rgb"][1])
        np.testing.assert_array_equal(handle.read(PAD + "pure_rgb", 2), episode.arrays[PAD + "pure_rgb"][2])
