"""Reading one frame of an HDF5 image or depth array straight from its stored chunk, into a given buffer.

Why: a frame of a 320 x 240 sensor decodes in about 0.55 ms (Blosc-zstd, both images and depth), but
h5py's ``dataset[t]`` adds about 0.1 ms of selection and type handling per array, allocates a new array
for every read, and the loader then copies it once more into the batch. Here the chunk's bytes are read
from the file at the place HDF5's chunk index gives (listed once per array with ``chunk_iter``, read with
``os.pread``: 7 us a chunk, and without the GIL, where h5py's ``read_direct_chunk`` takes 23 us holding it;
``read_direct_chunk`` remains for files HDF5 does not open as plain local files), and Blosc decodes them
into the caller's buffer (a slot of the batch tensor, or a scratch frame reused for every read).

What HDF5 would check is still checked: the chunk's Fletcher-32 checksum (HDF5's ``H5_checksum_fletcher32``,
through numcodecs' C port of it: about 9 us for a 23 KiB chunk, half of what the NumPy closed form took) and
the Blosc header's sizes. Anything this module does not handle itself
(another filter pipeline, a chunk HDF5 stored unfiltered, a bad checksum, a Blosc error) makes
``read_frame_into`` return ``False``; the caller then reads the frame through h5py, which decodes it or
raises the format's one-line ``CorruptFileError`` naming the file, exactly as before.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import h5py
import numpy as np
from numcodecs import blosc
from numcodecs.fletcher32 import Fletcher32

BLOSC_FILTER_ID = 32001          # the registered HDF5 filter id of Blosc (hdf5plugin)
FLETCHER32_FILTER_ID = 3         # H5Z_FILTER_FLETCHER32
BLOSC_HEADER_BYTES = 16          # Blosc 1 header: version, versionlz, flags, typesize, nbytes, blocksize, cbytes
_FLETCHER32 = Fletcher32()       # stateless: safe to share between threads

ChunkPlace = tuple[int, int, int]   # (byte offset in the file, stored bytes, HDF5 filter mask)


def fletcher32(data: bytes | memoryview | np.ndarray) -> int:
    """HDF5's Fletcher-32 of ``data`` (``H5_checksum_fletcher32``): big-endian 16-bit words, an odd last byte
    as the high byte of a final word, both sums kept in [1, 65535] (0 only when every word is 0).

    numcodecs' ``Fletcher32`` codec is a C port of HDF5's function; its encoding appends the checksum
    little-endian, as HDF5 stores it after a chunk.
    """
    return int.from_bytes(_FLETCHER32.encode(data)[-4:], "little")


def checksum_matches(chunk: bytes) -> bool:
    """Whether the last 4 bytes of ``chunk`` are HDF5's Fletcher-32 of the rest (little-endian, as HDF5 writes
    it). Checks without copying the chunk (``fletcher32`` copies it once)."""
    try:
        _FLETCHER32.decode(chunk)
    except (RuntimeError, ValueError):   # a mismatch (RuntimeError; older numcodecs documented ValueError)
        return False
    return True


def blosc_sizes(stream: memoryview) -> tuple[int, int]:
    """``(decoded bytes, stream bytes)`` from a Blosc 1 header (little-endian uint32 at bytes 4 and 12)."""
    header = bytes(stream[:BLOSC_HEADER_BYTES])
    return int.from_bytes(header[4:8], "little"), int.from_bytes(header[12:16], "little")


def chunk_places(dataset: h5py.Dataset) -> dict[int, ChunkPlace] | None:
    """Where each written frame's chunk is stored in the file (frame -> place), from one pass over HDF5's
    chunk index; ``None`` when the file is not a plain local file (another HDF5 driver) or this HDF5
    build cannot list chunks (``chunk_iter`` needs a recent HDF5; h5py's wheels have one)."""
    if dataset.file.driver != "sec2":
        return None
    places: dict[int, ChunkPlace] = {}

    def note(info: h5py.h5d.StoreInfo) -> None:
        places[int(info.chunk_offset[0])] = (int(info.byte_offset), int(info.size), int(info.filter_mask))

    try:
        dataset.id.chunk_iter(note)
    except Exception:  # an older HDF5 or h5py, or an unreadable chunk index: read_direct_chunk decides
        return None
    return places


@dataclass(frozen=True)
class FrameChunks:
    """An HDF5 array whose frames this module can decode: chunked one frame per chunk, filters exactly
    Blosc then Fletcher-32 (the format's encoding for images and depth)."""

    dataset: h5py.Dataset
    frame_shape: tuple[int, ...]   # shape of one frame, e.g. (240, 320, 3)
    frame_nbytes: int              # bytes of one decoded frame
    n_frames: int                  # frames in the array (h5py's ``shape`` costs microseconds per call)
    places: dict[int, ChunkPlace] | None   # frame -> where its chunk is stored; None: use read_direct_chunk
    file_descriptor: int           # the open file's descriptor, for os.pread at those places (-1 without)

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
        places = chunk_places(dataset)
        descriptor = -1 if places is None else int(dataset.file.id.get_vfd_handle())
        return cls(dataset, frame_shape, int(np.prod(frame_shape)) * dataset.dtype.itemsize, int(dataset.shape[0]),
                   places, descriptor)

    def stored_chunk(self, frame: int) -> bytes | None:
        """Frame ``frame``'s chunk as stored (Blosc stream, then the checksum), or ``None`` when it was never
        written, HDF5 skipped a filter for it, or it cannot be read. Valid while the file is open."""
        if self.places is None:
            try:
                filter_mask, chunk = self.dataset.id.read_direct_chunk((frame, *(0,) * len(self.frame_shape)))
            except Exception:  # an unreadable chunk index: let h5py report it
                return None
            return chunk if filter_mask == 0 else None
        place = self.places.get(frame)
        if place is None:
            return None   # never written: h5py gives the fill value
        offset, size, filter_mask = place
        try:
            chunk = os.pread(self.file_descriptor, size, offset)
        except OSError:
            return None
        return chunk if filter_mask == 0 and len(chunk) == size else None

    def read_frame_into(self, frame: int, out: np.ndarray) -> bool:
        """Decode frame ``frame`` into ``out`` (C-contiguous, ``frame_nbytes`` bytes, any dtype of that size).

        Returns ``False``, with ``out`` in an unspecified state, when the chunk is not one this module
        decodes or fails a check; the caller then reads through h5py (which raises for damaged data).
        """
        if not 0 <= frame < self.n_frames or out.nbytes != self.frame_nbytes or not out.flags.c_contiguous:
            return False
        chunk = self.stored_chunk(frame)
        if chunk is None or len(chunk) < BLOSC_HEADER_BYTES + 4:
            return False   # h5py reads it, or raises; too short for a Blosc header and a checksum
        if not checksum_matches(chunk):
            return False   # h5py repeats the check (and accepts HDF5's legacy byte order) or raises
        payload = memoryview(chunk)[:-4]
        if blosc_sizes(payload) != (self.frame_nbytes, len(payload)):
            return False
        try:
            # numcodecs decodes single-threaded in forked workers and in non-main threads (no global lock)
            blosc.decompress(payload, out.reshape(-1).view(np.uint8))
        except Exception:  # a damaged Blosc stream or a codec this build lacks
            return False
        return True
