"""Datasets of more episodes than a reader keeps open: the layout cache (``loaders/layouts.py``) and the
readers' own descriptors (``loaders/files.py``) against the plain h5py path."""

from __future__ import annotations

import gc
import os
import pickle
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from factories import assert_same, make_dataset

from univtac_data.loaders import FRAME_FIELDS, FrameBatchLoader, TactileFrameDataset
from univtac_data.loaders.chunks import ChunkPlaces, FrameLayout
from univtac_data.loaders.files import CachedFile, EpisodeFiles
from univtac_data.loaders.layouts import EpisodeLayout, FileIdentity, LayoutCache
from univtac_data.storage.errors import CorruptFileError

ALL_FIELDS = tuple(FRAME_FIELDS)
N_EPISODES, N_FRAMES = 6, 3          # 36 pad samples
BOUNDS = {"max_open_episodes": 2, "max_open_files": 2}   # far fewer than the episodes a batch spans


@pytest.fixture(scope="module")
def root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_dataset(tmp_path_factory.mktemp("many") / "d", "hdf5", N_EPISODES, n_frames=N_FRAMES)


def plain(root: Path, **kwargs: Any) -> TactileFrameDataset:
    """The same dataset read through h5py only: no layout kept (every episode reopened when evicted)."""
    return TactileFrameDataset(root, layout_cache_mib=0, **kwargs)


def shuffled_batches(n: int, batch_size: int, seed: int) -> list[list[int]]:
    order = np.random.default_rng(seed).permutation(n).tolist()
    return [order[k:k + batch_size] for k in range(0, n, batch_size)]


def open_descriptors() -> int:
    return len(os.listdir("/proc/self/fd"))


@pytest.mark.parametrize("compact", [False, True])
def test_values_equal_the_h5py_path_over_several_epochs(root: Path, compact: bool) -> None:
    ds = TactileFrameDataset(root, fields=ALL_FIELDS, compact=compact, channels_last=True, **BOUNDS)
    reference = plain(root, fields=ALL_FIELDS, compact=compact, channels_last=True)
    for epoch in range(2):   # the first records the layouts, the second reads through them only
        for indices in shuffled_batches(len(ds), 8, epoch):
            assert_same(ds.read_batch(indices), reference.read_batch(indices), channels_last=True)
    for index in (0, 17, len(ds) - 1):   # single samples and the raw arrays too
        assert_same(ds[index], reference[index], channels_last=True)
        for key, value in ds.read_raw(index)[3].items():
            assert np.array_equal(value, reference.read_raw(index)[3][key]) and value.dtype == \
                reference.read_raw(index)[3][key].dtype, key


def test_h5py_opens_stop_after_the_first_epoch(root: Path, h5py_opens: list[str]) -> None:
    ds = TactileFrameDataset(root, compact=True, channels_last=True, **BOUNDS)
    h5py_opens.clear()   # selecting the episodes opened each once
    for indices in shuffled_batches(len(ds), 8, 0):
        ds.read_batch(indices)
    first = len(h5py_opens)
    assert N_EPISODES <= first <= 2 * N_EPISODES   # about once per episode and pad; the handles were evicted
    for epoch in (1, 2):
        for indices in shuffled_batches(len(ds), 8, epoch):
            ds.read_batch(indices)
    assert len(h5py_opens) == first and ds.reader.opens == first
    assert ds.reader.n_open <= BOUNDS["max_open_episodes"] and ds.reader.n_files <= BOUNDS["max_open_files"]


def test_without_a_cache_every_batch_reopens_its_episodes(root: Path, h5py_opens: list[str]) -> None:
    ds = plain(root, compact=True, **BOUNDS)
    h5py_opens.clear()
    for epoch in range(2):
        for indices in shuffled_batches(len(ds), 8, epoch):
            ds.read_batch(indices)
    assert len(h5py_opens) > 4 * N_EPISODES and len(ds.reader.layouts) == 0


def test_frame_batch_loader_threads_share_the_cache(root: Path, h5py_opens: list[str]) -> None:
    ds = TactileFrameDataset(root, compact=True, channels_last=True, **BOUNDS)
    reference = plain(root, compact=True, channels_last=True)
    loader = FrameBatchLoader(ds, batch_size=5, shuffle=True, seed=1, threads=2, prefetch=1)
    expected = [[torch.utils.data.default_collate([reference[i] for i in indices])
                 for indices in shuffled_batches(len(ds), 5, 1 + epoch)] for epoch in range(3)]
    reference.reader.close()
    del reference
    gc.collect()  # files of earlier tests that only the collector closes would otherwise close mid-count
    before = open_descriptors()
    h5py_opens.clear()
    opens_per_epoch = []
    for epoch in range(3):
        for k, batch in enumerate(loader):
            assert_same(batch, expected[epoch][k], channels_last=True)
            # each thread: at most its bounds between batches, plus the episodes of the batch it is reading
            assert open_descriptors() - before <= 2 * (BOUNDS["max_open_episodes"] + BOUNDS["max_open_files"] + 2 * 5)
        opens_per_epoch.append(len(h5py_opens))
        h5py_opens.clear()
        assert open_descriptors() == before   # the loader closed its threads' handles and descriptors
    assert opens_per_epoch[0] >= N_EPISODES and opens_per_epoch[1:] == [0, 0]


def test_the_cache_stays_within_its_budget(root: Path, h5py_opens: list[str]) -> None:
    one_episode = TactileFrameDataset(root, compact=True, episodes=["ep0"])
    for index in range(len(one_episode)):
        one_episode[index]
    cache = one_episode.reader.layouts
    layout = cache.get(str(root / "episodes" / "ep0.h5"))
    assert layout is not None and set(layout.pooled) == {"tactile/left/pure_ref_rgb", "tactile/right/pure_ref_rgb"}
    per_episode, pooled = layout.nbytes, cache.nbytes - layout.nbytes
    assert 0 < per_episode < 64 * 1024
    assert pooled == 240 * 320 * 3   # both pads' pure_ref_rgb, the same background image: kept and counted once
    budget = pooled + 2.5 * per_episode   # two whole episodes (more partly recorded ones); every episode shares it
    ds = TactileFrameDataset(root, compact=True, layout_cache_mib=budget / 2**20, **BOUNDS)
    reference = plain(root, compact=True)
    for indices in shuffled_batches(len(ds), 8, 0) + shuffled_batches(len(ds), 8, 1):
        assert_same(ds.read_batch(indices), reference.read_batch(indices))
        assert ds.reader.layouts.nbytes <= budget and len(ds.reader.layouts) < N_EPISODES


def replace_file(target: Path, source: Path, *, in_place: bool) -> None:
    """Put ``source``'s bytes at ``target``: a new file renamed over it (what the writers do), or rewritten
    in place (same inode)."""
    if in_place:
        with open(source, "rb") as src, open(target, "r+b") as dst:
            dst.truncate(0)
            shutil.copyfileobj(src, dst)
    else:
        shutil.copyfile(source, target.with_suffix(".new"))
        os.replace(target.with_suffix(".new"), target)


@pytest.mark.parametrize("in_place", [False, True])
def test_a_replaced_episode_file_is_read_again(tmp_path: Path, in_place: bool) -> None:
    root = make_dataset(tmp_path / "d", "hdf5", 3, n_frames=N_FRAMES)
    ds = TactileFrameDataset(root, fields=ALL_FIELDS, compact=True, max_open_episodes=1, max_open_files=1)
    everything = list(range(len(ds)))
    before = ds.read_batch(everything)   # every layout recorded; ep0's descriptor or handle may still be open
    ds.read_batch(everything[:2])        # ep0 touched last
    target = root / "episodes" / "ep0.h5"
    old = FileIdentity.of(os.stat(target))
    replace_file(target, root / "episodes" / "ep1.h5", in_place=in_place)   # ep1's content under ep0's name
    assert FileIdentity.of(os.stat(target)) != old
    after = ds.read_batch(everything)
    expected = plain(root, fields=ALL_FIELDS, compact=True).read_batch(everything)
    assert_same(after, expected)
    ep0 = [k for k, eid in enumerate(before["episode_id"]) if eid == "ep0"]
    assert not torch.equal(before["marked_rgb"][ep0], after["marked_rgb"][ep0])   # it did change
    assert ds.reader.layouts.get(str(target)).identity == FileIdentity.of(os.stat(target))


def flip_byte(path: Path, array: str, frame: int, *, keep_mtime: bool) -> None:
    """Flip one byte in the middle of ``frame``'s chunk of ``array``; ``keep_mtime``: restore the modification
    time, so that the file's identity (device, inode, size, mtime) stays the same."""
    import h5py
    with h5py.File(path, "r") as f:
        info = f[array].id.get_chunk_info_by_coord((frame,) + (0,) * (f[array].ndim - 1))
        offset = int(info.byte_offset) + int(info.size) // 2
    stat = os.stat(path)
    with open(path, "r+b") as handle:
        handle.seek(offset)
        byte = handle.read(1)
        handle.seek(offset)
        handle.write(bytes([byte[0] ^ 0xFF]))
    if keep_mtime:
        os.utime(path, ns=(stat.st_atime_ns, stat.st_mtime_ns))


@pytest.mark.parametrize("keep_mtime", [False, True])
def test_a_damaged_chunk_of_a_cached_episode_raises_one_line(tmp_path: Path, keep_mtime: bool) -> None:
    root = make_dataset(tmp_path / "d", "hdf5", 3, n_frames=N_FRAMES)
    ds = TactileFrameDataset(root, compact=True, pads="left", max_open_episodes=1, max_open_files=1)
    everything = list(range(len(ds)))
    ds.read_batch(everything)   # recorded, and ep0's handle closed since
    path = root / "episodes" / "ep0.h5"
    identity = FileIdentity.of(os.stat(path))
    flip_byte(path, "tactile/left/pure_rgb", 1, keep_mtime=keep_mtime)
    # unchanged identity: the cached places are used, the checksum fails, h5py reads the frame and raises
    assert (FileIdentity.of(os.stat(path)) == identity) == keep_mtime
    for read in (lambda: ds[1], lambda: ds.read_batch(everything), lambda: list(FrameBatchLoader(ds, 4, threads=2))):
        with pytest.raises(CorruptFileError) as error:
            read()
        message = str(error.value)
        assert "\n" not in message and "ep0.h5" in message and "tactile/left/pure_rgb" in message
    assert_same(ds.read_batch([0, 2, 5]), plain(root, compact=True, pads="left").read_batch([0, 2, 5]))


class ReaderState(torch.utils.data.Dataset[dict[str, Any]]):
    """Batches of ``inner`` with the reading process, and what its reader had before and after the read."""

    def __init__(self, inner: TactileFrameDataset) -> None:
        self.inner = inner

    def __len__(self) -> int:
        return len(self.inner)

    def __getitem__(self, indices: list[int]) -> dict[str, Any]:
        kept_before = len(self.inner.reader.layouts)
        batch = self.inner.read_batch(indices)
        return {**batch, "pid": os.getpid(), "kept_before": kept_before, "opens": self.inner.reader.opens}


def test_worker_processes_start_with_an_empty_cache_and_read_the_same_values(root: Path) -> None:
    ds = TactileFrameDataset(root, compact=True, channels_last=True, **BOUNDS)
    ds.read_batch(list(range(len(ds))))   # the parent's cache is full and it holds open descriptors
    assert len(ds.reader.layouts) == N_EPISODES and ds.reader.n_files > 0
    shuffled = torch.utils.data.RandomSampler(ds, generator=torch.Generator().manual_seed(0))
    sampler = torch.utils.data.BatchSampler(shuffled, batch_size=6, drop_last=False)
    indices = list(sampler)
    loader = torch.utils.data.DataLoader(ReaderState(ds), batch_size=None, sampler=indices, num_workers=2)
    reference = plain(root, compact=True, channels_last=True)
    first_of: dict[int, int] = {}
    for batch, wanted in zip(loader, indices):
        pid = batch.pop("pid")
        kept_before, opens = batch.pop("kept_before"), batch.pop("opens")
        first_of.setdefault(pid, kept_before)
        assert opens <= len(indices) * 6   # its own handles, counted from zero
        assert_same(batch, reference.read_batch(wanted), channels_last=True)
    assert len(first_of) == 2 and os.getpid() not in first_of and set(first_of.values()) == {0}


def test_pickling_keeps_settings_and_drops_descriptors_and_layouts(root: Path) -> None:
    ds = TactileFrameDataset(root, compact=True, layout_cache_mib=1.5, **BOUNDS)
    ds.read_batch(list(range(len(ds))))
    clone = pickle.loads(pickle.dumps(ds))
    assert len(clone.reader.layouts) == 0 and clone.reader.n_files == 0 and clone.reader.n_open == 0
    assert clone.reader.layouts.budget_bytes == int(1.5 * 2**20) and clone.reader.files.max_open == 2
    assert clone.reader.files.layouts is clone.reader.layouts
    assert_same(clone.read_batch([3, 30, 11]), ds.read_batch([3, 30, 11]))


def test_zarr_datasets_of_many_episodes_still_read(tmp_path: Path) -> None:
    root = make_dataset(tmp_path / "z", "zarr", 3, n_frames=2)
    ds = TactileFrameDataset(root, fields=ALL_FIELDS, compact=True, max_open_episodes=1)
    indices = shuffled_batches(len(ds), 12, 0)[0]
    expected = torch.utils.data.default_collate([ds[i] for i in indices])
    assert_same(ds.read_batch(indices), expected)
    assert len(ds.reader.layouts) == 0 and ds.reader.n_files == 0


# --- LayoutCache and EpisodeFiles alone ------------------------------------------------------------

def layout_of(nbytes_of_whole: int, identity: FileIdentity = FileIdentity(1, 2, 3, 4)) -> EpisodeLayout:
    return EpisodeLayout(identity).with_arrays({}, {"a": np.zeros(nbytes_of_whole, np.uint8)})


def test_layout_cache_drops_least_recently_used_past_its_budget() -> None:
    size = layout_of(1000).nbytes
    cache = LayoutCache(budget_bytes=3 * size)
    identity = FileIdentity(1, 2, 3, 4)
    for name in ("a", "b", "c"):
        cache.record(name, identity, whole={"a": np.zeros(1000, np.uint8)})
    assert cache.get("a") is not None   # now the most recent
    cache.record("d", identity, whole={"a": np.zeros(1000, np.uint8)})
    assert [cache.get(n) is not None for n in "abcd"] == [True, False, True, True]
    assert cache.nbytes == 3 * size and len(cache) == 3
    cache.record("e", identity, whole={"a": np.zeros(10 * size, np.uint8)})   # larger than the budget: not kept
    assert cache.get("e") is None and cache.nbytes <= 3 * size
    kept = cache.get("a")
    assert kept is not None and not kept.whole["a"].flags.writeable   # threads share it


def test_layout_cache_keeps_one_version_per_file() -> None:
    cache = LayoutCache()
    old, new = FileIdentity(1, 2, 3, 4), FileIdentity(1, 2, 3, 5)
    frame = FrameLayout((2, 2), np.dtype(np.uint8), 4, 1, ChunkPlaces(np.zeros(1, np.int64), np.ones(1, np.int64)))
    cache.record("f", old, frames={"x": frame})
    cache.record("f", old, whole={"y": np.ones(3)})
    both = cache.get("f")
    assert both is not None and set(both.frames) == {"x"} and set(both.whole) == {"y"}
    cache.record("f", new, whole={"z": np.ones(3)})   # another version replaces, never merges
    layout = cache.get("f")
    assert layout is not None and layout.identity == new and set(layout.frames) == set() and set(layout.whole) == {"z"}
    cache.discard("f", old)   # a stale discard leaves the newer version
    assert cache.get("f") is not None
    cache.discard("f", new)
    assert cache.get("f") is None and cache.nbytes == 0


def test_layout_cache_with_no_budget_keeps_nothing_and_pickles_empty() -> None:
    empty = LayoutCache(budget_bytes=0)
    empty.record("f", FileIdentity(1, 2, 3, 4), whole={"a": np.ones(2)})
    assert empty.get("f") is None
    cache = LayoutCache(budget_bytes=10**6)
    cache.record("f", FileIdentity(1, 2, 3, 4), whole={"a": np.ones(2)})
    clone = pickle.loads(pickle.dumps(cache))
    assert clone.budget_bytes == 10**6 and len(clone) == 0 and clone.get("f") is None
    cache._pid = -1   # as if forked: the child starts empty, with a fresh lock
    assert cache.get("f") is None and len(cache) == 0
    with pytest.raises(ValueError, match=r"budget_bytes must be >= 0 \(got -1\)"):
        LayoutCache(-1)


def test_a_descriptor_of_another_version_is_never_used(tmp_path: Path) -> None:
    path = tmp_path / "f"
    path.write_bytes(b"0123456789")
    files = EpisodeFiles(LayoutCache(), max_open=1)
    actual = FileIdentity.of(os.stat(path))
    stale = CachedFile(str(path), actual._replace(size=11), EpisodeLayout(actual), checked=0)
    before = open_descriptors()
    assert files.descriptor(stale) == -1 and open_descriptors() == before
    fresh = CachedFile(str(path), actual, EpisodeLayout(actual), checked=0)
    assert files.descriptor(fresh) >= 0 and os.pread(fresh.descriptor, 4, 2) == b"2345"
    os.close(fresh.descriptor)
    with pytest.raises(ValueError, match=r"max_open_files must be >= 1 \(got 0\)"):
        EpisodeFiles(LayoutCache(), max_open=0)
