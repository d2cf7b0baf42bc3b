"""HDF5 backend: one file per episode (the ACT / RoboTwin / UniVTAC convention), local paths only."""

from __future__ import annotations

import os
from typing import Any

import h5py
import hdf5plugin
import numpy as np
from numcodecs import blosc as numcodecs_blosc
from numcodecs.fletcher32 import Fletcher32

from univtac_data.episode import Episode, meta_json
from univtac_data.storage.backend import META_ATTR, VERSION_ATTR, EpisodeHandle, EpisodeStore, parse_episode_meta
from univtac_data.storage.encoding import RESIDUAL_ATTR, ZSTD_LEVEL, EncodedArray, Encoding, encoded_arrays
from univtac_data.storage.errors import CorruptFileError, DatasetError
from univtac_data.storage.fs import Location, fsync_tree


_FLETCHER32 = Fletcher32()


def _blosc(enc: Encoding) -> hdf5plugin.Blosc:
    mode = hdf5plugin.Blosc.BITSHUFFLE if enc.shuffle == "bit" else hdf5plugin.Blosc.SHUFFLE
    return hdf5plugin.Blosc(cname=enc.blosc_cname, clevel=enc.blosc_clevel, shuffle=mode)


def write_frame_chunks(dataset: h5py.Dataset, item: EncodedArray) -> None:
    """Write a one-frame-per-chunk array chunk by chunk, each exactly as HDF5's pipeline would store it
    (Blosc, then Fletcher-32), so that any HDF5 reader decodes it. Encoding here rather than in the pipeline
    sets Blosc's block size and makes a residual one frame at a time, not as a whole-episode copy."""
    enc = item.encoding
    shuffle = numcodecs_blosc.BITSHUFFLE if enc.shuffle == "bit" else numcodecs_blosc.SHUFFLE
    zeros = (0,) * (item.data.ndim - 1)
    for frame in range(item.data.shape[0]):
        stream = numcodecs_blosc.compress(np.ascontiguousarray(item.stored(frame)), enc.blosc_cname.encode(),
                                          enc.blosc_clevel, shuffle, enc.blosc_blocksize)
        dataset.id.write_direct_chunk((frame, *zeros), _FLETCHER32.encode(stream))


class HDF5Handle(EpisodeHandle):
    def __init__(self, path: str, where: str) -> None:
        super().__init__()
        self.where = where
        try:
            self._file = h5py.File(path, "r", locking=False)
        except FileNotFoundError:
            raise CorruptFileError(f"{where}: file is missing") from None
        except OSError as error:
            raise CorruptFileError(f"{where}: not a readable HDF5 file ({_first_line(error)})") from None
        try:
            raw = self._file.attrs[META_ATTR]
        except Exception:
            self._file.close()
            raise CorruptFileError(f"{where}: no '{META_ATTR}' attribute (not a univtac-data episode)") from None
        try:
            self.meta = parse_episode_meta(raw, where)
        except Exception:
            self._file.close()
            raise
        version = self._file.attrs.get(VERSION_ATTR)
        self.version_attr = version.decode() if isinstance(version, bytes) else version
        self._datasets: dict[str, h5py.Dataset] = {}  # path lookups cost more than a small frame read

    def paths(self) -> list[str]:
        found: list[str] = []
        try:
            self._file.visititems(lambda name, obj: found.append(name) if isinstance(obj, h5py.Dataset) else None)
        except (RuntimeError, OSError, KeyError) as error:  # a damaged object header stops the walk
            raise CorruptFileError(f"{self.where}: cannot list arrays ({type(error).__name__}: {error})") from None
        return sorted(found)

    def _layout_raw(self, path: str) -> tuple[tuple[int, ...], np.dtype]:
        dataset = self._dataset(path)
        return dataset.shape, dataset.dtype

    def _read_raw(self, path: str, index: Any) -> np.ndarray:
        return self._dataset(path)[index]

    def _residual_of_raw(self, path: str) -> Any:
        return self._dataset(path).attrs.get(RESIDUAL_ATTR)

    def h5py_dataset(self, path: str) -> h5py.Dataset:
        """The open ``h5py.Dataset`` of an array path (cached), for readers that decode chunks themselves
        (``univtac_data.loaders`` reads image chunks straight into batch buffers). Raises ``KeyError`` when
        the path is not an array of this episode."""
        return self._dataset(path)

    def file_stat(self) -> os.stat_result | None:
        """``fstat`` of the file HDF5 has open (``None`` when HDF5 does not open it as a plain local file):
        which version of the file the handle reads, for readers that keep what they learnt from it."""
        if self._file.driver != "sec2":
            return None
        try:
            return os.fstat(int(self._file.id.get_vfd_handle()))
        except (OSError, ValueError, RuntimeError):
            return None

    def _dataset(self, path: str) -> h5py.Dataset:
        dataset = self._datasets.get(path)
        if dataset is None:
            dataset = self._file[path]  # KeyError when missing: read() turns it into CorruptFileError
            if not isinstance(dataset, h5py.Dataset):
                raise KeyError(path)
            self._datasets[path] = dataset
        return dataset

    def close(self) -> None:
        self._datasets.clear()
        self._file.close()


def _first_line(error: BaseException) -> str:
    return str(error).splitlines()[0] if str(error) else type(error).__name__


class HDF5Store(EpisodeStore):
    storage = "hdf5"
    suffix = ".h5"

    def write(self, episode: Episode, loc: Location, relpath: str, level: int = ZSTD_LEVEL) -> None:
        if not loc.is_local:
            raise DatasetError(f"{loc.url}: HDF5 datasets need a local path; use --format zarr for URLs")
        path = os.path.join(loc.root, relpath)
        # track_times=False and a fixed libver keep the bytes a function of the content: same seed, same file.
        threads = numcodecs_blosc.use_threads
        numcodecs_blosc.use_threads = False  # one core per writer: the generator runs a writer per core
        try:
            with h5py.File(path, "w", libver=("v110", "v110"), track_order=True) as handle:
                handle.attrs[VERSION_ATTR] = episode.meta.format_version
                handle.attrs[META_ATTR] = meta_json(episode.meta)
                for item in encoded_arrays(episode, level):
                    data, enc = item.data, item.encoding
                    per_frame_chunks = bool(data.size) and enc.frame_chunks
                    dataset = handle.create_dataset(
                        item.path, shape=data.shape, dtype=data.dtype,
                        data=None if per_frame_chunks else item.stored(), chunks=enc.chunks if data.size else None,
                        fletcher32=bool(data.size), track_times=False, **(_blosc(enc) if data.size else {}),
                    )
                    if item.residual_of is not None:
                        dataset.attrs[RESIDUAL_ATTR] = item.residual_of
                    if per_frame_chunks:
                        write_frame_chunks(dataset, item)
                handle.flush()
        finally:
            numcodecs_blosc.use_threads = threads
        fsync_tree(path)

    def open(self, loc: Location, relpath: str) -> HDF5Handle:
        return HDF5Handle(os.path.join(loc.root, relpath), where=loc.url_of(relpath))
