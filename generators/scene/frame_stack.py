"""A growable per-frame array, filled as frames are recorded, and the pool of episode buffers it draws from."""

from __future__ import annotations

import sys
import threading
from dataclasses import fields

import numpy as np

from univtac_data.generators.tactile import PixelBuffers

#: The per-pixel arrays of a tactile frame that an episode records, by their name under ``tactile/{pad}/``:
#: those ``simulate_frame`` writes into its ``PixelBuffers``.
PIXEL_FIELDS = tuple(f.name for f in fields(PixelBuffers))


# CPython with the GIL counts references exactly; a free-threaded build defers some counts
_EXACT_REFCOUNTS = getattr(sys, "_is_gil_enabled", lambda: True)()


class BufferPool:
    """Episode-sized frame buffers kept for the next episode that records frames of the same shape.

    A frame written into memory fresh from the system pays a page fault for every page it touches: on Lift Can
    recordings (2-core machine, under load) that cost 0.4 ms a frame without cameras and 3 to 5 ms with two
    480 x 270 cameras. A generator records episode after episode, so a buffer is handed out again once nothing
    refers to it any more: no episode, array or view of it is alive (its reference count is the pool's own),
    so a reused buffer can never overwrite frames someone still holds. On a free-threaded Python, whose
    reference counts are not exact, nothing is kept. At most ``max_per_shape`` buffers of one shape and ``max_bytes`` in
    all are kept (free buffers of the shapes asked for longest ago are let go to make room: a process that
    records one task after another keeps about one episode's buffers); ``clear()`` gives the memory back (a
    long-lived process that is done generating).
    """

    def __init__(self, max_per_shape: int = 8, max_bytes: int = 3 << 30) -> None:
        self.max_per_shape = max_per_shape
        self.max_bytes = max_bytes
        # insertion order is the order shapes were last asked for: free buffers of the stalest go first
        self._buffers: dict[tuple[tuple[int, ...], str], list[np.ndarray]] = {}
        self._bytes = 0
        self._lock = threading.Lock()

    def take(self, shape: tuple[int, ...], dtype: np.dtype | type) -> np.ndarray:
        """An uninitialised array of ``shape`` and ``dtype``: a kept one that nothing refers to, else a new one,
        kept if the limits allow once free buffers of other shapes are let go."""
        if not _EXACT_REFCOUNTS:
            return np.empty(shape, dtype)
        key = (tuple(shape), np.dtype(dtype).str)
        with self._lock:
            kept = self._buffers.pop(key, [])
            self._buffers[key] = kept
            for i in range(len(kept)):
                if self._free(kept, i):
                    return kept[i]
            buffer = np.empty(shape, dtype)
            if len(kept) < self.max_per_shape:
                self._let_go(buffer.nbytes, key)
                if self._bytes + buffer.nbytes <= self.max_bytes:
                    kept.append(buffer)
                    self._bytes += buffer.nbytes
            return buffer

    @staticmethod
    def _free(kept: list[np.ndarray], i: int) -> bool:
        # two references: the list's and getrefcount's argument; any view or holder adds one
        return sys.getrefcount(kept[i]) == 2

    def _let_go(self, nbytes: int, keep: tuple[tuple[int, ...], str]) -> None:
        """Forget free buffers of shapes other than ``keep``, stalest first, until ``nbytes`` more fit."""
        for key, kept in list(self._buffers.items()):
            if self._bytes + nbytes <= self.max_bytes:
                return
            if key == keep:
                continue
            for i in reversed(range(len(kept))):
                if self._free(kept, i):
                    self._bytes -= kept.pop(i).nbytes
            if not kept:
                del self._buffers[key]

    @property
    def kept_bytes(self) -> int:
        """Bytes of the buffers the pool keeps (in use or free)."""
        return self._bytes

    def clear(self) -> None:
        """Forget every kept buffer (those still in use live on with their users)."""
        with self._lock:
            self._buffers.clear()
            self._bytes = 0


#: The pool recorded episodes draw their frame buffers from.
FRAME_BUFFERS = BufferPool()


class FrameStack:
    """A (T, ...) array filled one frame at a time: the episode's array, without holding every frame's own
    array until the end and stacking them (for a 480 x 480 sensor that copy, and the page faults of memory
    that is never reused while the frames stay alive, took a sixth of a generated frame).

    A frame is either appended (copied in) or written in place: ``next_row`` gives the row the next frame
    goes to and ``commit`` counts it, which saves the copy of a frame the producer can write straight into.

    ``capacity``: frames to allocate for at first (the episode's frame budget when known; that buffer comes
    from ``FRAME_BUFFERS``); doubles when full.
    """

    def __init__(self, capacity: int = 64) -> None:
        self._capacity = max(1, capacity)
        self._buffer: np.ndarray | None = None
        self._row_given = False
        self.frames = 0

    def next_row(self, shape: tuple[int, ...], dtype: np.dtype | type) -> np.ndarray:
        """The (uninitialised) row of frame ``frames``, of ``shape`` and ``dtype``; ``commit()`` once it is
        filled. A row from before the buffer grew stays valid, but is no longer the stack's."""
        if self._buffer is None:
            self._buffer = FRAME_BUFFERS.take((self._capacity, *shape), dtype)
        elif self._buffer.shape[1:] != tuple(shape) or self._buffer.dtype != np.dtype(dtype):
            raise ValueError(f"frame of shape {tuple(shape)} {np.dtype(dtype)} in a stack of "
                             f"{self._buffer.shape[1:]} {self._buffer.dtype}")
        elif self.frames == self._buffer.shape[0]:
            grown = np.empty((2 * self._buffer.shape[0], *self._buffer.shape[1:]), self._buffer.dtype)
            grown[: self.frames] = self._buffer
            self._buffer = grown
        self._row_given = True
        return self._buffer[self.frames]

    def commit(self) -> None:
        """Count the row ``next_row`` gave as recorded."""
        if not self._row_given:
            raise ValueError("commit without a row from next_row")
        self._row_given = False
        self.frames += 1

    def clear(self) -> None:
        """Forget the frames but keep the memory: the next frame goes to row 0."""
        self._row_given = False
        self.frames = 0

    def append(self, frame: np.ndarray) -> None:
        self.next_row(frame.shape, frame.dtype)[...] = frame
        self.commit()

    def array(self) -> np.ndarray:
        """The frames so far, (T, ...); a view, valid until the next ``append``."""
        if self._buffer is None:
            raise ValueError("no frame recorded")
        return self._buffer[: self.frames]
