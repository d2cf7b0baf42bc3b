"""Zarr v3 backend: one group per episode, sharded, usable on object stores through fsspec URLs."""

from __future__ import annotations

import json
from typing import Any, Literal

import numpy as np
import zarr
from zarr.codecs import BloscCodec, Crc32cCodec

from univtac_data.episode import Episode
from univtac_data.storage.backend import META_ATTR, VERSION_ATTR, EpisodeHandle, EpisodeStore, parse_episode_meta
from univtac_data.storage.encoding import RESIDUAL_ATTR, ZSTD_LEVEL, encoded_arrays
from univtac_data.storage.errors import CorruptFileError
from univtac_data.storage.fs import Location, fsync_tree


def _store(loc: Location, relpath: str, mode: str) -> Any:
    if loc.is_local:
        return zarr.storage.LocalStore(loc.url_of(relpath), read_only=(mode == "r"))
    return zarr.storage.FsspecStore.from_url(loc.url_of(relpath), read_only=(mode == "r"))


class ZarrHandle(EpisodeHandle):
    def __init__(self, loc: Location, relpath: str) -> None:
        super().__init__()
        self.loc, self.relpath = loc, relpath   # where the group's objects are (the loaders read shards directly)
        self.where = loc.url_of(relpath)
        try:
            self._group = zarr.open_group(_store(loc, relpath, "r"), mode="r", zarr_format=3)
            attrs = dict(self._group.attrs)
        except FileNotFoundError:
            raise CorruptFileError(f"{self.where}: episode group is missing or has no zarr.json") from None
        except Exception as error:
            raise CorruptFileError(f"{self.where}: not a readable Zarr v3 group ({type(error).__name__}: {error})") \
                from None
        if META_ATTR not in attrs:
            raise CorruptFileError(f"{self.where}: no '{META_ATTR}' attribute (not a univtac-data episode)")
        self.meta = parse_episode_meta(attrs[META_ATTR], self.where)
        self.version_attr = attrs.get(VERSION_ATTR)
        self._arrays: dict[str, Any] = {}

    def paths(self) -> list[str]:
        try:
            return sorted(name for name, node in self._group.members(max_depth=None) if isinstance(node, zarr.Array))
        except Exception as error:
            raise CorruptFileError(f"{self.where}: cannot list arrays ({type(error).__name__}: {error})") from None

    def _array(self, path: str) -> Any:
        array = self._arrays.get(path)
        if array is None:
            try:
                array = self._group[path]
            except (KeyError, FileNotFoundError):
                raise KeyError(path) from None
            if not isinstance(array, zarr.Array):
                raise KeyError(path)
            self._arrays[path] = array
        return array

    def zarr_array(self, path: str) -> Any:
        """The ``zarr.Array`` at ``path`` (``KeyError`` when absent)."""
        return self._array(path)

    def _layout_raw(self, path: str) -> tuple[tuple[int, ...], np.dtype]:
        array = self._array(path)
        return array.shape, np.dtype(array.dtype)

    def _read_raw(self, path: str, index: Any) -> np.ndarray:
        return np.asarray(self._array(path)[index])

    def _residual_of_raw(self, path: str) -> Any:
        return self._array(path).attrs.get(RESIDUAL_ATTR)

    def close(self) -> None:
        self._arrays.clear()


class ZarrStore(EpisodeStore):
    storage = "zarr"
    suffix = ".zarr"

    def write(self, episode: Episode, loc: Location, relpath: str, level: int = ZSTD_LEVEL) -> None:
        group = zarr.open_group(_store(loc, relpath, "w"), mode="w", zarr_format=3)
        # The metadata is JSON already; store it as an object so zarr tools show it readably.
        group.attrs.update({VERSION_ATTR: episode.meta.format_version,
                            META_ATTR: json.loads(episode.meta.model_dump_json())})
        for item in encoded_arrays(episode, level):
            data, enc = item.data, item.encoding
            shuffle: Literal["bitshuffle", "shuffle"] = "bitshuffle" if enc.shuffle == "bit" else "shuffle"
            target = group.create_array(
                name=item.path, shape=data.shape, dtype=data.dtype, chunks=enc.chunks,
                shards=enc.shards, compressors=[BloscCodec(cname=enc.blosc_cname, clevel=enc.blosc_clevel,
                                                           shuffle=shuffle, blocksize=enc.blosc_blocksize),
                                                Crc32cCodec()],
                fill_value=0, attributes={RESIDUAL_ATTR: item.residual_of} if item.residual_of else None,
            )
            if data.size:
                target[...] = item.stored()
        if loc.is_local:
            fsync_tree(loc.url_of(relpath))

    def open(self, loc: Location, relpath: str) -> ZarrHandle:
        return ZarrHandle(loc, relpath)
