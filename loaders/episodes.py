"""The episode-store layer of the loaders: which episodes a loader uses, and reading them in a process.

``select_episodes`` turns dataset paths and filters into a list of ``EpisodeRef`` (plain, picklable
records). ``EpisodeReader`` owns the open episode handles of the *current process*: it opens lazily on
first read, keeps at most ``max_open`` open (least recently used closed first; none while a batch read is
``holding`` them), drops what it holds when pickled, and forgets handles it finds after a fork. So no h5py
or zarr handle crosses a process boundary (h5py handles inherited across fork give corrupt reads: pytorch
#11887), and a long run's memory stays bounded (openvla #39).

Datasets of many more episodes than ``max_open`` would reopen an episode for nearly every sample of a
shuffled batch; for local HDF5 files the reader therefore reads again through what it recorded on the
first touch (``layouts.LayoutCache``: chunk places and small arrays, checked against the file's version)
with descriptors of its own (``files.EpisodeFiles``), and opens h5py only for arrays not recorded yet.

Format 2.0 residual images (``marked_rgb`` over ``pure_rgb``, ``pure_rgb`` over ``pure_ref_rgb``) are read
the same way: a residual's source carries its base (``chunks.FrameSource``), taken from the same handle or
the same cached file, so that it stays valid exactly as long; a per-episode base is kept whole like the
small arrays. A residual's base is recorded with its chunk places, so cached reads need no h5py either.
"""

from __future__ import annotations

import functools
import os
from collections import OrderedDict
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Union

import numpy as np

from univtac_data.episode import Episode, resolve_shape
from univtac_data.storage import CorruptFileError, Dataset, DatasetError
from univtac_data.storage.backend import MAX_RESIDUAL_DEPTH, EpisodeHandle, residual_chain_error
from univtac_data.storage.hdf5_store import HDF5Handle
from univtac_data.storage.zarr_store import ZarrHandle
from univtac_data.schema.fields import field_for_path

from univtac_data.loaders.chunks import FrameBase, FrameChunks, FrameLayout, FrameSource
from univtac_data.loaders.files import DEFAULT_MAX_OPEN_FILES, CachedFile, EpisodeFiles
from univtac_data.loaders.layouts import FileIdentity, LayoutCache
from univtac_data.loaders.split import Split, check_split, split_of
from univtac_data.loaders.zarr_chunks import ZarrEpisodeCache, ZarrFrameChunks, metadata_identity, zarr_frame_chunks

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


def check_layouts(handle: EpisodeHandle, dataset: Dataset) -> None:
    """Raise ``CorruptFileError`` naming the file when an array's stored dtype or shape is not its field's (from
    the arrays' metadata only; values are checked by ``univtac-data validate``, not here)."""
    profile = dataset.sensor(handle.meta.sensor)
    expected = Episode(meta=handle.meta).expected_paths()
    for path in handle.paths():
        spec = expected.get(path)
        if spec is None:
            continue  # a field a newer minor version added: readers ignore it
        shape, dtype = handle.layout(path)
        allowed = ("uint8", "bool") if spec.dtype == "bool" else (spec.dtype,)
        if str(dtype) not in allowed:
            raise CorruptFileError(f"{handle.where}: {path} is stored as {dtype}, the format says {spec.dtype}; "
                                   f"run 'univtac-data validate'")
        want = resolve_shape(spec, path, handle.meta, profile)
        if tuple(shape) != want:
            raise CorruptFileError(f"{handle.where}: {path} has shape {tuple(shape)}, the format says {want}; "
                                   f"run 'univtac-data validate'")


def select_episodes(datasets: Sequence[Dataset], *, episodes: Sequence[str] | None = None, split: Split = "all",
                    val_fraction: float = 0.1, split_seed: int = 0, sensors: Sequence[str] | None = None,
                    names: Sequence[str] | None = None) -> list[EpisodeRef]:
    """Episodes of ``datasets`` that pass every filter, in (dataset, episode id) order.

    ``episodes``: explicit ids (in any of the datasets); ``split``: part by ``split_of`` (applied after
    ``episodes``); ``sensors`` / ``names``: keep only these sensor profiles / shape or task names. Each
    kept episode is opened once here, for its pads and cameras, and closed again.
    """
    check_split(split)
    for ds in datasets:
        if not ds.index_found:
            raise DatasetError(f"{ds.loc.url_of('meta/episodes.parquet')}: the dataset's index is missing; "
                               f"rebuild it with 'univtac-data reindex {ds.loc.url}'")
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
                check_layouts(handle, ds)
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


@functools.lru_cache(maxsize=4096)   # called per sample and array: field_for_path's pattern matching took 13 us
def is_whole_read(path: str) -> bool:
    """Whether a loader should read ``path`` whole and keep it (while the episode is open, and in the layout
    cache).

    Low-dimensional per-frame arrays and marker tracks are small (kilobytes per episode) but chunked
    over many frames, so reading one frame would decode the whole chunk again for every sample. Images
    and depth are chunked one frame per chunk, so they are read frame by frame.
    """
    spec = field_for_path(path)
    return spec is None or spec.codec in ("small", "dense") or spec.sampling == "per_episode"


@functools.lru_cache(maxsize=4096)
def is_bool(path: str) -> bool:
    """Whether ``path`` is a bool field (stored as uint8 0 / 1; ``EpisodeHandle.read`` gives bool)."""
    spec = field_for_path(path)
    return spec is not None and spec.dtype == "bool"


def handle_source(handle: EpisodeHandle, path: str, base_of: Callable[[str], FrameBase] | None = None,
                  depth: int = 0) -> FrameSource:
    """A ``FrameSource`` reading through an open handle: HDF5 chunks decoded directly (``chunks.FrameChunks``,
    through h5py's own descriptor), anything else through ``handle.read``. Valid while ``handle`` is open.

    A residual's chunks get their base from ``base_of(base path)`` (a reader passes one that keeps what it
    reads; default: read through ``handle`` alone); ``depth``: the array's place in a chain of residuals.
    Raises ``CorruptFileError`` naming the file when the array's ``residual_of`` is wrong (as
    ``handle.read`` would), ``KeyError`` when ``path`` is absent.
    """
    shape, dtype = handle.layout(path)   # KeyError when absent (the loader checked paths first)
    residual_of = handle.residual_base(path)
    if residual_of is not None and depth >= MAX_RESIDUAL_DEPTH:   # what handle.read raises for a cycle
        raise residual_chain_error(handle.where, path)
    chunks = _frame_chunks(handle, path, residual_of)
    base = None
    if chunks is not None and residual_of is not None:   # without chunks handle.read adds the base itself
        base = (base_of or functools.partial(_handle_base, handle, shape, depth))(residual_of)
    return FrameSource(shape[1:], dtype, chunks, lambda frame: handle.read(path, frame), base)


def _handle_base(handle: EpisodeHandle, shape: tuple[int, ...], depth: int, base: str) -> FrameBase:
    """What a residual of ``shape`` adds, through ``handle`` alone: a per-frame base frame by frame, a
    per-episode one read whole."""
    if handle.layout(base)[0] == shape:
        return handle_source(handle, base, depth=depth + 1)
    return handle.read(base)


def _frame_chunks(handle: EpisodeHandle, path: str, residual_of: str | None) -> FrameChunks | ZarrFrameChunks | None:
    if isinstance(handle, ZarrHandle):
        return zarr_frame_chunks(handle, path, residual_of)
    if not isinstance(handle, HDF5Handle):
        return None
    try:
        dataset = handle.h5py_dataset(path)
    except Exception:  # missing or damaged: handle.read raises the format's error on first use
        return None
    return FrameChunks.of(dataset, residual_of)


@dataclass
class _Open:
    handle: EpisodeHandle
    identity: FileIdentity | None                  # the file version the handle reads (local HDF5 only)
    whole: dict[str, np.ndarray] = field(default_factory=dict)
    frames: dict[str, FrameSource] = field(default_factory=dict)


class EpisodeReader:
    """Reads episodes of several datasets in the current process.

    Owns a bounded LRU of open episode handles (``max_open``) and, for local HDF5 episodes, an
    ``EpisodeFiles`` (``max_open_files`` descriptors of its own). The first read of an array of an HDF5
    episode goes through h5py and records what later reads need in ``layouts`` (a ``LayoutCache``, which
    ``sibling`` readers of other threads share); later reads of a checked file need no h5py handle at all:
    ``os.pread`` at the recorded places, or the array kept whole. Safe to hand to DataLoader workers by fork
    or by pickling: each process opens its own handles and descriptors, and starts with an empty cache.

    Files are checked against the recorded version once per *generation*: each ``holding`` block (a batch),
    or each read outside one.
    """

    def __init__(self, datasets: Sequence[Dataset], max_open: int = 16, *,
                 max_open_files: int = DEFAULT_MAX_OPEN_FILES, layouts: LayoutCache | None = None,
                 zarr_episodes: ZarrEpisodeCache | None = None) -> None:
        if max_open < 1:
            raise ValueError(f"max_open must be >= 1 (got {max_open})")
        self.datasets = list(datasets)
        self.max_open = max_open
        self.layouts = layouts if layouts is not None else LayoutCache()
        # what Zarr episodes need once opened (chunks, shard indexes, small arrays), shared with siblings
        self.zarr_episodes = zarr_episodes if zarr_episodes is not None else ZarrEpisodeCache()
        self.files = EpisodeFiles(self.layouts, max_open_files)
        self._open: OrderedDict[tuple[int, str], _Open] = OrderedDict()
        self._retired: list[EpisodeHandle] = []   # handles of replaced files, closed once no batch holds them
        self._paths: dict[tuple[int, str], str | None] = {}
        self._zarr_keys: dict[tuple[int, str], tuple[str, str] | None] = {}
        # per Zarr episode: sources made from zarr_episodes (per reader), and the generation they were checked in
        self._zarr_sources: dict[tuple[int, str], dict[str, FrameSource]] = {}
        self._zarr_checked: dict[tuple[int, str], int] = {}
        self._pid = os.getpid()
        self._holds = 0  # nested ``holding()`` blocks: while > 0 no handle or descriptor is closed
        self._generation = 0
        self.opens = 0  # handles opened by this process since creation; for tests and profiling

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_open"], state["_retired"], state["_holds"] = OrderedDict(), [], 0
        state["_zarr_sources"], state["_zarr_checked"] = {}, {}
        return state

    def sibling(self) -> EpisodeReader:
        """A reader for another thread of this process: the same datasets, bounds and layout cache, its own
        handles and descriptors (so no thread closes what another reads through)."""
        self._check_process()
        return EpisodeReader(self.datasets, self.max_open, max_open_files=self.files.max_open, layouts=self.layouts,
                             zarr_episodes=self.zarr_episodes)

    def _check_process(self) -> None:
        if self._pid != os.getpid():
            # Handles inherited across fork share the parent's file offsets and library state: reading
            # through them corrupts reads. Dropping them only releases this process's copies.
            self._open, self._retired = OrderedDict(), []
            self._zarr_sources, self._zarr_checked = {}, {}
            self.files.close()   # plain descriptors: closing the child's copies leaves the parent's open
            self._pid = os.getpid()
            self.opens = 0

    def _begin(self) -> None:
        self._check_process()
        if not self._holds:
            self._generation += 1

    def _file_path(self, ref: EpisodeRef) -> str | None:
        """The episode's file when it is a local HDF5 file (the only kind whose layout is cached)."""
        key = (ref.dataset, ref.episode_id)
        if key not in self._paths:
            ds = self.datasets[ref.dataset]
            local_hdf5 = ds.info.storage == "hdf5" and ds.loc.is_local
            self._paths[key] = os.path.join(ds.loc.root, ds.index[ref.episode_id].path) if local_hdf5 else None
        return self._paths[key]

    def _zarr_key(self, ref: EpisodeRef) -> tuple[str, str] | None:
        """The episode's key in ``zarr_episodes`` (its URL and index digest) when it is a Zarr episode."""
        key = (ref.dataset, ref.episode_id)
        if key not in self._zarr_keys:
            ds = self.datasets[ref.dataset]
            row = ds.index[ref.episode_id]
            self._zarr_keys[key] = (ds.loc.url_of(row.path), row.sha256) if ds.info.storage == "zarr" else None
        return self._zarr_keys[key]

    def _zarr_source(self, ref: EpisodeRef, key: tuple[str, str], path: str, depth: int = 0) -> FrameSource | None:
        """``path``'s source from the chunks ``zarr_episodes`` keeps (no zarr handle opened), or ``None`` when
        they are not kept (nor, for a residual, its base)."""
        if not self._zarr_current(ref, key):
            return None
        episode = (ref.dataset, ref.episode_id)
        source = self._zarr_sources.get(episode, {}).get(path)
        if source is not None:
            return source
        chunks = self.zarr_episodes.get(key, path)
        if not isinstance(chunks, ZarrFrameChunks):
            return None
        if chunks.identity is not None and metadata_identity(chunks.array_path) != chunks.identity:
            self._zarr_forget(ref, key)
            return None
        base: FrameBase | None = None
        residual_of = chunks.layout.residual_of
        if residual_of is not None:
            if depth >= MAX_RESIDUAL_DEPTH:
                return None
            base = self.zarr_episodes.get(key, residual_of) if is_whole_read(residual_of) \
                else self._zarr_source(ref, key, residual_of, depth + 1)
            if base is None:
                return None
        source = FrameSource(chunks.frame_shape, chunks.layout.dtype, chunks,   # type: ignore[arg-type]
                             lambda frame: self._entry(ref).handle.read(path, frame), base)
        self._zarr_sources.setdefault(episode, {})[path] = source
        return source

    def _zarr_current(self, ref: EpisodeRef, key: tuple[str, str]) -> bool:
        """Whether the sources this reader keeps for a Zarr episode still describe it: for local arrays, each
        one's ``zarr.json`` is the version its chunks were read from (checked once per generation, as HDF5
        files are). When not, everything kept of the episode is dropped (``_zarr_forget``)."""
        episode = (ref.dataset, ref.episode_id)
        if self._zarr_checked.get(episode) == self._generation:
            return True
        for source in self._zarr_sources.get(episode, {}).values():
            chunks = source.chunks
            if isinstance(chunks, ZarrFrameChunks) and chunks.identity is not None \
                    and metadata_identity(chunks.array_path) != chunks.identity:
                self._zarr_forget(ref, key)
                return False
        self._zarr_checked[episode] = self._generation
        return True

    def _zarr_forget(self, ref: EpisodeRef, key: tuple[str, str]) -> None:
        """Drop what is kept of a Zarr episode whose metadata changed, and retire its open handle: it is read
        through zarr again (which reports damage)."""
        episode = (ref.dataset, ref.episode_id)
        self.zarr_episodes.drop(key)
        self._zarr_sources.pop(episode, None)
        self._zarr_checked.pop(episode, None)
        entry = self._open.pop(episode, None)
        if entry is not None:
            self._retired.append(entry.handle)

    def _cached(self, ref: EpisodeRef) -> CachedFile | None:
        path = self._file_path(ref)
        if path is None:
            return None
        file, replaced = self.files.lookup(path, self._generation)
        if replaced:   # an open handle reads the former file
            entry = self._open.pop((ref.dataset, ref.episode_id), None)
            if entry is not None:
                self._retired.append(entry.handle)
        if not self._holds:
            self._close_least_recent()
        return file

    def _entry(self, ref: EpisodeRef) -> _Open:
        key = (ref.dataset, ref.episode_id)
        entry = self._open.get(key)
        if entry is not None:
            self._open.move_to_end(key)
            return entry
        handle = self.datasets[ref.dataset].open_episode(ref.episode_id)
        stat = handle.file_stat() if isinstance(handle, HDF5Handle) and self._file_path(ref) is not None else None
        entry = _Open(handle, FileIdentity.of(stat) if stat is not None else None)
        self.opens += 1
        self._open[key] = entry
        if not self._holds:
            self._close_least_recent()
        return entry

    def _record(self, ref: EpisodeRef, entry: _Open, *, frames: dict[str, FrameLayout | None] | None = None,
                whole: dict[str, np.ndarray] | None = None) -> None:
        path = self._file_path(ref)
        if entry.identity is not None and path is not None:
            self.layouts.record(path, entry.identity, frames=frames, whole=whole)

    def _close_least_recent(self) -> None:
        while len(self._open) > self.max_open:
            _, oldest = self._open.popitem(last=False)
            oldest.handle.close()
        retired, self._retired = self._retired, []
        for handle in retired:
            handle.close()
        self.files.trim()

    @contextmanager
    def holding(self) -> Iterator[None]:
        """Within the block no handle or descriptor is closed, so every ``FrameSource`` taken from this reader
        stays valid, even when a batch spans more than ``max_open`` episodes (each is opened once per batch,
        not once per array), and each file is checked once; on exit the least recently used are closed down
        to ``max_open`` and ``max_open_files`` again."""
        self._check_process()
        if not self._holds:
            self._generation += 1
        self._holds += 1
        try:
            yield
        finally:
            self._holds -= 1
            if not self._holds:
                self._close_least_recent()

    def read(self, ref: EpisodeRef, path: str, index: Any = ()) -> np.ndarray:
        """``path[index]`` of the episode in its logical dtype (see ``EpisodeHandle.read``). Paths for which
        ``is_whole_read`` holds are read whole once and indexed in memory (the array is read-only); one frame
        (an int ``index``) of a local HDF5 array or of a Zarr array is read like ``frame_source``."""
        self._begin()
        if is_whole_read(path):
            file = self._cached(ref)
            array = file.layout.whole.get(path) if file is not None else None
            zarr_key = self._zarr_key(ref) if file is None else None
            if zarr_key is not None:
                array = self.zarr_episodes.get(zarr_key, path)
            part: np.ndarray = (array if array is not None else self._read_whole(ref, path))[index]
            return part
        if isinstance(index, (int, np.integer)) and (self._file_path(ref) is not None
                                                     or self.datasets[ref.dataset].info.storage == "zarr"):
            frame: np.ndarray = self._frame_source(ref, path).read(int(index))
            return np.not_equal(frame, 0) if is_bool(path) else frame
        return self._entry(ref).handle.read(path, index)

    def _read_whole(self, ref: EpisodeRef, path: str) -> np.ndarray:
        entry = self._entry(ref)
        array = entry.whole.get(path)
        if array is None:
            array = entry.whole[path] = entry.handle.read(path)
            self._record(ref, entry, whole={path: array})
            zarr_key = self._zarr_key(ref)
            if zarr_key is not None:
                self.zarr_episodes.put(zarr_key, path, array)
        return array

    def frame_source(self, ref: EpisodeRef, path: str) -> FrameSource:
        """A ``FrameSource`` for per-frame array ``path`` of the episode, valid while its handle or descriptor
        stays open: within a ``holding`` block, or outside one until ``max_open`` other episodes (or
        ``max_open_files`` other files) have been read."""
        self._begin()
        return self._frame_source(ref, path)

    def _frame_source(self, ref: EpisodeRef, path: str) -> FrameSource:
        file = self._cached(ref)
        if file is not None:
            source = file.sources.get(path) or self._cached_source(ref, file, path)
            if source is not None:
                return source
        zarr_key = self._zarr_key(ref)
        if zarr_key is not None:
            source = self._zarr_source(ref, zarr_key, path)
            if source is not None:
                return source
        return self._handle_source(ref, self._entry(ref), path)

    def _handle_source(self, ref: EpisodeRef, entry: _Open, path: str, depth: int = 0) -> FrameSource:
        """``path``'s source through the open handle, kept with it; a residual's per-frame base is a source of
        the same handle (so it lives as long), a per-episode one is read whole and kept like small arrays."""
        source = entry.frames.get(path)
        if source is None:
            source = handle_source(entry.handle, path, lambda base: self._handle_base(ref, entry, base, depth), depth)
            entry.frames[path] = source
            if isinstance(source.chunks, ZarrFrameChunks):
                zarr_key = self._zarr_key(ref)
                if zarr_key is not None:
                    self.zarr_episodes.put(zarr_key, path, source.chunks)
            else:
                self._record(ref, entry, frames={path: source.chunks.layout if source.chunks is not None else None})
        return source

    def _handle_base(self, ref: EpisodeRef, entry: _Open, base: str, depth: int) -> FrameBase:
        """A residual's base as ``_cached_base`` finds it again from the layout cache: kept whole when small
        (``pure_ref_rgb``), else a source of the same handle."""
        if is_whole_read(base):
            return self._read_whole(ref, base)
        return self._handle_source(ref, entry, base, depth + 1)

    def _cached_source(self, ref: EpisodeRef, file: CachedFile, path: str, depth: int = 0) -> FrameSource | None:
        """``path``'s source through the reader's own descriptor of ``file``, from its cached layout alone, or
        ``None`` when the layout lacks it (or, for a residual, lacks its base: the handle path reads both)."""
        layout = file.layout.frames.get(path)
        if layout is None or layout.places is None:
            return None   # not recorded yet, or only h5py reads it
        base = None
        if layout.residual_of is not None:
            if depth >= MAX_RESIDUAL_DEPTH:
                return None   # never recorded so (the handle path raises first); let it report the chain
            base = self._cached_base(ref, file, layout.residual_of, depth)
            if base is None:
                return None
        descriptor = self.files.descriptor(file)
        if descriptor < 0:
            return None
        source = FrameSource(layout.frame_shape, layout.dtype, FrameChunks(layout, descriptor),
                             lambda frame: self._entry(ref).handle.read(path, frame), base)
        file.sources[path] = source
        return source

    def _cached_base(self, ref: EpisodeRef, file: CachedFile, base: str, depth: int) -> FrameBase | None:
        """A cached residual's base from the same file's layout only: a per-frame base's source then reads
        through the same descriptor, so it stays valid exactly as long. ``None`` when not kept."""
        if is_whole_read(base):
            return file.layout.whole.get(base)
        return file.sources.get(base) or self._cached_source(ref, file, base, depth + 1)

    @property
    def n_open(self) -> int:
        """Episode handles (h5py or zarr) open in this process now."""
        return len(self._open) if self._pid == os.getpid() else 0

    @property
    def n_files(self) -> int:
        """Descriptors of this reader's own open in this process now (besides the handles)."""
        return self.files.n_open if self._pid == os.getpid() else 0

    def close(self) -> None:
        """Close every handle and descriptor this process opened."""
        if self._pid == os.getpid():
            for entry in self._open.values():
                entry.handle.close()
            for handle in self._retired:
                handle.close()
        self._open, self._retired = OrderedDict(), []
        self.files.close()
