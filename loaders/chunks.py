"""Reading one frame of an HDF5 image or depth array straight from its stored chunk, into a given buffer.

Why: a frame of a 320 x 240 sensor decodes in about 0.55 ms (Blosc-zstd, both images and depth), but
h5py's ``dataset[t]`` adds about 0.1 ms of selection and type handling per array, allocates a new array
for every read, and the loader then copies it once more into the batch. Here the chunk's bytes come from
``read_direct_chunk`` and Blosc decodes them into the caller's buffer (a slot of the batch tensor, or a
scratch frame reused for every read).

What HDF5 would check is still checked: the chunk's Fletcher-32 checksum (computed exactly as HDF5's
``H5_checksum_fletcher32``) and the Blosc header's sizes. Anything this module does not handle itself
(another filter pipeline, a chunk HDF5 stored unfiltered, a bad checksum, a Blosc error) makes
``read_frame_into`` return ``False``; the caller then reads the frame through h5py, which decodes it or
raises the format's one-line ``CorruptFileError`` naming the file, exactly as before.
"""

from __future__ import annotations

from dataclasses import dataclass

import h5py
import numpy as np
from numcodecs import blosc

BLOSC_FILTER_ID = 32001          # the registered HDF5 filter id of Blosc (hdf5plugin)
FLETCHER32_FILTER_ID = 3         # H5Z_FILTER_FLETCHER32
MAX_CHECKSUM_WORDS = 1 << 22     # int64 sums stay exact below this many 16-bit words (8 MiB chunks)
BLOSC_HEADER_BYTES = 16          # Blosc 1 header: version, versionlz, flags, typesize, nbytes, blocksize, cbytes


def fletcher32(data: bytes | memoryview | np.ndarray) -> int:
    """HDF5's Fletcher-32 of ``data`` (``H5_checksum_fletcher32``): big-endian 16-bit words, an odd last byte
    as the high byte of a final word, both sums kept in [1, 65535] (0 only when every word is 0).

    Closed form of HDF5's blocked loop: sum1 = sum of the words, sum2 = sum of word i times (n - i), each
    reduced mod 65535 with 0 written as 65535 unless the data are all zero.
    """
    raw = np.frombuffer(data, np.uint8)
    words = raw[: raw.size - raw.size % 2].view(">u2").astype(np.int64)
    if raw.size % 2:
        words = np.append(words, np.int64(raw[-1]) << 8)
    total = int(words.sum())
    if total == 0:
        return 0
    sum1 = (total - 1) % 65535 + 1
    sum2 = (int(words @ _descending(words.size)) - 1) % 65535 + 1
    return (sum2 << 16) | sum1


_DESCENDING = np.zeros(0, np.int64)


def _descending(n: int) -> np.ndarray:
    """(n, n - 1, ..., 1) int64: the tail of one cached descending range (no allocation per checksum)."""
    global _DESCENDING
    cached = _DESCENDING   # one read of the global: another thread may replace it meanwhile
    if cached.size < n:
        cached = _DESCENDING = np.arange(max(n, 2 * cached.size), 0, -1, dtype=np.int64)
    return cached[cached.size - n:]


def blosc_sizes(stream: memoryview) -> tuple[int, int]:
    """``(decoded bytes, stream bytes)`` from a Blosc 1 header (little-endian uint32 at bytes 4 and 12)."""
    header = bytes(stream[:BLOSC_HEADER_BYTES])
    return int.from_bytes(header[4:8], "little"), int.from_bytes(header[12:16], "little")


@dataclass(frozen=True)
class FrameChunks:
    """An HDF5 array whose frames this module can decode: chunked one frame per chunk, filters exactly
    Blosc then Fletcher-32 (the format's encoding for images and depth)."""

    dataset: h5py.Dataset
    frame_shape: tuple[int, ...]   # shape of one frame, e.g. (240, 320, 3)
    frame_nbytes: int              # bytes of one decoded frame

    @classmethod
    def of(cls, dataset: h5py.Dataset) -> FrameChunks | None:
        """``FrameChunks`` for ``dataset``, or ``None`` when its layout or filters are anything else."""
        if dataset.chunks is None or dataset.ndim < 2 or dataset.chunks != (1, *dataset.shape[1:]):
            return None
        plist = dataset.id.get_create_plist()
        filters = [plist.get_filter(k)[0] for k in range(plist.get_nfilters())]
        if filters != [BLOSC_FILTER_ID, FLETCHER32_FILTER_ID]:
            return None
        frame_shape = tuple(int(s) for s in dataset.shape[1:])
        return cls(dataset, frame_shape, int(np.prod(frame_shape)) * dataset.dtype.itemsize)

    def read_frame_into(self, frame: int, out: np.ndarray) -> bool:
        """Decode frame ``frame`` into ``out`` (C-contiguous, ``frame_nbytes`` bytes, any dtype of that size).

        Returns ``False``, with ``out`` in an unspecified state, when the chunk is not one this module
        decodes or fails a check; the caller then reads through h5py (which raises for damaged data).
        """
        if not 0 <= frame < self.dataset.shape[0] or out.nbytes != self.frame_nbytes or not out.flags.c_contiguous:
            return False
        offset = (frame,) + (0,) * len(self.frame_shape)
        try:
            filter_mask, chunk = self.dataset.id.read_direct_chunk(offset)
        except Exception:  # an unreadable chunk index: let h5py report it
            return False
        if filter_mask != 0 or len(chunk) < 20 or len(chunk) // 2 > MAX_CHECKSUM_WORDS:
            return False   # stored with a filter skipped, too short for a Blosc header, or too large to sum
        payload = memoryview(chunk)[:-4]
        if fletcher32(payload) != int.from_bytes(chunk[-4:], "little"):
            return False   # h5py repeats the check (and accepts HDF5's legacy byte order) or raises
        if blosc_sizes(payload) != (self.frame_nbytes, len(payload)):
            return False
        try:
            # numcodecs decodes single-threaded in forked workers and in non-main threads (no global lock)
            blosc.decompress(payload, out.reshape(-1).view(np.uint8))
        except Exception:  # a damaged Blosc stream or a codec this build lacks
            return False
        return True
