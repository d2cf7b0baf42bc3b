"""Storage: one writer and one reader interface over two backends (HDF5, Zarr v3)."""

from univtac_data.storage.backend import EpisodeHandle, EpisodeStore
from univtac_data.storage.dataset import (
    STORES,
    Dataset,
    DatasetWriter,
    ReindexReport,
    WrittenEpisode,
    discard_staged,
    publish_staged,
    write_episode_file,
)
from univtac_data.storage.errors import (
    CorruptFileError,
    DatasetError,
    DatasetNotFoundError,
    EpisodeExistsError,
    FormatVersionError,
    NotADatasetError,
)
from univtac_data.storage.fs import Location
from univtac_data.storage.lock import DatasetLock, DatasetLockedError, LockHolder

__all__ = [
    "STORES", "CorruptFileError", "Dataset", "DatasetError", "DatasetLock", "DatasetLockedError", "DatasetNotFoundError",
    "DatasetWriter", "LockHolder",
    "EpisodeExistsError", "EpisodeHandle", "EpisodeStore", "FormatVersionError", "Location", "NotADatasetError",
    "ReindexReport", "WrittenEpisode", "discard_staged", "publish_staged", "write_episode_file",
]
