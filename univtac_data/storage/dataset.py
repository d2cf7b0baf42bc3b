"""Datasets on disk: ``Dataset`` reads, ``DatasetWriter`` writes.

Layout::

    ROOT/
      meta/info.json            format version, storage backend, sensor profiles, field table
      meta/episodes.parquet     one row per committed episode, keyed by episode_id
      meta/manifest.json        SHA-256 and size of every episode file
      episodes/<episode_id>.h5  (HDF5)  or  episodes/<episode_id>.zarr/  (Zarr v3 group)

An episode is written under ``episodes/.tmp-...``, checksummed, then renamed to its final name, and only
then entered in the manifest and the index. A kill at any point leaves complete episodes only; a finished
episode that missed the index is picked up by ``DatasetWriter.open`` (resume) or ``reindex``.
"""

from __future__ import annotations

import hashlib
import json
import os
import uuid
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np

from univtac_data.episode import Episode, check_episode
from univtac_data.schema.models import DatasetInfo, IndexRow, Manifest, ManifestEntry
from univtac_data.schema.sensors import SensorProfile, get_sensor
from univtac_data.storage.backend import EpisodeHandle, EpisodeStore, parse_versioned
from univtac_data.storage.encoding import ZSTD_LEVEL, ZSTD_LEVELS
from univtac_data.storage.errors import (
    CorruptFileError,
    DatasetError,
    DatasetNotFoundError,
    EpisodeExistsError,
    FormatVersionError,
    NotADatasetError,
)
from univtac_data.storage.fs import TMP_PREFIX, Location, fsync_dir
from univtac_data.storage.hdf5_store import HDF5Store
from univtac_data.storage.lock import LOCK_NAME, DatasetLock
from univtac_data.storage.index import (
    INDEX_PATH,
    INFO_PATH,
    read_index,
    read_manifest,
    write_index,
    write_manifest,
)
from univtac_data.storage.zarr_store import ZarrStore
from univtac_data.version import FORMAT_MAJOR, FORMAT_VERSION, parse_format_version

EPISODES_DIR = "episodes"
STORES: dict[str, EpisodeStore] = {"hdf5": HDF5Store(), "zarr": ZarrStore()}


def get_store(storage: str) -> EpisodeStore:
    if storage not in STORES:
        raise DatasetError(f"unknown storage {storage!r}; choose one of {', '.join(STORES)}")
    return STORES[storage]


def episode_relpath(episode_id: str, store: EpisodeStore) -> str:
    return f"{EPISODES_DIR}/{episode_id}{store.suffix}"


def read_info(loc: Location) -> DatasetInfo:
    return parse_versioned(DatasetInfo, loc.read_bytes(INFO_PATH), loc.url_of(INFO_PATH), "dataset description")


def write_info(loc: Location, info: DatasetInfo) -> None:
    loc.write_bytes_atomic(INFO_PATH, json.dumps(info.model_dump(mode="json"), indent=1, sort_keys=True).encode())


def episode_digest(entries: dict[str, ManifestEntry]) -> str:
    """One SHA-256 for an episode: over its files' sorted ``path sha256`` lines."""
    lines = "".join(f"{path} {entries[path].sha256}\n" for path in sorted(entries))
    return hashlib.sha256(lines.encode()).hexdigest()


def index_row(episode_id: str, relpath: str, handle_or_episode: EpisodeHandle | Episode,
              entries: dict[str, ManifestEntry]) -> IndexRow:
    meta = handle_or_episode.meta
    if isinstance(handle_or_episode, Episode):
        stamps = handle_or_episode.arrays["timestamps_ns"]
    else:
        stamps = handle_or_episode.read("timestamps_ns")
    return IndexRow(
        episode_id=episode_id, path=relpath, format_version=meta.format_version, kind=meta.kind, name=meta.name,
        sensor=meta.sensor, seed=meta.seed, n_frames=meta.n_frames, nominal_rate_hz=meta.nominal_rate_hz,
        duration_ns=int(stamps[-1] - stamps[0]) if len(stamps) else 0, success=meta.success,
        max_indentation_mm=meta.safety.max_indentation_mm, max_slip_mm=meta.safety.max_slip_mm,
        bytes=sum(e.bytes for e in entries.values()), sha256=episode_digest(entries),
    )


@dataclass
class WrittenEpisode:
    """What a worker hands the coordinating writer after ``write_episode_file``."""

    row: IndexRow
    files: dict[str, ManifestEntry]
    staged: str | None = None  # relative path of a file written but not yet published (``publish=False``)


def _hash_files(loc: Location, tmp_rel: str, final_rel: str, episode_id: str) -> dict[str, ManifestEntry]:
    entries = {}
    for rel in loc.files_under(tmp_rel):
        final = final_rel + rel[len(tmp_rel):]
        entries[final] = ManifestEntry(sha256=loc.sha256(rel), bytes=loc.size(rel), episode_id=episode_id)
    return entries


def _publish(loc: Location, tmp_rel: str, final_rel: str) -> None:
    """Make a finished episode visible under its final name."""
    if loc.is_local:
        os.replace(loc.join(tmp_rel), loc.join(final_rel))
        fsync_dir(loc.join(EPISODES_DIR))
        return
    # Object stores cannot rename. Copy the arrays first and the group's root zarr.json last: a reader
    # sees no episode until that object exists, and then sees all of it.
    root_doc = f"{tmp_rel}/zarr.json"
    files = [f for f in loc.files_under(tmp_rel) if f != root_doc]
    for rel in [*files, root_doc]:
        loc.fs.copy(loc.join(rel), loc.join(final_rel + rel[len(tmp_rel):]))
    loc.remove(tmp_rel)


def write_episode_file(loc: Location, storage: str, episode: Episode, *,
                       compression_level: int = ZSTD_LEVEL, publish: bool = True) -> WrittenEpisode:
    """Check ``episode`` against the spec, write it atomically, and return its index row and checksums.
    ``compression_level``: Blosc level 1 (fastest) to 9 (smallest); readers need not know it.

    Safe to call from worker processes in parallel (distinct episode ids); the caller commits the result
    with ``DatasetWriter.commit``. ``publish=False`` leaves the file under its temporary name (which a
    reopening writer removes) for the caller to ``publish_staged`` or ``discard_staged``: a collector that
    keeps only some of what its workers made decides in a fixed order, whatever order they finish in.
    """
    if compression_level not in ZSTD_LEVELS:
        raise ValueError(f"compression level must be {ZSTD_LEVELS.start} to {ZSTD_LEVELS.stop - 1} "
                         f"(got {compression_level})")
    store = get_store(storage)
    episode = episode.in_current_format()  # writers write the version they implement (spec, section 2)
    check_episode(episode, get_sensor(episode.meta.sensor))
    episode_id = episode.meta.episode_id
    final_rel = episode_relpath(episode_id, store)
    if loc.exists(final_rel):
        raise EpisodeExistsError(f"{loc.url_of(final_rel)}: episode {episode_id} already exists")
    loc.makedirs(EPISODES_DIR)
    tmp_rel = f"{EPISODES_DIR}/{TMP_PREFIX}{episode_id}-{uuid.uuid4().hex[:8]}{store.suffix}"
    try:
        store.write(episode, loc, tmp_rel, compression_level)
        files = _hash_files(loc, tmp_rel, final_rel, episode_id)
        if publish:
            _publish(loc, tmp_rel, final_rel)
    except BaseException:
        loc.remove(tmp_rel)
        raise
    return WrittenEpisode(row=index_row(episode_id, final_rel, episode, files), files=files,
                          staged=None if publish else tmp_rel)


def publish_staged(loc: Location, written: WrittenEpisode) -> WrittenEpisode:
    """Make an episode written with ``publish=False`` visible under its final name (then ``commit`` it)."""
    if written.staged is None:
        return written
    if loc.exists(written.row.path):
        loc.remove(written.staged)
        raise EpisodeExistsError(f"{loc.url_of(written.row.path)}: episode {written.row.episode_id} already exists")
    _publish(loc, written.staged, written.row.path)
    return WrittenEpisode(row=written.row, files=written.files)


def discard_staged(loc: Location, written: WrittenEpisode) -> None:
    """Remove an episode written with ``publish=False`` that will not be kept."""
    if written.staged is not None:
        loc.remove(written.staged)


class Dataset:
    """A dataset opened for reading: ``info``, the ``index`` (episode id -> row), and episodes on demand.

    Holds no open file: ``open_episode`` returns a handle the caller closes, so a ``Dataset`` may be
    pickled into worker processes.
    """

    def __init__(self, loc: Location, info: DatasetInfo, index: dict[str, IndexRow]) -> None:
        self.loc = loc
        self.info = info
        self.index = index
        self.store = get_store(info.storage)
        self.index_found = True  # False: meta/episodes.parquet is missing (``open`` then has an empty index)

    @classmethod
    def open(cls, path: str | os.PathLike[str]) -> Dataset:
        """Open the dataset at ``path`` (a directory or an fsspec URL). Errors name the path."""
        loc = Location.parse(path)
        if not loc.exists():
            raise DatasetNotFoundError(f"{loc.url}: no such file or directory")
        if not loc.exists(INFO_PATH):
            raise NotADatasetError(f"{loc.url}: not a univtac-data dataset (no {INFO_PATH})")
        info = read_info(loc)
        dataset = cls(loc, info, read_index(loc))
        dataset.index_found = loc.exists(INDEX_PATH)
        return dataset

    @property
    def episode_ids(self) -> list[str]:
        return sorted(self.index)

    def __len__(self) -> int:
        return len(self.index)

    def sensor(self, name: str) -> SensorProfile:
        if name in self.info.sensors:
            return self.info.sensors[name]
        return get_sensor(name)

    def _row(self, episode_id: str) -> IndexRow:
        try:
            return self.index[episode_id]
        except KeyError:
            raise DatasetError(f"{self.loc.url}: no episode {episode_id!r} in the index") from None

    def open_episode(self, episode_id: str) -> EpisodeHandle:
        """A lazy handle on one episode; close it (or use ``with``)."""
        return self.store.open(self.loc, self._row(episode_id).path)

    def load_episode(self, episode_id: str) -> Episode:
        with self.open_episode(episode_id) as handle:
            return handle.load()

    def episodes(self) -> Iterator[Episode]:
        for episode_id in self.episode_ids:
            yield self.load_episode(episode_id)

    def manifest(self) -> Manifest:
        return read_manifest(self.loc)

    def episode_files_on_disk(self) -> list[str]:
        """Names of the finished episode files (or Zarr groups) under ``episodes/``, indexed or not."""
        return [n for n in self.loc.listdir(EPISODES_DIR) if not n.startswith(TMP_PREFIX) and n.endswith(self.store.suffix)]

    def check_files(self) -> list[str]:
        """One line per indexed episode file that is missing, or whose size differs from the manifest (a cheap
        check from one directory listing: no file is opened or hashed; ``validate`` is the deep check)."""
        manifest = self.manifest()
        sizes: dict[str, int] = {}
        if self.loc.exists(EPISODES_DIR):
            prefix = self.loc.root.rstrip("/") + "/"
            for path, detail in self.loc.fs.find(self.loc.join(EPISODES_DIR), detail=True).items():
                sizes[path[len(prefix):] if path.startswith(prefix) else path.lstrip("/")] = int(detail["size"])
        by_episode: dict[str, list[str]] = {}
        for rel, entry in manifest.files.items():
            by_episode.setdefault(entry.episode_id, []).append(rel)
        problems = []
        for episode_id, row in sorted(self.index.items()):
            files = by_episode.get(episode_id)
            if not files:
                problems.append(f"{self.loc.url_of(row.path)}: indexed but not in the manifest")
                continue
            for rel in sorted(files):
                entry = manifest.files[rel]
                if rel not in sizes:
                    problems.append(f"{self.loc.url_of(rel)}: indexed but the file is missing")
                elif sizes[rel] != entry.bytes:
                    problems.append(f"{self.loc.url_of(rel)}: {sizes[rel]} bytes, the manifest says {entry.bytes} "
                                    f"(truncated or replaced)")
        return problems

    def verify_checksums(self, episode_ids: list[str] | None = None) -> list[str]:
        """One line per file whose SHA-256 or size differs from the manifest, or that is missing."""
        manifest = self.manifest()
        wanted = set(episode_ids if episode_ids is not None else self.index)
        problems = []
        for rel, entry in sorted(manifest.files.items()):
            if entry.episode_id not in wanted:
                continue
            if not self.loc.exists(rel):
                problems.append(f"{self.loc.url_of(rel)}: file is missing")
            elif self.loc.sha256(rel) != entry.sha256:
                problems.append(f"{self.loc.url_of(rel)}: SHA-256 differs from the manifest (file changed or damaged)")
        listed = {e.episode_id for e in manifest.files.values()}
        for episode_id in sorted(wanted - listed):
            problems.append(f"{self.loc.url_of(self._row(episode_id).path)}: not in the manifest")
        return problems


@dataclass
class ReindexReport:
    indexed: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)  # one line each: file and reason
    removed_temporaries: list[str] = field(default_factory=list)


class DatasetWriter:
    """Owns a dataset's ``meta/`` files while episodes are added. One writer per dataset, enforced by the
    dataset's ``DatasetLock`` (taken by ``open``, released by ``close`` or at process exit); workers may write
    episode files in parallel with ``write_episode_file`` and hand the results to ``commit``."""

    def __init__(self, loc: Location, info: DatasetInfo, *, read_existing: bool = True,
                 lock: DatasetLock | None = None) -> None:
        self.loc = loc
        self.info = info
        self.store = get_store(info.storage)
        self.lock = lock
        self.index = read_index(loc) if read_existing else {}
        self.manifest = read_manifest(loc) if read_existing else Manifest()
        self._dropped: set[str] = set()  # ids this writer removed on purpose (not merged back by ``commit``)
        self._index_seen = self._index_signature()

    @classmethod
    def open(cls, path: str | os.PathLike[str], storage: str = "hdf5", sensors: list[str] | None = None, *,
             recover: bool = True, lock: bool = True) -> DatasetWriter:
        """Create the dataset at ``path``, or reopen it to add episodes (resume). Reopening removes
        leftovers of killed writers and indexes finished episodes that missed the index (``recover``).

        ``lock``: take the dataset's writer lock first; a second writer (another process) is refused with
        ``DatasetLockedError`` naming the holder. Call ``close`` (or use ``with``) to release it early.
        """
        loc = Location.parse(path)
        get_store(storage)
        held = DatasetLock(loc).acquire() if lock else None
        try:
            info = cls._open_info(loc, storage, sensors)
            writer = cls(loc, info, lock=held)
            if recover:
                writer.recover()
        except BaseException:
            if held is not None:
                held.release()
            raise
        return writer

    @staticmethod
    def _open_info(loc: Location, storage: str, sensors: list[str] | None) -> DatasetInfo:
        if loc.exists(INFO_PATH):
            info = read_info(loc)
            if info.storage != storage:
                raise DatasetError(f"{loc.url}: holds a {info.storage} dataset, not {storage}")
            if parse_format_version(info.format_version)[0] != FORMAT_MAJOR:
                raise FormatVersionError(
                    f"{loc.url}: holds a format {info.format_version} dataset; this writer writes format "
                    f"{FORMAT_VERSION}; convert it first: univtac-data convert {loc.url} NEW_PATH --to {storage}")
        else:
            if loc.exists() and set(loc.listdir("")) - {LOCK_NAME}:
                raise NotADatasetError(f"{loc.url}: directory is not empty and holds no univtac-data dataset")
            loc.makedirs("meta")
            info = DatasetInfo(storage=storage, sensors={})  # type: ignore[arg-type]
        for name in sensors or []:
            info.sensors.setdefault(name, get_sensor(name))
        write_info(loc, info)
        return info

    def close(self) -> None:
        """Release the writer lock (the files are complete after every ``commit``)."""
        if self.lock is not None:
            self.lock.release()
            self.lock = None

    def __enter__(self) -> DatasetWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def has(self, episode_id: str) -> bool:
        return episode_id in self.index

    def add(self, episode: Episode) -> IndexRow:
        """Write one episode and commit it to the index."""
        written = write_episode_file(self.loc, self.info.storage, episode)
        self.commit([written])
        return written.row

    def commit(self, written: list[WrittenEpisode]) -> None:
        """Enter finished episode files in the manifest, then the index (in that order: the index never
        names an episode whose checksums are unknown)."""
        changed_sensors = False
        for item in written:
            self.manifest.files.update(item.files)
            self.index[item.row.episode_id] = item.row
            if item.row.sensor not in self.info.sensors:
                self.info.sensors[item.row.sensor] = get_sensor(item.row.sensor)
                changed_sensors = True
        if changed_sensors:
            write_info(self.loc, self.info)
        self._merge_others()
        write_manifest(self.loc, self.manifest)
        write_index(self.loc, list(self.index.values()))
        self._index_seen = self._index_signature()

    def _index_signature(self) -> tuple[int, int, int] | None:
        """Inode, size and mtime of the index file as this writer last saw it (local folders; None elsewhere).
        Every index write replaces the file, so another writer's write changes the inode."""
        if not self.loc.is_local:
            return None
        try:
            stat = os.stat(self.loc.join(INDEX_PATH))
        except FileNotFoundError:
            return None
        return stat.st_ino, stat.st_size, stat.st_mtime_ns

    def _merge_others(self) -> None:
        """Keep rows another writer committed since this one read the index (a writer that did not take the
        lock, or a ``reindex``): rewriting the index from memory alone would drop them."""
        if not self.loc.is_local or self._index_signature() == self._index_seen:
            return
        theirs, their_manifest = read_index(self.loc), read_manifest(self.loc)
        for episode_id, row in theirs.items():
            if episode_id not in self.index and episode_id not in self._dropped \
                    and self.loc.exists(row.path):
                self.index[episode_id] = row
                self.manifest.files.update({k: v for k, v in their_manifest.files.items()
                                            if v.episode_id == episode_id})

    def recover(self) -> ReindexReport:
        """Remove temporaries of killed writers; index complete episodes missing from the index."""
        report = ReindexReport()
        for name in self.loc.listdir(EPISODES_DIR):
            rel = f"{EPISODES_DIR}/{name}"
            if name.startswith(TMP_PREFIX):
                self.loc.remove(rel)
                report.removed_temporaries.append(rel)
        on_disk = self._episode_files()
        missing = {eid: rel for eid, rel in on_disk.items() if eid not in self.index}
        stale = {eid: row.path for eid, row in self.index.items() if eid not in on_disk}
        for episode_id, rel in stale.items():
            del self.index[episode_id]
            self._dropped.add(episode_id)
            report.skipped.append(f"{self.loc.url_of(rel)}: in the index but not on disk")
        if stale:
            self.manifest.files = {k: v for k, v in self.manifest.files.items() if v.episode_id not in stale}
        found = self._scan(missing, report)
        if found or stale or report.removed_temporaries:
            self.commit(found)
        return report

    @classmethod
    def reindex_dataset(cls, path: str | os.PathLike[str]) -> ReindexReport:
        """Rebuild the index and manifest of the dataset at ``path`` without reading the old ones (they may
        be the damaged part)."""
        loc = Location.parse(path)
        if not loc.exists():
            raise DatasetNotFoundError(f"{loc.url}: no such file or directory")
        if not loc.exists(INFO_PATH):
            raise NotADatasetError(f"{loc.url}: not a univtac-data dataset (no {INFO_PATH})")
        with DatasetLock(loc) as lock:
            return cls(loc, read_info(loc), read_existing=False, lock=lock).reindex()

    def reindex(self) -> ReindexReport:
        """Rebuild index and manifest from the episodes on disk, hashing every file."""
        self.index, self.manifest = {}, Manifest()
        report = ReindexReport()
        for name in self.loc.listdir(EPISODES_DIR):
            if name.startswith(TMP_PREFIX):
                self.loc.remove(f"{EPISODES_DIR}/{name}")
                report.removed_temporaries.append(f"{EPISODES_DIR}/{name}")
        found = self._scan(self._episode_files(), report)
        self._index_seen = self._index_signature()  # the rebuilt index replaces the old one: merge nothing
        self.commit(found)
        return report

    def _episode_files(self) -> dict[str, str]:
        out = {}
        for name in self.loc.listdir(EPISODES_DIR):
            if not name.startswith(TMP_PREFIX) and name.endswith(self.store.suffix):
                out[name[: -len(self.store.suffix)]] = f"{EPISODES_DIR}/{name}"
        return out

    def _scan(self, files: dict[str, str], report: ReindexReport) -> list[WrittenEpisode]:
        found = []
        for episode_id, rel in sorted(files.items()):
            try:
                with self.store.open(self.loc, rel) as handle:
                    if handle.meta.episode_id != episode_id:
                        raise CorruptFileError(f"{handle.where}: holds episode {handle.meta.episode_id!r}, "
                                               f"but its name says {episode_id!r}")
                    stamps = handle.read("timestamps_ns")
                    if stamps.shape != (handle.meta.n_frames,) or not np.issubdtype(stamps.dtype, np.integer):
                        raise CorruptFileError(f"{handle.where}: timestamps_ns does not match n_frames")
                    entries = _hash_files(self.loc, rel, rel, episode_id)
                    found.append(WrittenEpisode(index_row(episode_id, rel, handle, entries), entries))
                    report.indexed.append(episode_id)
            except DatasetError as error:
                report.skipped.append(str(error))
        return found
