"""``BatchBuffers``: batch tensors whose memory is reused once nothing refers to them any more.

Why: a compact 320 x 240 batch of 32 is 20 MB, and memory the process has not touched yet costs a page
fault per 4 KiB when first written (about 0.1 ms a sample on a 2-core VM; the allocator often gives
fresh pages for blocks this large). Reusing a batch's memory is only safe once the training loop has
let go of every tensor made from it, so each buffer is a NumPy array handed out through
``torch.from_numpy``: every tensor and view made from it keeps one storage alive, and that storage
holds a reference to the array, so the array's reference count says exactly whether any of them is
alive. A tensor moved to shared memory (``share_memory_``, or sent to another process) gets its own
copy and lets go of the array.

Used by ``FrameBatchLoader`` (one pool per thread); not for DataLoader worker processes, whose batches
must be in fresh shared memory.
"""

from __future__ import annotations

import sys

import numpy as np
import torch

MAX_BUFFERS = 8  # per shape and dtype: batches in flight plus the few the training loop holds


class BatchBuffers:
    """Tensors of given shapes and dtypes, each on a NumPy buffer reused when no tensor refers to it."""

    def __init__(self, max_buffers: int = MAX_BUFFERS) -> None:
        self.max_buffers = max_buffers
        self._free: dict[tuple[tuple[int, ...], np.dtype], list[np.ndarray]] = {}

    def empty(self, shape: tuple[int, ...], dtype: torch.dtype) -> torch.Tensor:
        """An uninitialised tensor of ``shape`` and ``dtype`` on a buffer nothing else uses."""
        np_dtype = torch.empty((), dtype=dtype).numpy().dtype
        pool = self._free.setdefault((tuple(shape), np_dtype), [])
        for array in pool:
            # references: the pool's list, this loop's variable, getrefcount's argument; more means a
            # tensor made from the array (or a view of one) is still alive
            if sys.getrefcount(array) <= 3:
                return torch.from_numpy(array)
        array = np.empty(shape, np_dtype)
        if len(pool) < self.max_buffers:
            pool.append(array)
        return torch.from_numpy(array)
