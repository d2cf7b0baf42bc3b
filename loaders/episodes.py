"""The episode-store layer of the loaders: which episodes a loader uses, and reading them in a process.

``select_episodes`` turns dataset paths and filters into a list of ``EpisodeRef`` (plain, picklable
records). ``EpisodeReader`` owns the open episode handles of the *current process*: it opens lazily on
first read, keeps at most ``max_open`` open (least recently used closed first; none while a batch read is
``holding`` them), drops what it holds when pickled, and forgets handles it finds after a fork. So no h5py
or zarr handle crosses a process boundary (h5py handles inherited across fork give corrupt reads: pytorch
#11887), and a long run's memory stays bounded (openvla #39).
"""

from __future__ import annotations

import os
from collections import OrderedDict
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Union

import numpy as np

from univtac_data.storage import Dataset
from univtac_data.storage.backend import EpisodeHandle
from univtac_data.storage.hdf5_store import HDF5Handle
from univtac_data.schema.fields import field_for_path

from univtac_data.loaders.chunks import FrameChunks
from univtac_data.loaders.split import Split, check_split, split_of

PathLike = Union[str, "os.PathLike[str]"]


@dataclass(frozen=True)
class EpisodeRef:
    """One selected episode of one of a loader's datasets (no open file; picklable)."""

    dataset: int                 # position of the episode's dataset in the loader's path list
    episode_id: str
    n_frames: int                # T
    sensor: str                  # sensor profile name, e.g. "gelsight_mini"
    name: str                    # indenter shape or task name (EpisodeMeta.name)
    pads: tuple[str, ...]        # tactile pads present, e.g. ("left", "right")
    cameras: tuple[str, ...]     # scene cameras present
    paths: frozenset[str]        # array paths stored in the episode
    sha256: str                  # the index's digest of the episode's files


def as_path_list(path_or_paths: PathLike | Sequence[PathLike]) -> list[str]:
    """One path or several, as a list of strings."""
    if isinstance(path_or_paths, (str, os.PathLike)):
        return [os.fspath(path_or_paths)]
    paths = [os.fspath(p) for p in path_or_paths]
    if not paths:
        raise ValueError("need at least one dataset path (got an empty list)")
    return paths


def select_episodes(datasets: Sequence[Dataset], *, episodes: Sequence[str] | None = None, split: Split = "all",
                    val_fraction: float = 0.1, split_seed: int = 0, sensors: Sequence[str] | None = None,
                    names: Sequence[str] | None = None) -> list[EpisodeRef]:
    """Episodes of ``datasets`` that pass every filter, in (dataset, episode id) order.

    ``episodes``: explicit ids (in any of the datasets); ``split``: part by ``split_of`` (applied after
    ``episodes``); ``sensors`` / ``names``: keep only these sensor profiles / shape or task names. Each
    kept episode is opened once here, for its pads and cameras, and closed again.
    """
    check_split(split)
    wanted = set(episodes) if episodes is not None else None
    if wanted is not None:
        known = {eid for ds in datasets for eid in ds.index}
        unknown = sorted(wanted - known)
        if unknown:
            raise ValueError(f"episodes not in any of the datasets: {unknown[:5]}"
                             f"{' ...' if len(unknown) > 5 else ''}")
    refs: list[EpisodeRef] = []
    for k, ds in enumerate(datasets):
        for episode_id in ds.episode_ids:
            row = ds.index[episode_id]
            if wanted is not None and episode_id not in wanted:
                continue
            if split != "all" and split_of(episode_id, val_fraction, split_seed) != split:
                continue
            if sensors is not None and row.sensor not in sensors:
                continue
            if names is not None and row.name not in names:
                continue
            with ds.open_episode(episode_id) as handle:
                meta, paths = handle.meta, frozenset(handle.paths())
            refs.append(EpisodeRef(dataset=k, episode_id=episode_id, n_frames=row.n_frames, sensor=row.sensor,
                                   name=row.name, pads=tuple(meta.pads), cameras=tuple(c.name for c in meta.cameras),
                                   paths=paths, sha256=row.sha256))
    if not refs:
        raise ValueError(f"no episode left after selection (split={split!r}, val_fraction={val_fraction}, "
                         f"sensors={list(sensors) if sensors is not None else None}, "
                         f"names={list(names) if names is not None else None}, "
                         f"episodes={sorted(wanted) if wanted is not None else None}) in "
                         f"{[ds.loc.url for ds in datasets]}")
    return refs


def open_selected(paths: Sequence[str], config: Any) -> tuple[list[Dataset], list[EpisodeRef]]:
    """Open ``paths`` and pick the episodes a loader config asks for (its ``episodes``, ``split``,
    ``val_fraction``, ``split_seed``, ``sensors`` and ``names``)."""
    datasets = [Dataset.open(p) for p in paths]
    refs = select_episodes(datasets, episodes=config.episodes, split=config.split, val_fraction=config.val_fraction,
                           split_seed=config.split_seed, sensors=config.sensors, names=config.names)
    return datasets, refs


def require_paths(refs: Sequence[EpisodeRef], paths: Sequence[str], datasets: Sequence[Dataset]) -> None:
    """Raise ``ValueError`` naming the first episode that lacks one of ``paths``."""
    for ref in refs:
        missing = [p for p in paths if p not in ref.paths]
        if missing:
            raise ValueError(f"{datasets[ref.dataset].loc.url}: episode {ref.episode_id} has no {missing} "
                             f"(it stores {len(ref.paths)} arrays; pads {list(ref.pads)}, "
                             f"cameras {list(ref.cameras)})")


def is_whole_read(path: str) -> bool:
    """Whether a loader should read ``path`` whole and keep it while the episode is open.

    Low-dimensional per-frame arrays and marker tracks are small (kilobytes per episode) but chunked
    over many frames, so reading one frame would decode the whole chunk again for every sample. Images
    and depth are chunked one frame per chunk, so they are read frame by frame.
    """
    spec = field_for_path(path)
    return spec is None or spec.codec in ("small", "dense") or spec.sampling == "per_episode"


class FrameSource:
    """One per-frame array of an open episode (an image or depth map), read one frame at a time into a
    buffer the caller owns. HDF5 frames are decoded straight from their chunk (``chunks.FrameChunks``);
    anything else, and any chunk that fails a check there, goes through ``EpisodeHandle.read``, which
    decodes it or raises ``CorruptFileError`` naming the file."""

    def __init__(self, handle: EpisodeHandle, path: str) -> None:
        self.handle, self.path = handle, path
        shape, self.dtype = handle.layout(path)   # KeyError when absent (the loader checked paths first)
        self.frame_shape = shape[1:]               # e.g. (240, 320, 3) for an image
        self.chunks = _frame_chunks(handle, path)

    def read(self, frame: int) -> np.ndarray:
        """Frame ``frame`` as a new array of the stored dtype."""
        out = np.empty(self.frame_shape, self.dtype)
        self.read_into(frame, out)
        return out

    def read_into(self, frame: int, out: np.ndarray) -> None:
        """Frame ``frame`` into ``out``: C-contiguous, the stored frame shape, the stored dtype or one of its
        size (uint16 micrometres into an int16 buffer keeps the bits)."""
        if self.chunks is None or not self.chunks.read_frame_into(frame, out):
            out[...] = self.handle.read(self.path, frame).view(out.dtype)


def _frame_chunks(handle: EpisodeHandle, path: str) -> FrameChunks | None:
    if not isinstance(handle, HDF5Handle):
        return None
    try:
        dataset = handle.h5py_dataset(path)
    except Exception:  # missing or damaged: handle.read raises the format's error on first use
        return None
    return FrameChunks.of(dataset)


@dataclass
class _Open:
    handle: EpisodeHandle
    whole: dict[str, np.ndarray] = field(default_factory=dict)
    frames: dict[str, FrameSource] = field(default_factory=dict)


class EpisodeReader:
    """Reads episodes of several datasets in the current process, through a bounded LRU of open handles.

    Safe to hand to DataLoader workers by fork or by pickling: each process opens its own handles on
    first use.
    """

    def __init__(self, datasets: Sequence[Dataset], max_open: int = 16) -> None:
        if max_open < 1:
            raise ValueError(f"max_open must be >= 1 (got {max_open})")
        self.datasets = list(datasets)
        self.max_open = max_open
        self._open: OrderedDict[tuple[int, str], _Open] = OrderedDict()
        self._pid = os.getpid()
        self._holds = 0  # nested ``holding()`` blocks: while > 0 no handle is closed
        self.opens = 0  # handles opened by this process since creation; for tests and profiling

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_open"] = OrderedDict()
        state["_holds"] = 0
        return state

    def _entry(self, ref: EpisodeRef) -> _Open:
        if self._pid != os.getpid():
            # Handles inherited across fork share the parent's file offsets and library state: reading
            # through them corrupts reads. Dropping them only releases this process's copies.
            self._open = OrderedDict()
            self._pid = os.getpid()
            self.opens = 0
        key = (ref.dataset, ref.episode_id)
        entry = self._open.get(key)
        if entry is not None:
            self._open.move_to_end(key)
            return entry
        entry = _Open(self.datasets[ref.dataset].open_episode(ref.episode_id))
        self.opens += 1
        self._open[key] = entry
        if not self._holds:
            self._close_least_recent()
        return entry

    def _close_least_recent(self) -> None:
        while len(self._open) > self.max_open:
            _, oldest = self._open.popitem(last=False)
            oldest.handle.close()

    @contextmanager
    def holding(self) -> Iterator[None]:
        """Within the block no handle is closed, so every ``FrameSource`` taken from this reader stays valid,
        even when a batch spans more than ``max_open`` episodes (each is opened once per batch, not once per
        array); on exit the least recently used are closed down to ``max_open`` again."""
        self._holds += 1
        try:
            yield
        finally:
            self._holds -= 1
            if not self._holds:
                self._close_least_recent()

    def read(self, ref: EpisodeRef, path: str, index: Any = ()) -> np.ndarray:
        """``path[index]`` of the episode in its logical dtype (see ``EpisodeHandle.read``). Paths for which
        ``is_whole_read`` holds are read whole once and indexed in memory."""
        entry = self._entry(ref)
        if is_whole_read(path):
            array = entry.whole.get(path)
            if array is None:
                array = entry.handle.read(path)
                entry.whole[path] = array
            return array[index]
        return entry.handle.read(path, index)

    def frame_source(self, ref: EpisodeRef, path: str) -> FrameSource:
        """A ``FrameSource`` for per-frame array ``path`` of the episode, valid while its handle stays open
        (at most ``max_open`` other episodes later)."""
        entry = self._entry(ref)
        source = entry.frames.get(path)
        if source is None:
            source = entry.frames[path] = FrameSource(entry.handle, path)
        return source

    @property
    def n_open(self) -> int:
        """Handles open in this process now."""
        return len(self._open) if self._pid == os.getpid() else 0

    def close(self) -> None:
        """Close every handle this process opened."""
        if self._pid == os.getpid():
            for entry in self._open.values():
                entry.handle.close()
        self._open = OrderedDict()
