"""A growable per-frame array, filled as frames are recorded."""

from __future__ import annotations

from dataclasses import fields

import numpy as np

from univtac_data.generators.tactile import PixelBuffers

#: The per-pixel arrays of a tactile frame that an episode records, by their name under ``tactile/{pad}/``:
#: those ``simulate_frame`` writes into its ``PixelBuffers``.
PIXEL_FIELDS = tuple(f.name for f in fields(PixelBuffers))


class FrameStack:
    """A (T, ...) array filled one frame at a time: the episode's array, without holding every frame's own
    array until the end and stacking them (for a 480 x 480 sensor that copy, and the page faults of memory
    that is never reused while the frames stay alive, took a sixth of a generated frame).

    A frame is either appended (copied in) or written in place: ``next_row`` gives the row the next frame
    goes to and ``commit`` counts it, which saves the copy of a frame the producer can write straight into.

    ``capacity``: frames to allocate for at first (the episode's frame budget when known); doubles when full.
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
            self._buffer = np.empty((self._capacity, *shape), dtype)
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
