"""The loaders' fast path (direct chunk decoding, batch reads, FrameBatchLoader) against straightforward reads."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import h5py
import hdf5plugin  # noqa: F401  (the Blosc filter, for the straightforward reads)
import numpy as np
import pytest
import torch
from factories import assert_same, make_dataset

from univtac_data.loaders import FRAME_FIELDS, FrameBatchLoader, TactileFrameDataset
from univtac_data.loaders.buffers import BatchBuffers
from univtac_data.loaders.chunks import FrameChunks, fletcher32
from univtac_data.loaders.frames import convert_compact, convert_target
from univtac_data.storage import Dataset
from univtac_data.storage.errors import CorruptFileError

ALL_FIELDS = tuple(FRAME_FIELDS)


@pytest.fixture(scope="module", params=["hdf5", "zarr"])
def root(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_dataset(tmp_path_factory.mktemp(request.param) / "d", request.param, 2, n_frames=5)


def straightforward_sample(root: Path, ds: TactileFrameDataset, index: int) -> dict[str, Any]:
    """Sample ``index`` read the plain way: the episode's arrays through ``EpisodeHandle.read``, converted."""
    ref, frame, pad = ds._row(index)
    convert = convert_compact if ds.config.compact else convert_target
    sample: dict[str, Any] = {}
    with Dataset.open(root).open_episode(ref.episode_id) as handle:
        for key in ds.config.fields:
            path = f"tactile/{pad}/{FRAME_FIELDS[key]}"
            value = handle.read(path) if key == "markers_ref" else handle.read(path, frame)
            name, sample[name] = convert(key, value, 320, 240)
    sample.update(sensor=ref.sensor, pad=pad, episode_id=ref.episode_id, name=ref.name, frame=frame,
                  dataset=ref.dataset)
    return sample


@pytest.mark.parametrize("compact", [False, True])
def test_samples_equal_a_straightforward_read(root: Path, compact: bool) -> None:
    ds = TactileFrameDataset(root, fields=ALL_FIELDS, compact=compact)
    for index in range(len(ds)):
        assert_same(ds[index], straightforward_sample(root, ds, index))


@pytest.mark.parametrize("compact", [False, True])
def test_batches_equal_default_collate_of_samples(root: Path, compact: bool) -> None:
    ds = TactileFrameDataset(root, fields=ALL_FIELDS, compact=compact)
    indices = [7, 0, 19, 3, 3, 12]
    expected = torch.utils.data.default_collate([ds[k] for k in indices])
    assert_same(ds.read_batch(indices), expected)
    assert_same(ds[indices], expected)   # a list index, as DataLoader(batch_size=None, sampler=BatchSampler) passes


def test_hdf5_images_and_depth_take_the_chunk_path(tmp_path: Path) -> None:
    root = make_dataset(tmp_path / "d", "hdf5", 1, n_frames=2)
    ds = TactileFrameDataset(root, compact=True)
    ds[0]
    (entry,) = ds.reader._open.values()
    assert {path.rsplit("/", 1)[1] for path, source in entry.frames.items() if source.chunks is not None} \
        == {"marked_rgb", "pure_rgb", "depth_um"}


@pytest.mark.parametrize("threads", [1, 2])
def test_frame_batch_loader_matches_default_collate(root: Path, threads: int) -> None:
    ds = TactileFrameDataset(root, compact=True)
    loader = FrameBatchLoader(ds, batch_size=6, shuffle=True, seed=3, threads=threads, prefetch=1)
    got = list(loader)
    order = np.random.default_rng(3).permutation(len(ds)).tolist()
    assert len(got) == len(loader) == 4
    for k, batch in enumerate(got):
        assert_same(batch, torch.utils.data.default_collate([ds[i] for i in order[6 * k:6 * k + 6]]))
    assert loader.epoch == 1 and ds.reader.n_open == 2   # only the test's own reads opened the dataset's reader
    again = [batch["frame"].tolist() for batch in loader]   # the next epoch is shuffled differently
    assert sorted(sum(again, [])) == sorted(sum((b["frame"].tolist() for b in got), []))
    assert again != [b["frame"].tolist() for b in got]


def test_frame_batch_loader_with_a_batch_sampler_and_a_transform(root: Path) -> None:
    ds = TactileFrameDataset(root, transform=lambda s: {**s, "frame": s["frame"] + 100})
    got = list(FrameBatchLoader(ds, batch_sampler=[[0, 1], [5]], threads=2))
    assert [b["frame"].tolist() for b in got] == [[100, 100], [102]]


def test_batched_fetch_in_two_worker_processes(root: Path) -> None:
    ds = TactileFrameDataset(root, compact=True)
    ds[0]   # the parent holds an open handle; the workers must open their own
    sampler = torch.utils.data.BatchSampler(torch.utils.data.SequentialSampler(ds), batch_size=7, drop_last=False)
    loader = torch.utils.data.DataLoader(ds, batch_size=None, sampler=sampler, num_workers=2)
    got = list(loader)
    assert len(got) == 3
    for batch, indices in zip(got, sampler):
        assert_same(batch, torch.utils.data.default_collate([ds[i] for i in indices]))


@pytest.mark.parametrize("size", [1, 2, 3, 7, 720, 721, 4099])
def test_fletcher32_matches_hdf5(tmp_path: Path, size: int) -> None:
    rng = np.random.default_rng(size)
    with h5py.File(tmp_path / "f.h5", "w") as f:
        for name, data in (("random", rng.integers(0, 256, (2, size), dtype=np.uint8)),
                           ("zeros", np.zeros((2, size), np.uint8)),
                           ("ones", np.full((2, size), 255, np.uint8))):
            dataset = f.create_dataset(name, data=data, chunks=(1, size), fletcher32=True)
            for frame in range(2):
                _, chunk = dataset.id.read_direct_chunk((frame, 0))
                assert fletcher32(chunk[:-4]) == int.from_bytes(chunk[-4:], "little"), (name, frame)


def flip_chunk_byte(path: Path, array: str, frame: int) -> None:
    """Flip one byte in the middle of ``frame``'s stored chunk of ``array``."""
    with h5py.File(path, "r") as f:
        info = f[array].id.get_chunk_info_by_coord((frame,) + (0,) * (f[array].ndim - 1))
        offset = int(info.byte_offset) + int(info.size) // 2
    with open(path, "r+b") as handle:
        handle.seek(offset)
        byte = handle.read(1)
        handle.seek(offset)
        handle.write(bytes([byte[0] ^ 0xFF]))


@pytest.mark.parametrize("array", ["tactile/left/marked_rgb", "tactile/left/depth_um"])
def test_a_damaged_chunk_raises_one_line_naming_the_file(tmp_path: Path, array: str) -> None:
    root = make_dataset(tmp_path / "d", "hdf5", 1, n_frames=3)
    path = root / "episodes" / "ep0.h5"
    flip_chunk_byte(path, array, 1)
    ds = TactileFrameDataset(root, compact=True, pads="left")
    with h5py.File(path, "r") as f:
        chunks = FrameChunks.of(f[array])
        assert chunks is not None
        assert not chunks.read_frame_into(1, np.empty(chunks.frame_shape, f[array].dtype))   # the checksum fails
        assert chunks.read_frame_into(0, np.empty(chunks.frame_shape, f[array].dtype))
    for read in (lambda: ds[1], lambda: ds.read_batch([0, 1, 2]), lambda: list(FrameBatchLoader(ds, 3, threads=2))):
        with pytest.raises(CorruptFileError) as error:
            read()
        message = str(error.value)
        assert "\n" not in message and "ep0.h5" in message and array in message
    ds[0], ds[2]   # the undamaged frames still read
    assert os.path.exists(path)


def test_batch_buffers_are_reused_only_when_no_tensor_refers_to_them() -> None:
    buffers = BatchBuffers()
    first = buffers.empty((2, 3), torch.uint8)
    address = first.data_ptr()
    assert buffers.empty((2, 3), torch.uint8).data_ptr() != address   # `first` is alive
    view = first[1]
    del first
    assert buffers.empty((2, 3), torch.uint8).data_ptr() != address   # a view of it is alive
    del view
    again = buffers.empty((2, 3), torch.uint8)
    assert again.data_ptr() == address
    as_numpy = again.numpy()
    del again
    assert buffers.empty((2, 3), torch.uint8).data_ptr() != address   # a NumPy view of it is alive
    del as_numpy
    shared = buffers.empty((2, 3), torch.uint8).share_memory_()      # moved: no longer uses the buffer
    assert shared.data_ptr() != address and buffers.empty((2, 3), torch.uint8).data_ptr() == address
