"""The Zarr fast path (``loaders/zarr_chunks.py``): frames decoded straight from their shards, locally and
through fsspec URLs (``file://``, ``memory://``), with the same samples as the HDF5 loader and zarr's own reads."""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from pathlib import Path

import fsspec
import numpy as np
import pytest
from factories import assert_same, make_dataset

from univtac_data.loaders import FRAME_FIELDS, FrameBatchLoader, TactileFrameDataset
from univtac_data.loaders.zarr_chunks import ZarrFrameChunks, ZarrFrameLayout, crc32c_matches
from univtac_data.storage import Dataset
from univtac_data.storage.errors import CorruptFileError
from univtac_data.storage.zarr_store import ZarrHandle

ALL_FIELDS = tuple(FRAME_FIELDS)
DECODED = {"marked_rgb", "pure_rgb", "depth_um", "contact_mask"}


@pytest.fixture(scope="module")
def hdf5_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_dataset(tmp_path_factory.mktemp("h") / "d", "hdf5", 2, n_frames=5)


@pytest.fixture
def memory_url() -> Iterator[str]:
    url = f"memory://univtac-{uuid.uuid4().hex}"
    make_dataset(url, "zarr", 2, n_frames=5)
    yield url
    fsspec.filesystem("memory").rm(url.removeprefix("memory://"), recursive=True)


def zarr_roots(tmp_path: Path, memory_url: str) -> dict[str, str]:
    local = make_dataset(tmp_path / "z", "zarr", 2, n_frames=5)
    return {"local": str(local), "file_url": f"file://{local}", "memory_url": memory_url}


def count_zarr_frame_reads(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """Every per-frame read of an image, depth or mask array that goes through zarr (not the fast path)."""
    reads: list[str] = []
    original = ZarrHandle._read_raw

    def counting(self: ZarrHandle, path: str, index: object) -> np.ndarray:
        if path.rsplit("/", 1)[1] in DECODED and index != ():
            reads.append(path)
        return original(self, path, index)

    monkeypatch.setattr(ZarrHandle, "_read_raw", counting)
    return reads


@pytest.mark.parametrize("where", ["local", "file_url", "memory_url"])
@pytest.mark.parametrize(("compact", "channels_last"), [(False, False), (True, True)])
def test_zarr_samples_equal_hdf5_samples_through_the_fast_path(tmp_path, memory_url, hdf5_root, monkeypatch, where,
                                                               compact, channels_last):
    root = zarr_roots(tmp_path, memory_url)[where]
    reads = count_zarr_frame_reads(monkeypatch)
    zarr_ds = TactileFrameDataset(root, fields=ALL_FIELDS, compact=compact, channels_last=channels_last)
    hdf5_ds = TactileFrameDataset(hdf5_root, fields=ALL_FIELDS, compact=compact, channels_last=channels_last)
    assert len(zarr_ds) == len(hdf5_ds) == 20
    for index in range(len(zarr_ds)):
        a, b = zarr_ds[index], hdf5_ds[index]
        a.pop("dataset"), b.pop("dataset")
        assert_same(a, b, channels_last=channels_last)
    indices = [7, 0, 19, 3, 3, 12]
    assert_same(zarr_ds.read_batch(indices), hdf5_ds.read_batch(indices), channels_last=channels_last)
    for x, y in zip(FrameBatchLoader(zarr_ds, 6, threads=2, shuffle=False),
                    FrameBatchLoader(hdf5_ds, 6, threads=2, shuffle=False)):
        assert_same(x, y, channels_last=channels_last)
    assert reads == []   # every image, depth and mask frame came from the shards directly
    (entry,) = [e for e in zarr_ds.reader._open.values()][:1]
    kinds = {path.rsplit("/", 1)[1]: type(source.chunks) for path, source in entry.frames.items()}
    assert kinds == {name: ZarrFrameChunks for name in DECODED}


def test_layout_reads_frames_as_zarr_does(tmp_path):
    root = make_dataset(tmp_path / "z", "zarr", 1, n_frames=5, reference=False)
    with Dataset.open(root).open_episode("ep0") as handle:
        assert isinstance(handle, ZarrHandle)
        for path in ("tactile/left/marked_rgb", "tactile/right/depth_um", "tactile/left/contact_mask"):
            array = handle.zarr_array(path)
            layout = ZarrFrameLayout.of(array)
            assert layout is not None and layout.n_frames == 5 and layout.frame_shape == array.shape[1:]
            chunks = ZarrFrameChunks(layout, handle.loc.fs, handle.loc.join(handle.relpath, path), True)
            for t in range(5):   # frame 0 of depth and mask is all zeros: a chunk zarr never wrote
                out = np.empty(layout.frame_shape, layout.dtype)
                assert chunks.read_frame_into(t, out)
                np.testing.assert_array_equal(out, np.asarray(array[t]))
            assert not chunks.read_frame_into(5, np.empty(layout.frame_shape, layout.dtype))
        # a per-frame array chunked many frames a chunk is not one the fast path decodes
        assert ZarrFrameLayout.of(handle.zarr_array("tactile/left/markers_px")) is None


def flip_chunk_byte(root: Path, array: str, frame: int) -> None:
    """Flip one byte in the middle of frame ``frame``'s chunk inside its shard."""
    with Dataset.open(root).open_episode("ep0") as handle:
        layout = ZarrFrameLayout.of(handle.zarr_array(array))
        chunks = ZarrFrameChunks(layout, handle.loc.fs, handle.loc.join(handle.relpath, array), True)
        offset, size = chunks._index(0)[frame]
        shard = Path(chunks._shard_path(0))
    data = bytearray(shard.read_bytes())
    data[int(offset) + int(size) // 2] ^= 0xFF
    shard.write_bytes(bytes(data))


@pytest.mark.parametrize("array", ["tactile/left/marked_rgb", "tactile/left/depth_um"])
def test_a_damaged_chunk_raises_one_line_naming_the_episode(tmp_path, array):
    root = make_dataset(tmp_path / "z", "zarr", 1, n_frames=3)
    flip_chunk_byte(root, array, 1)
    ds = TactileFrameDataset(root, compact=True, pads="left")
    for read in (lambda: ds[1], lambda: ds.read_batch([0, 1, 2]), lambda: list(FrameBatchLoader(ds, 3, threads=2))):
        with pytest.raises(CorruptFileError) as error:
            read()
        message = str(error.value)
        assert "\n" not in message and "ep0.zarr" in message
    ds[0], ds[2]   # the undamaged frames still read


def test_crc32c_matches_zarrs_checksum_and_rejects_a_flipped_byte():
    import google_crc32c

    payload = bytes(range(256)) * 40
    stored = payload + google_crc32c.value(payload).to_bytes(4, "little")
    assert crc32c_matches(stored)
    for position in (0, 100, len(stored) - 1):
        damaged = bytearray(stored)
        damaged[position] ^= 0x01
        assert not crc32c_matches(bytes(damaged))


def test_later_epochs_open_no_zarr_episode(tmp_path, monkeypatch):
    """Each FrameBatchLoader epoch starts new readers; what they need of a Zarr episode (chunks, shard indexes,
    small arrays) is kept by the dataset's reader (``zarr_episodes``, shared with the threads' readers), so only the
    first epoch opens episodes."""
    root = make_dataset(tmp_path / "z", "zarr", 3, n_frames=4)
    opens: list[str] = []
    original = ZarrHandle.__init__

    def counting(self: ZarrHandle, loc: object, relpath: str) -> None:
        opens.append(relpath)
        original(self, loc, relpath)

    monkeypatch.setattr(ZarrHandle, "__init__", counting)
    loader = FrameBatchLoader(TactileFrameDataset(root, compact=True, channels_last=True), 5, threads=2,
                              shuffle=False)
    first = list(loader)
    assert opens
    opens.clear()
    again = list(loader)
    assert opens == []
    assert len(first) == len(again) == 5
    for x, y in zip(first, again):
        assert_same(x, y, channels_last=True)
