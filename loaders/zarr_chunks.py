"""Reading one frame of a Zarr image or depth array straight from its shard, into a given buffer.

Why: ``zarr.Array.__getitem__`` costs about 2 ms a frame beyond the decode itself (its asyncio event loop,
codec pipeline and buffer prototypes, per read), so the Zarr loader ran at a tenth of the HDF5 one, whose
frames are read by ``chunks.FrameChunks``. The format's image, depth and mask arrays are laid out the same
way in both backends: one frame per chunk, Blosc then a 4-byte checksum. In Zarr the chunks of
``SHARD_FRAMES`` frames sit in one shard object (``c/<s>/0/0[/0]`` under the array), located by the shard's
index at its end: ``(offset, nbytes)`` as little-endian uint64 per chunk, then the index's CRC-32C. So a
frame is: the shard's index (read once per shard and kept), a ranged read of the chunk (``os.pread`` on a
local file, ``fs.cat_file(path, start, end)`` for any fsspec file system), its CRC-32C checked, and Blosc
decoding into the caller's buffer, the same ``FrameSource`` machinery as HDF5 (residuals included).

What Zarr would check is still checked (the chunk's and the index's CRC-32C, the Blosc header's sizes);
anything else (another codec pipeline, a chunk never written, a bad checksum, a read error) makes
``read_frame_into`` return ``False`` and the caller reads through zarr, which decodes the frame or raises
the format's one-line ``CorruptFileError``.
"""

from __future__ import annotations

import os
import threading
from dataclasses import dataclass
from typing import Any

import google_crc32c
import numpy as np
from numcodecs import blosc

from univtac_data.loaders.chunks import BLOSC_HEADER_BYTES, blosc_sizes

EMPTY = np.uint64(2**64 - 1)   # offset and size of a chunk never written


def crc32c_matches(data: bytes) -> bool:
    """Whether the last 4 bytes of ``data`` are the little-endian CRC-32C of the rest (zarr's ``crc32c``).
    (google_crc32c takes bytes only; slicing copies, about 3.5 us for 60 KiB.)"""
    return len(data) >= 4 and google_crc32c.value(data[:-4]) == int.from_bytes(data[-4:], "little")


@dataclass(frozen=True)
class ZarrFrameLayout:
    """A sharded Zarr v3 array whose frames this module decodes: inner chunks of one frame, codecs exactly
    bytes -> Blosc -> CRC-32C, the shard index at the end (bytes, CRC-32C). Immutable, no open file."""

    frame_shape: tuple[int, ...]   # shape of one frame, e.g. (240, 320, 3)
    dtype: np.dtype                # stored dtype
    frame_nbytes: int              # bytes of one decoded frame
    n_frames: int
    shard_frames: int              # frames per shard (the outer chunk's length along T)
    shard_keys: tuple[str, ...]    # path of each shard under the array, by shard number
    fill_value: Any                # what zarr gives for a chunk never written (zarr skips chunks of fill values)
    residual_of: str | None = None  # as ``chunks.FrameLayout.residual_of``

    @classmethod
    def of(cls, array: Any, residual_of: str | None = None) -> ZarrFrameLayout | None:
        """The layout of the ``zarr.Array`` ``array``, or ``None`` when it is laid out any other way."""
        from zarr.codecs import BloscCodec, BytesCodec, Crc32cCodec, ShardingCodec
        from zarr.codecs.sharding import ShardingCodecIndexLocation

        try:
            meta = array.metadata
            codecs = tuple(meta.codecs)
            shape = tuple(int(s) for s in array.shape)
            shard = tuple(int(s) for s in meta.chunk_grid.chunk_shape)
        except Exception:
            return None
        if len(shape) < 2 or len(codecs) != 1 or not isinstance(codecs[0], ShardingCodec):
            return None
        sharding = codecs[0]
        inner = [type(c) for c in sharding.codecs]
        index = [type(c) for c in sharding.index_codecs]
        dtype = np.dtype(array.dtype)
        if (inner != [BytesCodec, BloscCodec, Crc32cCodec] or index != [BytesCodec, Crc32cCodec]
                or sharding.index_location != ShardingCodecIndexLocation.end
                or tuple(sharding.chunk_shape) != (1, *shape[1:]) or shard[1:] != shape[1:]
                or (dtype.itemsize > 1 and sharding.codecs[0].endian is not None
                    and sharding.codecs[0].endian.value != "little")):
            return None
        n_shards = -(-shape[0] // shard[0]) if shape[0] else 0
        keys = tuple(meta.encode_chunk_key((s,) + (0,) * (len(shape) - 1)) for s in range(n_shards))
        frame_shape = shape[1:]
        try:
            fill = np.asarray(meta.fill_value, dtype).item()
        except Exception:
            return None
        return cls(frame_shape, dtype, int(np.prod(frame_shape)) * dtype.itemsize, shape[0], shard[0], keys, fill,
                   residual_of)


class ZarrFrameChunks:
    """The frames of a ``ZarrFrameLayout`` under ``array_path`` on the fsspec file system ``fs`` (a local
    one is read with ``os.pread``). Keeps each shard's index once read; safe to share between threads."""

    def __init__(self, layout: ZarrFrameLayout, fs: Any, array_path: str, local: bool) -> None:
        self.layout, self.fs, self.array_path, self.local = layout, fs, array_path, local
        # the version of the array's metadata the layout was read from (local files only): a reader that keeps
        # these chunks compares it with the file once per batch (``metadata_identity``)
        self.identity = metadata_identity(array_path) if local else None
        self._indexes: dict[int, np.ndarray | None] = {}
        self._lock = threading.Lock()

    @property
    def frame_shape(self) -> tuple[int, ...]:
        return self.layout.frame_shape

    @property
    def frame_nbytes(self) -> int:
        return self.layout.frame_nbytes

    def _shard_path(self, shard: int) -> str:
        return f"{self.array_path}/{self.layout.shard_keys[shard]}"

    def _read(self, path: str, start: int, size: int) -> bytes | None:
        """``size`` bytes of ``path`` from ``start`` (negative: from the end), or ``None``."""
        try:
            if self.local:
                fd = os.open(path, os.O_RDONLY)
                try:
                    if start < 0:
                        start += os.fstat(fd).st_size
                    data = os.pread(fd, size, start)
                finally:
                    os.close(fd)
            else:
                data = self.fs.cat_file(path, start=start, end=None if start < 0 else start + size)
        except (OSError, ValueError):
            return None
        return bytes(data) if len(data) == size else None

    def _index(self, shard: int) -> np.ndarray | None:
        """The shard's (shard_frames, 2) uint64 (offset, nbytes), or ``None`` when it cannot be used."""
        if shard in self._indexes:
            return self._indexes[shard]
        n = self.layout.shard_frames
        raw = self._read(self._shard_path(shard), -(16 * n + 4), 16 * n + 4)
        index = None
        if raw is not None and crc32c_matches(raw):
            index = np.frombuffer(raw[:-4], "<u8").reshape(n, 2)
        with self._lock:
            self._indexes[shard] = index
        return index

    def stored_chunk(self, frame: int) -> bytes | None:
        """Frame ``frame``'s chunk as stored (Blosc stream, then CRC-32C); ``b""`` for a chunk never written
        (its frame is the fill value); ``None`` when it cannot be read here."""
        if not 0 <= frame < self.layout.n_frames:
            return None
        shard, k = divmod(frame, self.layout.shard_frames)
        index = self._index(shard)
        if index is None:
            return None
        offset, size = index[k]
        if offset == EMPTY:
            return b"" if size == EMPTY else None
        return self._read(self._shard_path(shard), int(offset), int(size))

    def read_frame_into(self, frame: int, out: np.ndarray) -> bool:
        """Decode frame ``frame`` into ``out`` (C-contiguous, ``frame_nbytes`` bytes); ``False`` when the caller
        must read it through zarr instead (see the module's docstring)."""
        if out.nbytes != self.frame_nbytes or not out.flags.c_contiguous:
            return False
        chunk = self.stored_chunk(frame)
        if chunk == b"":
            out.view(self.layout.dtype)[...] = self.layout.fill_value
            return True
        if chunk is None or len(chunk) < BLOSC_HEADER_BYTES + 4 or not crc32c_matches(chunk):
            return False
        payload = memoryview(chunk)[:-4]
        if blosc_sizes(payload) != (out.nbytes, len(payload)):
            return False
        try:
            blosc.decompress(payload, out.reshape(-1).view(np.uint8))
        except Exception:  # a damaged Blosc stream
            return False
        return True


def metadata_identity(array_path: str) -> tuple[int, int, int, int] | None:
    """Device, inode, size and modification time of a local array's ``zarr.json``, or ``None``."""
    try:
        stat = os.stat(os.path.join(array_path, "zarr.json"))
    except OSError:
        return None
    return stat.st_dev, stat.st_ino, stat.st_size, stat.st_mtime_ns


def zarr_frame_chunks(handle: Any, path: str, residual_of: str | None) -> ZarrFrameChunks | None:
    """``ZarrFrameChunks`` for array ``path`` of the open ``ZarrHandle``, or ``None`` when its layout is not one
    this module decodes (or the array cannot be opened: the handle's read then reports it)."""
    try:
        array = handle.zarr_array(path)
    except Exception:
        return None
    layout = ZarrFrameLayout.of(array, residual_of)
    if layout is None:
        return None
    loc = handle.loc
    return ZarrFrameChunks(layout, loc.fs, loc.join(handle.relpath, path), loc.is_local)


class ZarrEpisodeCache:
    """What reading Zarr episodes needs once they have been opened, kept across readers (an ``EpisodeReader``
    and its ``sibling`` readers share one, as they share the HDF5 ``LayoutCache``): each
    array's ``ZarrFrameChunks`` (its layout and the shard indexes read so far; thread-safe, so readers of all
    threads share them) and the small arrays read whole (markers, poses, ``pure_ref_rgb``). Without it every
    new reader (each ``FrameBatchLoader`` epoch starts one per thread) opens each episode through zarr again
    and reads its small arrays again: about 10 ms an episode.

    Keyed by the episode's URL and its index digest (``IndexRow.sha256``), so a rewritten episode is not read
    at its former places. Least recently used episodes are dropped past ``budget_bytes`` (default 512 MiB).
    Per process: a forked child or an unpickled copy starts empty.
    """

    def __init__(self, budget_bytes: int = 512 * 2**20) -> None:
        self.budget_bytes = budget_bytes
        self._reset()

    def _reset(self) -> None:
        from collections import OrderedDict

        self._lock = threading.Lock()
        self._episodes: OrderedDict[tuple[str, str], dict[str, Any]] = OrderedDict()
        self._sizes: dict[tuple[str, str], int] = {}
        self._nbytes = 0
        self._pid = os.getpid()

    def __getstate__(self) -> dict[str, Any]:
        return {"budget_bytes": self.budget_bytes}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.budget_bytes = state["budget_bytes"]
        self._reset()

    def get(self, key: tuple[str, str], path: str) -> Any:
        """The ``ZarrFrameChunks`` or whole array kept for ``path`` of episode ``key``, or ``None``."""
        if self._pid != os.getpid():
            self._reset()
        with self._lock:
            arrays = self._episodes.get(key)
            if arrays is None:
                return None
            self._episodes.move_to_end(key)
            return arrays.get(path)

    def put(self, key: tuple[str, str], path: str, value: Any) -> None:
        """Keep ``value`` (a ``ZarrFrameChunks`` or a whole array, made read-only) for ``path`` of ``key``."""
        if self._pid != os.getpid():
            self._reset()
        if isinstance(value, np.ndarray):
            value.flags.writeable = False
            size = value.nbytes + 200
        else:
            size = 200 + 16 * value.layout.n_frames   # a frame's index entry, once its shard is read
        with self._lock:
            arrays = self._episodes.setdefault(key, {})
            self._episodes.move_to_end(key)
            if path not in arrays:
                arrays[path] = value
                self._sizes[key] = self._sizes.get(key, 0) + size
                self._nbytes += size
            while self._nbytes > self.budget_bytes and self._episodes:
                dropped, _ = self._episodes.popitem(last=False)
                self._nbytes -= self._sizes.pop(dropped)

    def drop(self, key: tuple[str, str]) -> None:
        """Forget episode ``key`` (its metadata changed on disk)."""
        with self._lock:
            if self._episodes.pop(key, None) is not None:
                self._nbytes -= self._sizes.pop(key)

    def __len__(self) -> int:
        return len(self._episodes) if self._pid == os.getpid() else 0

