"""Reading one frame of an HDF5 image or depth array straight from its stored chunk, into a given buffer.

Why: a frame of a 320 x 240 sensor decodes in about 0.55 ms (Blosc-zstd, both images and depth), but
h5py's ``dataset[t]`` adds about 0.1 ms of selection and type handling per array, allocates a new array
for every read, and the loader then copies it once more into the batch. Here the chunk's bytes are read
from the file at the place HDF5's chunk index gives (listed once per array with ``chunk_iter``, read with
``os.pread``: 7 us a chunk, and without the GIL, where h5py's ``read_direct_chunk`` takes 23 us holding it;
``read_direct_chunk`` remains for files HDF5 does not open as plain local files), and Blosc decodes them
into the caller's buffer (a slot of the batch tensor, or a scratch frame reused for every read).

What decoding needs besides the file's bytes (``FrameLayout``: frame shape, dtype and the chunks' places)
is kept apart from any open file, so that a reader can keep it after closing the episode and read the
next frame with a plain descriptor and ``os.pread`` instead of reopening the file with h5py (about 2 ms
an episode; ``loaders/layouts.py``).

Residual arrays (format 2.0: ``residual_of``, see ``EpisodeHandle.residual_base``) are decoded the same
way, into the same buffer, and their base is then added in place (``FrameSource``): a per-frame base
(``marked_rgb`` over ``pure_rgb``) decoded into a per-thread scratch frame, a per-episode one
(``pure_rgb`` over ``pure_ref_rgb``) from memory: one uint8 addition (about 5 us a 320 x 240 frame), plus,
for ``marked_rgb``, decoding ``pure_rgb``'s chunk once more.

What HDF5 would check is still checked: the chunk's Fletcher-32 checksum (HDF5's ``H5_checksum_fletcher32``,
through numcodecs' C port of it: about 9 us for a 23 KiB chunk, half of what the NumPy closed form took) and
the Blosc header's sizes. Anything this module does not handle itself
(another filter pipeline, a chunk HDF5 stored unfiltered, a bad checksum, a Blosc error) makes
``read_frame_into`` return ``False``; the caller then reads the frame through h5py, which decodes it or
raises the format's one-line ``CorruptFileError`` naming the file, exactly as before.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Union

import h5py
import numpy as np
from numcodecs import blosc
from numcodecs.fletcher32 import Fletcher32

BLOSC_FILTER_ID = 32001          # the registered HDF5 filter id of Blosc (hdf5plugin)
FLETCHER32_FILTER_ID = 3         # H5Z_FILTER_FLETCHER32
BLOSC_HEADER_BYTES = 16          # Blosc 1 header: version, versionlz, flags, typesize, nbytes, blocksize, cbytes
_FLETCHER32 = Fletcher32()       # stateless: safe to share between threads
_SCRATCH = threading.local()     # per thread: frames of residual bases (``scratch_frame``)


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



@dataclass(frozen=True)
class ChunkPlaces:
    """Where each frame's chunk of one array is stored in its file, as two arrays of 8 bytes a frame: a
    cache of the places of thousands of episodes stays small (a dict of tuples takes about 200 bytes a
    frame). Read-only, so one instance may be shared by the threads of a process."""

    offsets: np.ndarray   # (T,) int64: byte offset of frame t's chunk in the file; -1: none to read here
                          # (never written, so h5py gives the fill value; or HDF5 skipped a filter for it)
    sizes: np.ndarray     # (T,) int64: stored bytes of that chunk (the Blosc stream, then the checksum)

    @classmethod
    def of(cls, dataset: h5py.Dataset) -> ChunkPlaces | None:
        """The places of ``dataset``'s frames, from one pass over HDF5's chunk index; ``None`` when the file
        is not a plain local file (another HDF5 driver) or this HDF5 build cannot list chunks
        (``chunk_iter`` needs a recent HDF5; h5py's wheels have one)."""
        if dataset.file.driver != "sec2":
            return None
        n_frames = int(dataset.shape[0])
        offsets, sizes = np.full(n_frames, -1, np.int64), np.zeros(n_frames, np.int64)

        def note(info: h5py.h5d.StoreInfo) -> None:
            frame = int(info.chunk_offset[0])
            if info.filter_mask == 0 and 0 <= frame < n_frames:
                offsets[frame], sizes[frame] = int(info.byte_offset), int(info.size)

        try:
            dataset.id.chunk_iter(note)
        except Exception:  # an older HDF5 or h5py, or an unreadable chunk index: read_direct_chunk decides
            return None
        offsets.flags.writeable = sizes.flags.writeable = False
        return cls(offsets, sizes)

    def get(self, frame: int) -> tuple[int, int] | None:
        """``(offset, stored bytes)`` of frame ``frame``'s chunk (0 <= frame < T), or ``None``."""
        offset = int(self.offsets[frame])
        return None if offset < 0 else (offset, int(self.sizes[frame]))

    @property
    def nbytes(self) -> int:
        return int(self.offsets.nbytes + self.sizes.nbytes)


@dataclass(frozen=True)
class FrameLayout:
    """An HDF5 array whose frames this module decodes (chunked one frame per chunk, filters exactly Blosc then
    Fletcher-32: the format's encoding for images, depth and masks), described without any open file: what
    decoding frame t needs besides the file's bytes. Immutable; ``loaders.layouts`` keeps it after the
    file is closed."""

    frame_shape: tuple[int, ...]   # shape of one frame, e.g. (240, 320, 3) for an image
    dtype: np.dtype                # stored dtype, e.g. uint8 for images and masks, uint16 for depth_um
    frame_nbytes: int              # bytes of one decoded frame
    n_frames: int                  # frames in the array (h5py's ``shape`` costs microseconds per call)
    places: ChunkPlaces | None     # None: HDF5 cannot list the chunks; read them with read_direct_chunk
    residual_of: str | None = None  # the array whose values are added to the decoded ones (validated by
                                    # ``EpisodeHandle.residual_base``); chunks hold ``(value - base) mod 2^bits``

    @classmethod
    def of(cls, dataset: h5py.Dataset, residual_of: str | None = None) -> FrameLayout | None:
        """The layout of ``dataset``, or ``None`` when its chunks or filters are anything else. ``residual_of``:
        its validated residual base (``EpisodeHandle.residual_base``), kept with the places so that a reader
        of the cached layout needs no h5py handle to know it."""
        if dataset.chunks is None or dataset.ndim < 2 or dataset.chunks != (1, *dataset.shape[1:]):
            return None
        plist = dataset.id.get_create_plist()
        filters = [plist.get_filter(k)[0] for k in range(plist.get_nfilters())]
        if filters != [BLOSC_FILTER_ID, FLETCHER32_FILTER_ID]:
            return None
        frame_shape = tuple(int(s) for s in dataset.shape[1:])
        return cls(frame_shape, np.dtype(dataset.dtype), int(np.prod(frame_shape)) * dataset.dtype.itemsize,
                   int(dataset.shape[0]), ChunkPlaces.of(dataset), residual_of)


@dataclass(frozen=True)
class FrameChunks:
    """The frames of a ``FrameLayout``, read from an open file: with ``os.pread`` on ``file_descriptor`` at
    the layout's places, or, without places or descriptor, through h5py's ``read_direct_chunk``."""

    layout: FrameLayout
    file_descriptor: int = -1              # open descriptor of the layout's file (-1: read through ``dataset``)
    dataset: h5py.Dataset | None = None    # the open h5py array, when there is one

    @classmethod
    def of(cls, dataset: h5py.Dataset, residual_of: str | None = None) -> FrameChunks | None:
        """``FrameChunks`` reading through h5py's open file, or ``None`` when ``FrameLayout.of`` is ``None``.
        They give the stored values: a residual's base is added by its ``FrameSource``."""
        layout = FrameLayout.of(dataset, residual_of)
        if layout is None:
            return None
        descriptor = -1 if layout.places is None else int(dataset.file.id.get_vfd_handle())
        return cls(layout, descriptor, dataset)

    @property
    def frame_shape(self) -> tuple[int, ...]:
        return self.layout.frame_shape

    @property
    def frame_nbytes(self) -> int:
        return self.layout.frame_nbytes

    def stored_chunk(self, frame: int) -> bytes | None:
        """Frame ``frame``'s chunk as stored (Blosc stream, then the checksum), or ``None`` when it was never
        written, HDF5 skipped a filter for it, or it cannot be read. Valid while the file is open."""
        if not 0 <= frame < self.layout.n_frames:
            return None
        places = self.layout.places
        if places is None or self.file_descriptor < 0:
            if self.dataset is None:
                return None
            try:
                filter_mask, chunk = self.dataset.id.read_direct_chunk((frame, *(0,) * len(self.frame_shape)))
            except Exception:  # an unreadable chunk index: let h5py report it
                return None
            return chunk if filter_mask == 0 else None
        place = places.get(frame)
        if place is None:
            return None   # never written (h5py gives the fill value), or a filter skipped
        offset, size = place
        try:
            chunk = os.pread(self.file_descriptor, size, offset)
        except OSError:
            return None
        return chunk if len(chunk) == size else None

    def read_frame_into(self, frame: int, out: np.ndarray) -> bool:
        """Decode frame ``frame`` into ``out`` (C-contiguous, ``frame_nbytes`` bytes, any dtype of that size).

        Returns ``False``, with ``out`` in an unspecified state, when the chunk is not one this module
        decodes or fails a check; the caller then reads through h5py (which raises for damaged data).
        """
        if out.nbytes != self.frame_nbytes or not out.flags.c_contiguous:
            return False
        chunk = self.stored_chunk(frame)
        return chunk is not None and decode_chunk_into(chunk, out)


def decode_chunk_into(chunk: bytes, out: np.ndarray) -> bool:
    """Check a stored chunk (Blosc stream, then HDF5's Fletcher-32) and decode it into ``out`` (C-contiguous,
    exactly the decoded size). ``False``, with ``out`` in an unspecified state, for anything unexpected."""
    if len(chunk) < BLOSC_HEADER_BYTES + 4:
        return False   # too short for a Blosc header and a checksum
    if not checksum_matches(chunk):
        return False   # h5py repeats the check (and accepts HDF5's legacy byte order) or raises
    payload = memoryview(chunk)[:-4]
    if blosc_sizes(payload) != (out.nbytes, len(payload)):
        return False
    try:
        # numcodecs decodes single-threaded in forked workers and in non-main threads (no global lock)
        blosc.decompress(payload, out.reshape(-1).view(np.uint8))
    except Exception:  # a damaged Blosc stream or a codec this build lacks
        return False
    return True


def scratch_frame(shape: tuple[int, ...], dtype: np.dtype, level: int) -> np.ndarray:
    """A frame buffer of this thread, one per ``(shape, dtype, level)``: where a residual's per-frame base is
    decoded before it is added, reused for every frame rather than allocated per read (and not one per
    source: a reader keeps dozens of sources, at 225 KiB a GelSight Mini frame). ``level``: the residual's
    depth in its chain, since a base of a base needs a buffer of its own while the first is in use. Per
    thread, because threads of a process decode at once."""
    frames: dict[tuple[tuple[int, ...], str, int], np.ndarray] = _SCRATCH.__dict__.setdefault("frames", {})
    key = (shape, dtype.str, level)
    buffer = frames.get(key)
    if buffer is None:
        buffer = frames[key] = np.empty(shape, dtype)
    return buffer


#: The values a residual's base adds to each decoded frame: a ``FrameSource`` (a per-frame base read frame by
#: frame), or an array kept whole (read-only): ``frame_shape`` for a per-episode base, ``(T, *frame_shape)``
#: for a per-frame one.
FrameBase = Union["FrameSource", np.ndarray]


class FrameSource:
    """One per-frame array of an episode (an image, depth map or mask), read one frame at a time into a buffer
    the caller owns, in its logical values: decoded straight from its chunk when ``chunks`` is given, plus
    ``base`` for a residual (``chunks.layout.residual_of``); otherwise, and for any chunk that fails a check
    there, by ``read_logical`` (the storage backend's read: it decodes the frame, adds any residual base,
    or raises ``CorruptFileError`` naming the file)."""

    __slots__ = ("base", "chunks", "dtype", "frame_shape", "read_logical")

    def __init__(self, frame_shape: tuple[int, ...], dtype: np.dtype, chunks: FrameChunks | None,
                 read_logical: Callable[[int], np.ndarray], base: FrameBase | None = None) -> None:
        if chunks is not None and (chunks.layout.residual_of is None) != (base is None):
            raise ValueError(f"a residual's chunks need its base and only a residual has one "
                             f"(residual_of={chunks.layout.residual_of!r}, base given: {base is not None})")
        self.frame_shape = frame_shape   # e.g. (240, 320, 3) for an image
        self.dtype = dtype               # stored dtype (uint8 for images and masks, uint16 for depth_um)
        self.chunks, self.read_logical, self.base = chunks, read_logical, base

    def read(self, frame: int) -> np.ndarray:
        """Frame ``frame`` as a new array of the stored dtype."""
        out = np.empty(self.frame_shape, self.dtype)
        self.read_into(frame, out)
        return out

    def read_into(self, frame: int, out: np.ndarray, level: int = 0, base_values: np.ndarray | None = None) -> None:
        """Frame ``frame`` into ``out``: C-contiguous, the stored frame shape, the stored dtype or one of its
        size (uint16 micrometres into an int16 buffer keeps the bits). ``level``: this array's depth in a
        chain of residuals (0 unless called for a base). ``base_values``: for a residual, its base's frame
        ``frame`` in logical values, when the caller has decoded it already (``self.base.read_into`` of the
        same frame): added instead of decoding the base again."""
        if self.chunks is None or not self.chunks.read_frame_into(frame, out):
            out[...] = self.read_logical(frame).view(out.dtype)   # residual bases added already
        elif self.base is not None:
            if base_values is None:
                self._add_base(frame, out.view(self.dtype), level)
            else:
                stored = out.view(self.dtype)
                np.add(stored, base_values, out=stored)

    def _add_base(self, frame: int, stored: np.ndarray, level: int) -> None:
        """Add the base's frame ``frame`` to the decoded residual ``stored``, in place: unsigned, so modulo
        2^bits, as the writer subtracted it."""
        base = self.base
        if isinstance(base, FrameSource):
            values = scratch_frame(self.frame_shape, self.dtype, level)
            base.read_into(frame, values, level + 1)
        elif base.ndim == len(self.frame_shape):
            values = base          # per episode: the same for every frame
        else:
            values = base[frame]   # per frame, kept whole
        np.add(stored, values, out=stored)
