"""The loaders' fast path (direct chunk decoding, batch reads, FrameBatchLoader) against straightforward reads."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import Any

import h5py
import hdf5plugin  # noqa: F401  (the Blosc filter, for the straightforward reads)
import numpy as np
import pytest
import torch
from factories import assert_same, has_hwc_memory, make_dataset

from univtac_data.loaders import FRAME_FIELDS, FrameBatchLoader, TactileFrameDataset, to_float
from univtac_data.loaders.buffers import BatchBuffers
from univtac_data.loaders.chunks import FrameChunks, checksum_matches, fletcher32
from univtac_data.loaders.frames import convert_compact, convert_target, decode_batch
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


@pytest.mark.parametrize("channels_last", [False, True])
@pytest.mark.parametrize("compact", [False, True])
def test_samples_equal_a_straightforward_read(root: Path, compact: bool, channels_last: bool) -> None:
    ds = TactileFrameDataset(root, fields=ALL_FIELDS, compact=compact, channels_last=channels_last)
    for index in range(len(ds)):
        assert_same(ds[index], straightforward_sample(root, ds, index), channels_last=channels_last)


@pytest.mark.parametrize("channels_last", [False, True])
@pytest.mark.parametrize("compact", [False, True])
def test_batches_equal_default_collate_of_samples(root: Path, compact: bool, channels_last: bool) -> None:
    ds = TactileFrameDataset(root, fields=ALL_FIELDS, compact=compact, channels_last=channels_last)
    indices = [7, 0, 19, 3, 3, 12]
    expected = torch.utils.data.default_collate([ds[k] for k in indices])   # contiguous: torch.stack's layout
    assert_same(ds.read_batch(indices), expected, channels_last=channels_last)
    # a list index, as DataLoader(batch_size=None, sampler=BatchSampler) passes
    assert_same(ds[indices], expected, channels_last=channels_last)


def test_channels_last_batches_are_channels_last_views_of_hwc_memory(root: Path) -> None:
    ds = TactileFrameDataset(root, compact=True, channels_last=True)
    batch = ds.read_batch([0, 5, 9])
    image = batch["marked_rgb"]
    assert image.shape == (3, 3, 240, 320) and image.is_contiguous(memory_format=torch.channels_last)
    assert image.stride() == (240 * 320 * 3, 1, 320 * 3, 3)
    sample = ds[5]["pure_rgb"]
    assert sample.shape == (3, 240, 320) and sample.stride() == (1, 320 * 3, 3)
    assert batch["depth_um"].is_contiguous() and batch["depth_um"].shape == (3, 1, 240, 320)


@pytest.mark.parametrize("compact", [False, True])
def test_channels_last_values_equal_the_contiguous_layout(root: Path, compact: bool) -> None:
    indices = [3, 18, 4]
    plain = TactileFrameDataset(root, compact=compact).read_batch(indices)
    hwc = TactileFrameDataset(root, compact=compact, channels_last=True).read_batch(indices)
    assert_same(hwc, plain, channels_last=True)
    assert_same(TactileFrameDataset(root, compact=compact, channels_last=True)[4],
                TactileFrameDataset(root, compact=compact)[4], channels_last=True)


def test_to_float_keeps_the_channels_last_layout_and_gives_the_float_targets(root: Path) -> None:
    indices = [1, 10, 19]
    floats = TactileFrameDataset(root, channels_last=True).read_batch(indices)
    converted = to_float(TactileFrameDataset(root, compact=True, channels_last=True).read_batch(indices))
    assert set(converted) == set(floats)
    for key in floats:
        assert_same(converted[key], floats[key], channels_last=True, key=key)


def test_a_transform_still_gives_channels_last_batches(root: Path) -> None:
    ds = TactileFrameDataset(root, compact=True, channels_last=True,
                             transform=lambda s: {**s, "frame": s["frame"] + 100})
    batch = ds.read_batch([2, 6])
    assert has_hwc_memory(batch["marked_rgb"]) and batch["frame"].tolist() == [101, 103]
    plain = TactileFrameDataset(root, compact=True).read_batch([2, 6])
    assert torch.equal(batch["marked_rgb"], plain["marked_rgb"])


class ArraySource:
    """Frames from an in-memory (T, ...) array, read like a ``FrameSource``."""

    def __init__(self, frames: np.ndarray) -> None:
        self.frames, self.frame_shape, self.dtype = frames, frames.shape[1:], frames.dtype

    def read_into(self, frame: int, out: np.ndarray) -> None:
        out[...] = self.frames[frame].view(out.dtype)


@pytest.mark.parametrize("channels_last", [False, True])
@pytest.mark.parametrize("compact", [False, True])
def test_decoded_batches_equal_converted_frames_on_random_images(compact: bool, channels_last: bool) -> None:
    rgb = np.random.default_rng(4).integers(0, 256, (3, 24, 32, 3), dtype=np.uint8)   # every byte value
    sources = [(ArraySource(rgb), t) for t in (2, 0, 1)]
    name, batch = decode_batch("marked_rgb", sources, compact, channels_last=channels_last)
    convert = convert_compact if compact else convert_target
    expected = torch.stack([convert("marked_rgb", rgb[t], 32, 24)[1] for t in (2, 0, 1)])
    assert_same({name: batch}, {"marked_rgb": expected}, channels_last=channels_last)


def test_compact_depth_beyond_int16_raises_in_batches_and_samples() -> None:
    depth = np.zeros((2, 4, 5), np.uint16)
    depth[1, 2, 3] = 40_000
    sources = [(ArraySource(depth), t) for t in (0, 1)]
    with pytest.raises(ValueError, match=r"depth 40000 um exceeds the compact int16 range \(32767 um\)"):
        decode_batch("depth_mm", sources, compact=True)
    with pytest.raises(ValueError, match=r"depth 40000 um exceeds the compact int16 range"):
        convert_compact("depth_mm", depth[1], 5, 4)
    name, batch = decode_batch("depth_mm", sources[:1], compact=True)
    assert name == "depth_um" and batch.dtype == torch.int16 and batch.shape == (1, 1, 4, 5)


@pytest.mark.parametrize("channels_last", [False, True])
def test_a_batch_spanning_more_episodes_than_max_open(root: Path, channels_last: bool) -> None:
    ds = TactileFrameDataset(root, fields=ALL_FIELDS, compact=True, channels_last=channels_last, max_open_episodes=1)
    indices = [0, 19, 1, 18, 0]
    batch = ds.read_batch(indices)
    assert len(set(batch["episode_id"])) == 2
    assert ds.reader.n_open == 1 and ds.reader.opens == 2   # each episode opened once; closed down after the batch
    everything = TactileFrameDataset(root, fields=ALL_FIELDS, compact=True, channels_last=channels_last)
    assert_same(batch, everything.read_batch(indices), channels_last=channels_last)
    loader = FrameBatchLoader(ds, batch_size=7, shuffle=True, threads=2)
    assert sum(len(b["frame"]) for b in loader) == len(ds)


def test_hdf5_images_and_depth_take_the_chunk_path(tmp_path: Path) -> None:
    root = make_dataset(tmp_path / "d", "hdf5", 1, n_frames=2)
    ds = TactileFrameDataset(root, compact=True)
    ds[0]
    (entry,) = ds.reader._open.values()
    assert {path.rsplit("/", 1)[1] for path, source in entry.frames.items() if source.chunks is not None} \
        == {"marked_rgb", "pure_rgb", "depth_um"}


@pytest.mark.parametrize(("threads", "channels_last"), [(1, False), (2, False), (2, True)])
def test_frame_batch_loader_matches_default_collate(root: Path, threads: int, channels_last: bool) -> None:
    ds = TactileFrameDataset(root, compact=True, channels_last=channels_last)
    loader = FrameBatchLoader(ds, batch_size=6, shuffle=True, seed=3, threads=threads, prefetch=1)
    got = list(loader)
    order = np.random.default_rng(3).permutation(len(ds)).tolist()
    assert len(got) == len(loader) == 4
    for k, batch in enumerate(got):
        assert_same(batch, torch.utils.data.default_collate([ds[i] for i in order[6 * k:6 * k + 6]]),
                    channels_last=channels_last)
    assert loader.epoch == 1
    # only the test's own reads used the dataset's reader; they needed no h5py or zarr handle, since the loader's
    # threads had recorded every array's layout (HDF5) or chunks and small arrays (Zarr) in the cache they share
    assert ds.reader.opens == 0 and ds.reader.n_open == 0
    if ds.datasets[0].info.storage == "hdf5":
        assert ds.reader.n_files == 2
    again = [batch["frame"].tolist() for batch in loader]   # the next epoch is shuffled differently
    assert sorted(sum(again, [])) == sorted(sum((b["frame"].tolist() for b in got), []))
    assert again != [b["frame"].tolist() for b in got]


def test_frame_batch_loader_with_a_batch_sampler_and_a_transform(root: Path) -> None:
    ds = TactileFrameDataset(root, transform=lambda s: {**s, "frame": s["frame"] + 100})
    got = list(FrameBatchLoader(ds, batch_sampler=[[0, 1], [5]], threads=2))
    assert [b["frame"].tolist() for b in got] == [[100, 100], [102]]


@pytest.mark.parametrize("channels_last", [False, True])
def test_batched_fetch_in_two_worker_processes(root: Path, channels_last: bool) -> None:
    ds = TactileFrameDataset(root, compact=True, channels_last=channels_last)
    ds[0]   # the parent holds an open handle; the workers must open their own
    sampler = torch.utils.data.BatchSampler(torch.utils.data.SequentialSampler(ds), batch_size=7, drop_last=False)
    loader = torch.utils.data.DataLoader(ds, batch_size=None, sampler=sampler, num_workers=2)
    got = list(loader)
    assert len(got) == 3
    for batch, indices in zip(got, sampler):   # the layout survives the trip through shared memory
        assert_same(batch, torch.utils.data.default_collate([ds[i] for i in indices]), channels_last=channels_last)


# odd and even sizes around HDF5's blocks of 360 words, and past 65,536 words
@pytest.mark.parametrize("size", [1, 2, 3, 7, 719, 720, 721, 1441, 4099, 131_073, 131_074])
def test_fletcher32_matches_hdf5(tmp_path: Path, size: int) -> None:
    rng = np.random.default_rng(size)
    last_byte_only = np.zeros((2, size), np.uint8)
    last_byte_only[:, -1] = 255   # an odd size's last byte is the high byte of a word of its own
    with h5py.File(tmp_path / "f.h5", "w") as f:
        for name, data in (("random", rng.integers(0, 256, (2, size), dtype=np.uint8)),
                           ("zeros", np.zeros((2, size), np.uint8)),
                           ("ones", np.full((2, size), 255, np.uint8)),
                           ("last_byte_only", last_byte_only)):
            dataset = f.create_dataset(name, data=data, chunks=(1, size), fletcher32=True)
            for frame in range(2):
                _, chunk = dataset.id.read_direct_chunk((frame, 0))
                assert fletcher32(chunk[:-4]) == int.from_bytes(chunk[-4:], "little"), (name, frame)
                assert checksum_matches(chunk), (name, frame)
    assert fletcher32(bytes(size)) == 0   # all-zero data: HDF5 stores 0, not 0xFFFFFFFF


@pytest.mark.parametrize("position", [0, 1, 500, -5, -1])
def test_checksum_matches_rejects_any_flipped_byte(position: int) -> None:
    data = np.random.default_rng(1).integers(0, 256, 1001, dtype=np.uint8).tobytes()
    chunk = bytearray(data + fletcher32(data).to_bytes(4, "little"))
    assert checksum_matches(bytes(chunk))
    chunk[position] ^= 0x01
    assert not checksum_matches(bytes(chunk))


def test_chunks_are_read_at_their_place_in_the_file_as_h5py_reads_them(tmp_path: Path) -> None:
    root = make_dataset(tmp_path / "d", "hdf5", 1, n_frames=3)
    with h5py.File(root / "episodes" / "ep0.h5", "r") as f:
        for array in ("tactile/right/pure_rgb", "tactile/right/depth_um"):
            chunks = FrameChunks.of(f[array])
            assert chunks is not None and chunks.layout.places is not None and chunks.file_descriptor >= 0
            through_h5py = dataclasses.replace(chunks, file_descriptor=-1)   # read_direct_chunk
            for frame in range(3):
                assert chunks.stored_chunk(frame) == through_h5py.stored_chunk(frame)
                out = np.empty(chunks.frame_shape, f[array].dtype)
                assert chunks.read_frame_into(frame, out) and np.array_equal(out, f[array][frame])


def test_a_frame_never_written_is_left_to_h5py(tmp_path: Path) -> None:
    frames = np.random.default_rng(2).integers(0, 4, (3, 240, 320, 3), dtype=np.uint8)
    with h5py.File(tmp_path / "f.h5", "w") as f:
        array = f.create_dataset("rgb", shape=frames.shape, dtype=np.uint8, chunks=(1, 240, 320, 3),
                                 fletcher32=True, **hdf5plugin.Blosc(cname="zstd"))
        array[0], array[2] = frames[0], frames[2]   # frame 1 has no chunk: h5py reads the fill value
    with h5py.File(tmp_path / "f.h5", "r") as f:
        chunks = FrameChunks.of(f["rgb"])
        assert chunks is not None and chunks.layout.places is not None
        assert chunks.layout.places.offsets.tolist()[1] == -1 and chunks.layout.places.get(1) is None
        out = np.empty(chunks.frame_shape, np.uint8)
        assert [chunks.read_frame_into(k, out) for k in range(3)] == [True, False, True]
        assert np.array_equal(out, frames[2])


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
