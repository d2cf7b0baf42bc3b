"""What reading an HDF5 episode needs once its file is known, kept after the file is closed.

Why: a shuffled batch of 32 from thousands of episodes spans about 32 of them, far more than a reader keeps
open, so without this nearly every sample reopens its episode with h5py (2 to 5 CPU-ms: the file's
metadata, the chunk index listed again for every image array, the small arrays read whole again), several
times the 0.8 ms its frames take to decode. What a frame read needs after the first touch of an episode is
small and immutable: each image or depth array's ``FrameLayout`` (frame shape, dtype, 16 bytes of chunk
place a frame, the array it is a residual of) and the small arrays read whole (marker tracks, object pose:
about 1 KiB a frame for both pads of a GelSight Mini; and each pad's ``pure_ref_rgb``, the base of the
format 2.0 ``pure_rgb`` residuals). ``EpisodeLayout`` holds those for one file; ``LayoutCache`` keeps them
for the process, least recently used dropped first past a byte budget. A reader then needs only a
descriptor and ``os.pread`` (``EpisodeReader``).

Large arrays kept whole are kept once per content (``POOL_MIN_BYTES``): ``pure_ref_rgb`` is 225 KiB a pad
(GelSight Mini; 675 KiB on a GF225), 1.8 GiB for 4,000 episode files if each kept its own, while the
generator renders the same background frame for every episode and pad of a sensor. Pooled arrays count
once in the budget, however many episodes share them.

A layout belongs to one version of one file: ``FileIdentity`` (device, inode, size, modification time)
taken with ``fstat`` on the descriptor HDF5 read the layout through. A reader compares it with ``stat``
of the path before using a layout (once per batch) and with ``fstat`` of every descriptor it opens, so a
replaced or rewritten episode is read again through h5py, never at the places of its former version.

The cache is per process: pickling gives an empty cache and a forked child starts empty (its copy of the
parent's lock could be held by a thread that does not exist in the child).
"""

from __future__ import annotations

import os
import threading
import zlib
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, NamedTuple

import numpy as np

from univtac_data.loaders.chunks import FrameLayout

DEFAULT_BUDGET_MIB = 512.0   # about 1.3 KiB a frame for the encoder targets of a GelSight Mini: ~270 MiB for the
                             # paper-size corpus (206k frames), plus one pooled pure_ref_rgb per distinct
                             # background frame; per process, filled only by episodes read
_EPISODE_OVERHEAD = 1500     # bytes counted per episode for the Python objects around its arrays (tracemalloc)
_ARRAY_OVERHEAD = 450        # and per array (FrameLayout and ChunkPlaces objects, NumPy headers, dict entries)
POOL_MIN_BYTES = 64 * 1024   # whole arrays from this size are kept once per content: a tactile image (pure_ref_rgb)
                             # is 225 KiB; below, a checksum (about 80 us for 225 KiB) would cost more than it saves

PoolKey = tuple[tuple[int, ...], str, int]   # shape, dtype, CRC-32 of the bytes


def pool_key(array: np.ndarray) -> PoolKey:
    """What finds arrays of the same content (equal keys are compared in full before sharing)."""
    return tuple(array.shape), array.dtype.str, zlib.crc32(np.ascontiguousarray(array))


class FileIdentity(NamedTuple):
    """One version of one file, as ``os.stat`` sees it."""

    device: int
    inode: int
    size: int            # bytes
    mtime_ns: int        # modification time, ns since the epoch

    @classmethod
    def of(cls, stat: os.stat_result) -> FileIdentity:
        return cls(stat.st_dev, stat.st_ino, stat.st_size, stat.st_mtime_ns)


@dataclass(frozen=True)
class EpisodeLayout:
    """What reading one version of one HDF5 episode file needs, without the file open. Immutable: a layout
    that gains an array is replaced by a new one (``with_arrays``)."""

    identity: FileIdentity
    frames: Mapping[str, FrameLayout | None] = field(default_factory=dict)  # path -> layout; None: h5py decodes
    whole: Mapping[str, np.ndarray] = field(default_factory=dict)           # path -> array read whole (read-only)
    pooled: Mapping[str, PoolKey] = field(default_factory=dict)             # paths of ``whole`` shared through the
                                                                             # cache's pool, and their keys
    nbytes: int = _EPISODE_OVERHEAD                                          # memory held, roughly, besides pooled
                                                                             # arrays (the cache counts those once)

    def with_arrays(self, frames: Mapping[str, FrameLayout | None], whole: Mapping[str, np.ndarray],
                    pooled: Mapping[str, PoolKey] | None = None) -> EpisodeLayout:
        """This layout with ``frames`` and ``whole`` added (whole arrays are made read-only: threads share them);
        ``pooled``: which of ``whole`` are the cache's shared arrays."""
        for array in whole.values():
            array.flags.writeable = False
        merged_frames, merged_whole = {**self.frames, **frames}, {**self.whole, **whole}
        merged_pooled = {p: k for p, k in self.pooled.items() if p not in whole} | dict(pooled or {})
        nbytes = _EPISODE_OVERHEAD + _ARRAY_OVERHEAD * (len(merged_frames) + len(merged_whole)) \
            + sum(f.places.nbytes for f in merged_frames.values() if f is not None and f.places is not None) \
            + sum(a.nbytes for p, a in merged_whole.items() if p not in merged_pooled)
        return EpisodeLayout(self.identity, MappingProxyType(merged_frames), MappingProxyType(merged_whole),
                             MappingProxyType(merged_pooled), nbytes)


class LayoutCache:
    """The ``EpisodeLayout`` of each recently read HDF5 episode file of this process, keyed by file path;
    least recently used dropped first once they hold more than ``budget_bytes`` (0 keeps nothing). Shared
    by the readers of a process's threads, hence the lock; every call is a few dictionary operations."""

    def __init__(self, budget_bytes: int = int(DEFAULT_BUDGET_MIB * 2**20)) -> None:
        if budget_bytes < 0:
            raise ValueError(f"budget_bytes must be >= 0 (got {budget_bytes})")
        self.budget_bytes = budget_bytes
        self._reset()

    def _reset(self) -> None:
        self._lock = threading.Lock()
        self._layouts: OrderedDict[str, EpisodeLayout] = OrderedDict()
        self._pool: dict[PoolKey, np.ndarray] = {}   # large whole arrays, one per content
        self._users: dict[PoolKey, int] = {}         # kept layouts' references to each (a pooled array counts in
        self._nbytes = 0                              # ``_nbytes`` while it has users)
        self._pid = os.getpid()

    def __getstate__(self) -> dict[str, Any]:
        return {"budget_bytes": self.budget_bytes}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.budget_bytes = state["budget_bytes"]
        self._reset()

    def _check_process(self) -> None:
        if self._pid != os.getpid():   # forked: the lock may have been held by a thread left in the parent
            self._reset()

    def get(self, path: str) -> EpisodeLayout | None:
        """The layout kept for ``path`` (now the most recently used), or ``None``."""
        self._check_process()
        with self._lock:
            layout = self._layouts.get(path)
            if layout is not None:
                self._layouts.move_to_end(path)
            return layout

    def record(self, path: str, identity: FileIdentity, *, frames: Mapping[str, FrameLayout | None] | None = None,
               whole: Mapping[str, np.ndarray] | None = None) -> None:
        """Add arrays of version ``identity`` of ``path``; a layout of another version is replaced. A layout
        larger than the whole budget is not kept. Whole arrays of ``POOL_MIN_BYTES`` or more that equal one
        the cache holds already are replaced by it."""
        self._check_process()
        if not self.budget_bytes:
            return
        whole = dict(whole or {})
        for array in whole.values():
            array.flags.writeable = False   # the caller's too, even where the pool's copy replaces it below
        keys = {p: pool_key(a) for p, a in whole.items() if a.nbytes >= POOL_MIN_BYTES}   # outside the lock
        with self._lock:
            old = self._layouts.pop(path, None)
            base = old if old is not None and old.identity == identity else EpisodeLayout(identity)
            layout = base.with_arrays(frames or {}, whole, self._share(whole, keys))
            alone = layout.nbytes + sum(self._pool[k].nbytes for k in set(layout.pooled.values()))
            if alone <= self.budget_bytes:   # else not kept: it would push out every other episode
                self._layouts[path] = layout
                self._acquire(layout)
            if old is not None:
                self._release(old)   # after acquiring: pooled arrays both hold stay
            for key in layout.pooled.values():
                if key not in self._users:
                    self._pool.pop(key, None)   # shared by a layout not kept
            while self._nbytes > self.budget_bytes:
                _, dropped = self._layouts.popitem(last=False)
                self._release(dropped)

    def _share(self, whole: dict[str, np.ndarray], keys: Mapping[str, PoolKey]) -> dict[str, PoolKey]:
        """Put the pool's array in ``whole`` for each path of ``keys`` whose content it holds (adding those it
        does not hold yet); the paths so shared, with their keys. Holding the lock."""
        pooled = {}
        for path, key in keys.items():
            kept = self._pool.setdefault(key, whole[path])
            if kept is whole[path] or np.array_equal(kept, whole[path]):   # else a CRC-32 collision: not shared
                whole[path], pooled[path] = kept, key
        return pooled

    def _acquire(self, layout: EpisodeLayout) -> None:
        self._nbytes += layout.nbytes
        for key in layout.pooled.values():
            users = self._users.get(key, 0)
            if not users:
                self._nbytes += self._pool[key].nbytes
            self._users[key] = users + 1

    def _release(self, layout: EpisodeLayout) -> None:
        self._nbytes -= layout.nbytes
        for key in layout.pooled.values():
            users = self._users.pop(key) - 1
            if users:
                self._users[key] = users
            else:
                self._nbytes -= self._pool.pop(key).nbytes

    def discard(self, path: str, identity: FileIdentity) -> None:
        """Forget ``path``'s layout if it is of version ``identity`` (a newer one recorded meanwhile stays)."""
        self._check_process()
        with self._lock:
            layout = self._layouts.get(path)
            if layout is not None and layout.identity == identity:
                del self._layouts[path]
                self._release(layout)

    @property
    def nbytes(self) -> int:
        """Bytes the kept layouts hold (roughly: their arrays plus a fixed overhead each; a pooled array once)."""
        self._check_process()
        return self._nbytes

    def __len__(self) -> int:
        self._check_process()
        return len(self._layouts)
