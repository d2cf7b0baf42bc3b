"""Format 2.0 residual images (``residual_of``) through every loader path, against the images as written;
format 1.0 files (no residuals) beside them; damaged residual metadata; the layout cache's pool."""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import h5py
import hdf5plugin
import numpy as np
import pytest
import torch
import zarr
from factories import assert_same, make_episode

from univtac_data import Episode
from univtac_data.loaders import FRAME_FIELDS, FrameBatchLoader, PolicyChunkDataset, TactileFrameDataset
from univtac_data.loaders.chunks import FrameChunks, FrameSource
from univtac_data.loaders.episodes import handle_source
from univtac_data.loaders.frames import Sample, convert_compact, convert_target, image_chw
from univtac_data.loaders.layouts import POOL_MIN_BYTES, FileIdentity, LayoutCache
from univtac_data.storage import Dataset, DatasetWriter
from univtac_data.storage.errors import CorruptFileError

N_EPISODES, N_FRAMES, H, W = 3, 4, 240, 320
PADS = ("left", "right")
ALL_FIELDS = tuple(FRAME_FIELDS)
MARKED, PURE, REF = "tactile/left/marked_rgb", "tactile/left/pure_rgb", "tactile/left/pure_ref_rgb"


def random_images(rng: np.random.Generator, *shape: int) -> np.ndarray:
    """uint8 (..., H, W, 3) of every byte value, so that residuals wrap modulo 256 everywhere, yet in runs of 8
    pixels: compressible, as HDF5's filter pipeline (the 1.0 writer) would otherwise store chunks unfiltered,
    which the fast path leaves to h5py."""
    runs = rng.integers(0, 256, (*shape[:-1], shape[-1] // 8, 3), dtype=np.uint8)   # shape: (..., H, W)
    return np.repeat(runs, 8, axis=-2)


def residual_episode(k: int) -> Episode:
    """Episode ``ep{k}`` with random images and a random ``pure_ref_rgb`` per pad, the same for every episode
    (as the generator's background frame is)."""
    episode = make_episode("gelsight_mini", N_FRAMES, f"ep{k}", seed=k)
    rng = np.random.default_rng(k)
    for p, pad in enumerate(PADS):
        episode.arrays[f"tactile/{pad}/pure_ref_rgb"] = random_images(np.random.default_rng(1000 + p), H, W)
        episode.arrays[f"tactile/{pad}/pure_rgb"] = random_images(rng, N_FRAMES, H, W)
        episode.arrays[f"tactile/{pad}/marked_rgb"] = random_images(rng, N_FRAMES, H, W)
    return episode


def assert_chunks_decode_directly(path: Path, arrays: tuple[str, ...]) -> None:
    """Every frame of ``arrays`` takes the fast path (none is left to h5py), so that the tests test it."""
    with h5py.File(path, "r", locking=False) as f:
        for array in arrays:
            chunks = FrameChunks.of(f[array])
            assert chunks is not None, array
            out = np.empty(chunks.frame_shape, np.uint8)
            assert all(chunks.read_frame_into(t, out) for t in range(N_FRAMES)), array


IMAGES = tuple(f"tactile/{pad}/{name}" for pad in PADS for name in ("marked_rgb", "pure_rgb"))


def write_dataset(root: Path, storage: str) -> dict[str, Episode]:
    writer = DatasetWriter.open(root, storage=storage, sensors=["gelsight_mini"])
    written = {}
    for k in range(N_EPISODES):
        episode = residual_episode(k)
        writer.add(episode)
        written[episode.meta.episode_id] = episode
    return written


@pytest.fixture(scope="module", params=["hdf5", "zarr"])
def stored(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) \
        -> tuple[Path, dict[str, Episode]]:
    root = tmp_path_factory.mktemp(request.param) / "d"
    written = write_dataset(root, request.param)
    with Dataset.open(root).open_episode("ep0") as handle:   # what the tests below are about
        assert handle.residual_base(MARKED) == PURE and handle.residual_base(PURE) == REF
        assert handle.residual_base(REF) is None
    if request.param == "hdf5":
        assert_chunks_decode_directly(root / "episodes" / "ep0.h5", IMAGES)
    return root, written


def expected_sample(ds: TactileFrameDataset, index: int, written: dict[str, Episode]) -> Sample:
    """Sample ``index`` converted from the arrays as written (the logical values), as the loader converts."""
    ref, frame, pad = ds._row(index)
    convert = convert_compact if ds.config.compact else convert_target
    sample: Sample = {}
    for key in ds.config.fields:
        value = written[ref.episode_id].arrays[f"tactile/{pad}/{FRAME_FIELDS[key]}"]
        name, sample[name] = convert(key, value if key == "markers_ref" else value[frame], W, H,
                                     ds.config.channels_last)
    sample.update(sensor=ref.sensor, pad=pad, episode_id=ref.episode_id, name=ref.name, frame=frame,
                  dataset=ref.dataset)
    return sample


def expected_batch(ds: TactileFrameDataset, indices: list[int], written: dict[str, Episode]) -> Sample:
    return torch.utils.data.default_collate([expected_sample(ds, i, written) for i in indices])


def shuffled_batches(n: int, batch_size: int = 5, seed: int = 0) -> list[list[int]]:
    order = np.random.default_rng(seed).permutation(n).tolist()
    return [order[k:k + batch_size] for k in range(0, n, batch_size)]


def read_batches(ds: TactileFrameDataset, mode: str) -> Iterator[tuple[list[int], Sample]]:
    """``(indices, batch)`` read one way: one sample at a time, ``read_batch``, ``FrameBatchLoader`` threads,
    DataLoader worker processes, or a bounded reader's second epoch (through the layout cache on HDF5)."""
    batches = shuffled_batches(len(ds))
    if mode == "samples":
        for index in range(len(ds)):
            yield [index], torch.utils.data.default_collate([ds[index]])
    elif mode == "read_batch":
        for indices in batches:
            yield indices, ds.read_batch(indices)
    elif mode == "threads":
        yield from zip(batches, FrameBatchLoader(ds, batch_size=5, shuffle=True, seed=0, threads=2))
    elif mode == "workers":
        loader = torch.utils.data.DataLoader(ds, batch_size=None, sampler=batches, num_workers=2)
        yield from zip(batches, loader)
    elif mode == "cached":
        for epoch in range(2):   # the first records the layouts, the second reads through them
            for indices in shuffled_batches(len(ds), seed=epoch):
                yield indices, ds.read_batch(indices)
    else:
        raise ValueError(mode)


MODES = ("samples", "read_batch", "threads", "workers", "cached")


def bounds(mode: str) -> dict[str, int]:
    return {"max_open_episodes": 1, "max_open_files": 1} if mode == "cached" else {}


def check(ds: TactileFrameDataset, mode: str, written: dict[str, Episode]) -> int:
    n = 0
    for indices, batch in read_batches(ds, mode):
        if mode == "samples":   # a sample as __getitem__ gives it: channels-last images stay views
            assert_same(ds[indices[0]], expected_sample(ds, indices[0], written), channels_last=ds.config.channels_last)
        assert_same(batch, expected_batch(ds, indices, written),
                    channels_last=ds.config.channels_last and mode != "samples")
        n += len(indices)
    return n


# --- values: every path against the images as written --------------------------------------------

@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize(("compact", "channels_last"), [(False, False), (True, False), (False, True), (True, True)])
def test_residual_images_equal_the_written_images(stored: tuple[Path, dict[str, Episode]], mode: str, compact: bool,
                                                  channels_last: bool) -> None:
    root, written = stored
    ds = TactileFrameDataset(root, fields=ALL_FIELDS, compact=compact, channels_last=channels_last, **bounds(mode))
    n = check(ds, mode, written)
    assert n == len(ds) * (2 if mode == "cached" else 1)


@pytest.mark.parametrize("mode", ["samples", "read_batch", "cached"])
def test_residual_images_equal_the_handle_read(stored: tuple[Path, dict[str, Episode]], mode: str) -> None:
    """The loaders' values are ``EpisodeHandle.read``'s (the backend's own residual decoding)."""
    root, _ = stored
    dataset = Dataset.open(root)
    handles = {eid: dataset.open_episode(eid) for eid in dataset.episode_ids}
    try:
        as_read = {eid: Episode(meta=h.meta, arrays={f"tactile/{pad}/{name}": h.read(f"tactile/{pad}/{name}")
                                                     for pad in PADS for name in ("marked_rgb", "pure_rgb")})
                   for eid, h in handles.items()}
    finally:
        for handle in handles.values():
            handle.close()
    ds = TactileFrameDataset(root, fields=("marked_rgb", "pure_rgb"), compact=True, channels_last=True,
                             **bounds(mode))
    check(ds, mode, as_read)


@pytest.mark.parametrize("mode", MODES)
def test_only_marked_rgb(stored: tuple[Path, dict[str, Episode]], mode: str) -> None:
    """``marked_rgb`` alone needs ``pure_rgb`` (its base) and ``pure_ref_rgb`` (pure_rgb's), read for it."""
    root, written = stored
    ds = TactileFrameDataset(root, fields=("marked_rgb",), compact=True, channels_last=True, **bounds(mode))
    check(ds, mode, written)


def test_only_marked_rgb_reads_through_the_cache_without_h5py(tmp_path: Path, h5py_opens: list[str]) -> None:
    root = tmp_path / "d"
    written = write_dataset(root, "hdf5")
    ds = TactileFrameDataset(root, fields=("marked_rgb",), compact=True, max_open_episodes=1, max_open_files=1)
    h5py_opens.clear()   # selecting the episodes opened each once
    for indices in shuffled_batches(len(ds), seed=0):
        assert_same(ds.read_batch(indices), expected_batch(ds, indices, written))
    assert len(h5py_opens) >= N_EPISODES
    layout = ds.reader.layouts.get(str(root / "episodes" / "ep0.h5"))
    assert layout is not None   # the residual bases are recorded with the places, the reference kept whole
    assert layout.frames[MARKED] is not None and layout.frames[MARKED].residual_of == PURE
    assert layout.frames[PURE] is not None and layout.frames[PURE].residual_of == REF
    assert set(layout.pooled) == {REF, "tactile/right/pure_ref_rgb"}
    assert np.array_equal(layout.whole[REF], written["ep0"].arrays[REF])
    h5py_opens.clear()
    for epoch in (1, 2):
        for indices in shuffled_batches(len(ds), seed=epoch):
            assert_same(ds.read_batch(indices), expected_batch(ds, indices, written))
        for index in (0, 7, len(ds) - 1):
            assert_same(ds[index], expected_sample(ds, index, written))
    assert h5py_opens == []


@pytest.fixture(scope="module")
def hdf5_stored(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Episode]]:
    root = tmp_path_factory.mktemp("hdf5") / "d"
    return root, write_dataset(root, "hdf5")


@pytest.mark.parametrize("failing", ["every", "base"])
def test_chunks_left_to_h5py_still_give_the_written_images(hdf5_stored: tuple[Path, dict[str, Episode]],
                                                           failing: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """A chunk the fast path does not decode is read through ``handle.read``, which adds the base itself:
    every chunk, or only ``pure_rgb``'s (the base ``marked_rgb`` adds after decoding its own chunk)."""
    root, written = hdf5_stored
    decode = FrameChunks.read_frame_into

    def failing_read(self: FrameChunks, frame: int, out: np.ndarray) -> bool:
        base = self.layout.residual_of
        if failing == "every" or (base is not None and base.endswith("/pure_ref_rgb")):
            return False
        return decode(self, frame, out)

    monkeypatch.setattr(FrameChunks, "read_frame_into", failing_read)
    for channels_last in (False, True):
        ds = TactileFrameDataset(root, fields=ALL_FIELDS, compact=True, channels_last=channels_last,
                                 max_open_episodes=1, max_open_files=1)
        for mode in ("samples", "cached"):
            check(ds, mode, written)


def test_reader_reads_whole_arrays_frames_and_slices(stored: tuple[Path, dict[str, Episode]]) -> None:
    root, written = stored
    ds = TactileFrameDataset(root, max_open_episodes=1, max_open_files=1)
    for _ in range(2):   # the second time through the cache (HDF5)
        for ref in ds.episodes:
            arrays = written[ref.episode_id].arrays
            for path in (MARKED, PURE, "tactile/right/marked_rgb"):
                assert np.array_equal(ds.reader.read(ref, path), arrays[path])
                assert np.array_equal(ds.reader.read(ref, path, slice(1, 3)), arrays[path][1:3])
                for frame in range(N_FRAMES):
                    assert np.array_equal(ds.reader.read(ref, path, frame), arrays[path][frame])
            assert np.array_equal(ds.reader.read(ref, REF), arrays[REF])


def test_policy_observes_the_written_images(stored: tuple[Path, dict[str, Episode]]) -> None:
    root, written = stored
    keys = (MARKED, PURE, "tactile/right/marked_rgb")
    ds = PolicyChunkDataset(root, obs_keys=keys, history=2, chunk=2)
    for index in range(len(ds)):
        sample = ds[index]
        episode, win = ds.table.window(index)
        arrays = written[ds.episodes[episode].episode_id].arrays
        for key in keys:
            expected = torch.stack([image_chw(arrays[key][t]) for t in win.obs_frames])
            assert torch.equal(sample["obs"][key], expected), (index, key)


def test_a_handle_source_alone_adds_the_bases(hdf5_stored: tuple[Path, dict[str, Episode]]) -> None:
    root, written = hdf5_stored
    with Dataset.open(root).open_episode("ep2") as handle:
        marked = handle_source(handle, MARKED)
        assert marked.chunks is not None and isinstance(marked.base, FrameSource)
        assert marked.base.chunks is not None and isinstance(marked.base.base, np.ndarray)   # pure_ref_rgb
        for frame in range(N_FRAMES):
            assert np.array_equal(marked.read(frame), written["ep2"].arrays[MARKED][frame])


def test_a_frame_source_refuses_residual_chunks_without_a_base(hdf5_stored: tuple[Path, dict[str, Episode]]) -> None:
    root, _ = hdf5_stored
    with h5py.File(root / "episodes" / "ep0.h5", "r", locking=False) as f:
        chunks = FrameChunks.of(f[MARKED], PURE)
        assert chunks is not None and chunks.layout.residual_of == PURE
        with pytest.raises(ValueError, match="a residual's chunks need its base"):
            FrameSource(chunks.frame_shape, np.dtype(np.uint8), chunks, lambda frame: np.empty(0))


def test_a_chain_of_per_frame_residuals(tmp_path: Path) -> None:
    """left marked_rgb -> left pure_rgb -> right pure_rgb -> right pure_ref_rgb: two per-frame bases in a row
    (the format allows any sibling of the same shape), each decoded into a scratch frame of its own."""
    root = tmp_path / "d"
    written = write_dataset(root, "hdf5")
    right = "tactile/right/pure_rgb"
    with h5py.File(root / "episodes" / "ep0.h5", "r+") as f:
        del f[PURE]
        stored = np.subtract(written["ep0"].arrays[PURE], written["ep0"].arrays[right], dtype=np.uint8)
        f.create_dataset(PURE, data=stored, chunks=(1, H, W, 3), fletcher32=True,
                         **hdf5plugin.Blosc(cname="zstd", clevel=1, shuffle=hdf5plugin.Blosc.SHUFFLE))
        f[PURE].attrs["residual_of"] = right
    with Dataset.open(root).open_episode("ep0") as handle:
        assert handle.residual_base(PURE) == right
        assert np.array_equal(handle.read(MARKED), written["ep0"].arrays[MARKED])
    assert_chunks_decode_directly(root / "episodes" / "ep0.h5", (MARKED, PURE, right))
    ds = TactileFrameDataset(root, pads="left", compact=True, max_open_episodes=1, max_open_files=1)
    for mode in ("samples", "cached"):
        check(ds, mode, written)


# --- format 1.0 files: no residuals --------------------------------------------------------------

def downgrade_to_1_0(root: Path, episode_id: str, written: Episode, storage: str) -> None:
    """Store episode ``episode_id`` as the 1.0 writers did: images plain (no ``residual_of``), no ``pure_ref_rgb``,
    format version 1.0."""
    path = root / Dataset.open(root).index[episode_id].path
    if storage == "hdf5":
        with h5py.File(path, "r+") as f:
            for pad in PADS:
                del f[f"tactile/{pad}/pure_ref_rgb"]
                for name in ("pure_rgb", "marked_rgb"):
                    array = f"tactile/{pad}/{name}"
                    del f[array]
                    data = written.arrays[array]
                    f.create_dataset(array, data=data, chunks=(1, *data.shape[1:]), fletcher32=True, track_times=False,
                                     **hdf5plugin.Blosc(cname="zstd", clevel=1, shuffle=hdf5plugin.Blosc.SHUFFLE))
            meta = json.loads(f.attrs["univtac_meta"])
            f.attrs["univtac_meta"] = json.dumps({**meta, "format_version": "1.0"}, sort_keys=True)
            f.attrs["format_version"] = "1.0"
    else:
        group = zarr.open_group(str(path), mode="r+")
        for pad in PADS:
            del group[f"tactile/{pad}/pure_ref_rgb"]
            for name in ("pure_rgb", "marked_rgb"):
                array = group[f"tactile/{pad}/{name}"]
                del array.attrs["residual_of"]
                array[...] = written.arrays[f"tactile/{pad}/{name}"]
        group.attrs.update({"format_version": "1.0",
                            "univtac_meta": {**dict(group.attrs)["univtac_meta"], "format_version": "1.0"}})


@pytest.fixture(scope="module", params=["hdf5", "zarr"])
def mixed(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) \
        -> tuple[Path, dict[str, Episode]]:
    """A dataset whose ep1 is a format 1.0 file, beside 2.0 files."""
    root = tmp_path_factory.mktemp(request.param) / "d"
    written = write_dataset(root, request.param)
    downgrade_to_1_0(root, "ep1", written["ep1"], request.param)
    with Dataset.open(root).open_episode("ep1") as handle:
        assert handle.meta.format_version == "1.0" and REF not in handle.paths()
        assert handle.residual_base(MARKED) is None and handle.residual_base(PURE) is None
    if request.param == "hdf5":
        assert_chunks_decode_directly(root / "episodes" / "ep1.h5", IMAGES)
    return root, written


@pytest.mark.parametrize("mode", MODES)
def test_format_1_0_files_load_equal(mixed: tuple[Path, dict[str, Episode]], mode: str) -> None:
    root, written = mixed
    for compact, channels_last in ((False, False), (True, True)):
        ds = TactileFrameDataset(root, fields=ALL_FIELDS, compact=compact, channels_last=channels_last,
                                 **bounds(mode))
        check(ds, mode, written)
        fields = TactileFrameDataset(root, fields=("marked_rgb",), **bounds(mode))
        check(fields, mode, written)


def test_format_1_0_images_take_the_chunk_path(mixed: tuple[Path, dict[str, Episode]]) -> None:
    root, written = mixed
    ds = TactileFrameDataset(root, compact=True)
    ref = next(r for r in ds.episodes if r.episode_id == "ep1")
    for path in (MARKED, PURE):
        source = ds.reader.frame_source(ref, path)
        assert source.base is None
        assert source.chunks is not None   # both backends: HDF5 chunks, Zarr shards (loaders/zarr_chunks.py)
        assert np.array_equal(source.read(2), written["ep1"].arrays[path][2])


# --- damaged residual metadata -------------------------------------------------------------------

DAMAGES = {   # array -> its new residual_of
    "missing": (MARKED, "tactile/left/no_such_rgb"),
    "itself": (MARKED, MARKED),
    "dtype": (MARKED, "tactile/left/depth_um"),          # uint16
    "shape": (PURE, "tactile/left/contact_mask"),        # uint8 (T, H, W)
    "not_a_path": (MARKED, 7),
    "cycle": (PURE, MARKED),                             # marked_rgb -> pure_rgb -> marked_rgb -> ...
}


def damage(root: Path, array: str, residual_of: Any, storage: str) -> None:
    path = root / Dataset.open(root).index["ep0"].path
    if storage == "hdf5":
        with h5py.File(path, "r+") as f:
            f[array].attrs["residual_of"] = residual_of
    else:
        zarr.open_group(str(path), mode="r+")[array].attrs["residual_of"] = residual_of


@pytest.mark.parametrize("storage", ["hdf5", "zarr"])
@pytest.mark.parametrize("kind", list(DAMAGES))
def test_damaged_residual_metadata_raises_one_line(tmp_path: Path, storage: str, kind: str) -> None:
    root = tmp_path / "d"
    write_dataset(root, storage)
    warm = TactileFrameDataset(root, compact=True, pads="left", max_open_episodes=1, max_open_files=1)
    warm.read_batch(list(range(len(warm))))   # layouts recorded (HDF5); ep0's handle closed since
    file = root / Dataset.open(root).index["ep0"].path
    identity = FileIdentity.of(os.stat(file))
    damage(root, *DAMAGES[kind], storage)
    if storage == "hdf5":
        assert FileIdentity.of(os.stat(file)) != identity
    with Dataset.open(root).open_episode("ep0") as handle, pytest.raises(CorruptFileError) as error:
        handle.read(MARKED, 0)   # the first image the loaders read
    expected = str(error.value)
    assert "\n" not in expected and "ep0" in expected and "tactile/left/" in expected
    cold = TactileFrameDataset(root, compact=True, pads="left")
    for ds in (cold, warm):
        for read in (lambda: ds[0], lambda: ds.read_batch([0, 1, 2]), lambda: list(FrameBatchLoader(ds, 3, threads=2)),
                     lambda: ds.reader.read(ds.episodes[0], MARKED, 1)):
            with pytest.raises(CorruptFileError) as error:
                read()
            assert str(error.value) == expected
    good = [k for k in range(len(cold)) if cold._row(k)[0].episode_id != "ep0"]
    assert_same(cold.read_batch(good), warm.read_batch(good))   # the other episodes still read


# --- the layout cache's pool of large whole arrays -----------------------------------------------

IDENTITY = FileIdentity(1, 2, 3, 4)


def image(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (H, W, 3), dtype=np.uint8)


def test_equal_large_arrays_are_kept_once_and_counted_once() -> None:
    cache = LayoutCache()
    cache.record("a", IDENTITY, whole={"ref": image(0), "small": np.ones(10)})
    cache.record("b", IDENTITY, whole={"ref": image(0)})   # another copy of the same image
    cache.record("b", IDENTITY, whole={"other": image(1)})
    a, b = cache.get("a"), cache.get("b")
    assert a is not None and b is not None
    assert b.whole["ref"] is a.whole["ref"] and not a.whole["ref"].flags.writeable
    assert set(a.pooled) == {"ref"} and set(b.pooled) == {"ref", "other"}
    assert a.nbytes < POOL_MIN_BYTES and b.nbytes < POOL_MIN_BYTES   # pooled arrays are not in a layout's bytes
    assert cache.nbytes == a.nbytes + b.nbytes + 2 * image(0).nbytes
    cache.discard("a", IDENTITY)
    assert cache.nbytes == b.nbytes + 2 * image(0).nbytes   # b still holds the image
    cache.record("c", IDENTITY, whole={"ref": image(0)})
    c = cache.get("c")
    assert c is not None and c.whole["ref"] is b.whole["ref"]
    cache.discard("b", IDENTITY)
    cache.discard("c", IDENTITY)
    assert cache.nbytes == 0 and cache._pool == {} and cache._users == {}


def test_pooled_arrays_leave_with_the_last_layout_holding_them() -> None:
    one = LayoutCache()
    one.record("a", IDENTITY, whole={"ref": image(0)})
    size = one.nbytes
    cache = LayoutCache(budget_bytes=2 * size - 1)   # room for one episode and its image
    cache.record("a", IDENTITY, whole={"ref": image(0)})
    cache.record("b", IDENTITY, whole={"ref": image(1)})   # pushes a out, and a's image with it
    assert cache.get("a") is None and cache.nbytes == size and len(cache._pool) == 1
    cache.record("c", IDENTITY, whole={"ref": np.zeros(3 * size, np.uint8)})   # larger than the budget: not kept
    assert cache.get("c") is None and cache.nbytes <= size and len(cache._pool) == 1
    cache.record("b", FileIdentity(1, 2, 3, 5), whole={"x": np.ones(3)})   # another version drops b's image
    assert cache.nbytes == cache.get("b").nbytes and cache._pool == {}


def test_a_checksum_collision_is_never_shared(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr("univtac_data.loaders.layouts.pool_key", lambda array: ((1,), "|u1", 0))
    cache = LayoutCache()
    cache.record("a", IDENTITY, whole={"ref": image(0)})
    cache.record("b", IDENTITY, whole={"ref": image(1)})   # same key, other content
    a, b = cache.get("a"), cache.get("b")
    assert a is not None and b is not None and np.array_equal(b.whole["ref"], image(1))
    assert set(b.pooled) == set() and cache.nbytes == a.nbytes + b.nbytes + image(0).nbytes


@pytest.mark.parametrize("compact, channels_last", [(True, True), (True, False), (False, True), (False, False)])
def test_a_batch_decodes_each_pure_frame_once(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, compact: bool,
                                              channels_last: bool) -> None:
    """I_marked is a residual of I_pure: a batch with both adds the I_pure frames it decoded to the marked
    residuals instead of decoding them again, and gets the same values."""
    root = tmp_path / "d"
    written = write_dataset(root, "hdf5")
    ds = TactileFrameDataset(root, compact=compact, channels_last=channels_last,
                             fields=("marked_rgb", "pure_rgb", "depth_mm", "markers"))
    indices = shuffled_batches(len(ds), 6, seed=3)[0]
    ds.read_batch(indices)   # layouts recorded: the second batch decodes every chunk itself
    decoded: list[int] = []
    original = FrameChunks.read_frame_into

    def counting(self: FrameChunks, frame: int, out: np.ndarray) -> bool:
        decoded.append(frame)
        return original(self, frame, out)

    monkeypatch.setattr(FrameChunks, "read_frame_into", counting)
    batch = ds.read_batch(indices)
    assert len(decoded) == 3 * len(indices)   # I_marked, I_pure and depth once per sample
    assert_same(batch, expected_batch(ds, indices, written), channels_last=channels_last)
    decoded.clear()
    alone = TactileFrameDataset(root, compact=compact, channels_last=channels_last, fields=("marked_rgb",))
    alone.read_batch(indices)
    decoded.clear()
    assert_same(alone.read_batch(indices), expected_batch(alone, indices, written), channels_last=channels_last)
    assert len(decoded) == 2 * len(indices)   # without I_pure in the batch, I_marked decodes its base itself
