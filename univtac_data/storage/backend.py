"""The storage interface: an episode store writes a whole episode and opens one for lazy reading."""

from __future__ import annotations

import json
from abc import ABC, abstractmethod
from typing import Any, TypeVar

import numpy as np
from pydantic import BaseModel, ValidationError

from univtac_data.episode import Episode
from univtac_data.schema.fields import field_for_path
from univtac_data.schema.models import EpisodeMeta
from univtac_data.storage.encoding import ZSTD_LEVEL
from univtac_data.storage.errors import CorruptFileError
from univtac_data.storage.fs import Location
from univtac_data.version import check_readable

META_ATTR = "univtac_meta"
VERSION_ATTR = "format_version"
MAX_RESIDUAL_DEPTH = 4  # 2.0 writers chain two (marked_rgb -> pure_rgb -> pure_ref_rgb)


def residual_chain_error(where: str, path: str) -> CorruptFileError:
    """The one-line error for a residual chain deeper than ``MAX_RESIDUAL_DEPTH`` (in practice a cycle), the
    same from every reader of ``path`` in file ``where``."""
    return CorruptFileError(f"{where}: {path} is a residual of a residual more than {MAX_RESIDUAL_DEPTH} deep "
                            f"(a cycle?)")


def _prune_unknown(model: type[BaseModel], data: Any) -> Any:
    """Drop keys a newer minor version added, so that this reader's models accept the rest."""
    if not isinstance(data, dict):
        return data
    out = {}
    for key, value in data.items():
        if key not in model.model_fields:
            continue
        annotation = model.model_fields[key].annotation
        if isinstance(annotation, type) and issubclass(annotation, BaseModel):
            value = _prune_unknown(annotation, value)
        out[key] = value
    return out


M = TypeVar("M", bound=BaseModel)


def parse_versioned(model: type[M], raw: Any, where: str, what: str) -> M:
    """A versioned JSON document (text or object) as ``model``: another major version is refused, keys a newer
    minor version added are dropped, anything else wrong is a ``CorruptFileError`` naming ``where``."""
    try:
        data = json.loads(raw) if isinstance(raw, (str, bytes)) else raw
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise CorruptFileError(f"{where}: {what} is not valid JSON ({error})") from None
    if not isinstance(data, dict) or "format_version" not in data:
        raise CorruptFileError(f"{where}: {what} has no format_version")
    if check_readable(str(data["format_version"]), where):
        data = _prune_unknown(model, data)
    try:
        return model.model_validate(data)
    except ValidationError as error:
        first = error.errors()[0]
        loc = ".".join(str(p) for p in first["loc"]) or "document"
        raise CorruptFileError(f"{where}: {what} field {loc}: {first['msg']}") from None


def parse_episode_meta(raw: Any, where: str) -> EpisodeMeta:
    """Episode metadata from its stored JSON (text or object); errors name ``where``."""
    return parse_versioned(EpisodeMeta, raw, where, "episode metadata")


class EpisodeHandle(ABC):
    """An open episode: metadata now, arrays on demand. Not picklable: open one per process."""

    meta: EpisodeMeta
    where: str
    version_attr: Any = None  # the file's (group's) own ``format_version`` attribute as stored; None when absent

    def __init__(self) -> None:
        self._residual_bases: dict[str, str | None] = {}  # path -> checked residual base (None: stored as is)
        self._episode_bases: dict[str, np.ndarray] = {}   # per-episode residual bases, read once
        # the last single frame read as a residual base: reading I_marked at frame t decodes I_pure at t,
        # which a reader usually asks for next (a sample holds both); through zarr a decode costs ~1.5 ms
        self._last_base_frame: tuple[str, int, np.ndarray] | None = None

    @abstractmethod
    def paths(self) -> list[str]:
        """Concrete array paths stored in the episode, sorted."""

    @abstractmethod
    def _read_raw(self, path: str, index: Any) -> np.ndarray: ...

    @abstractmethod
    def _layout_raw(self, path: str) -> tuple[tuple[int, ...], np.dtype]: ...

    @abstractmethod
    def _residual_of_raw(self, path: str) -> Any:
        """The array's ``residual_of`` attribute as stored, or None."""

    def residual_base(self, path: str) -> str | None:
        """The array ``path`` is stored as a residual of (its ``residual_of`` attribute), or None when it is
        stored as is. Checked: the base exists in this episode, is not itself, has the same unsigned integer
        dtype, and has the array's shape or its shape without the leading frame axis (a per-episode base).
        Raises ``KeyError`` when ``path`` is absent, ``CorruptFileError`` naming the file when the attribute
        is wrong."""
        cache = self._residual_bases
        if path in cache:
            return cache[path]
        shape, dtype = self.layout(path)
        try:
            raw = self._residual_of_raw(path)
        except KeyError:
            raise
        except Exception as error:
            raise CorruptFileError(f"{self.where}: cannot read the attributes of {path} "
                                   f"({type(error).__name__}: {error})") from None
        if raw is None:
            cache[path] = None
            return None
        base = raw.decode() if isinstance(raw, bytes) else raw
        what = f"{self.where}: {path} is stored as a residual of {base!r}"
        if not isinstance(base, str) or base == path:
            raise CorruptFileError(f"{what}, which is not another array of the episode")
        try:
            base_shape, base_dtype = self.layout(base)
        except KeyError:
            raise CorruptFileError(f"{what}, which is missing") from None
        if base_dtype != dtype or dtype.kind != "u":
            raise CorruptFileError(f"{what}, whose dtype {base_dtype} is not the array's unsigned {dtype}")
        if base_shape not in (shape, shape[1:]):
            raise CorruptFileError(f"{what}, whose shape {base_shape} is neither {shape} nor {shape[1:]}")
        cache[path] = base
        return base

    def layout(self, path: str) -> tuple[tuple[int, ...], np.dtype]:
        """``(shape, dtype)`` of ``path`` as stored, without reading its data (a bool field is stored as
        uint8). Raises ``KeyError`` when absent, ``CorruptFileError`` when its metadata cannot be read."""
        try:
            shape, dtype = self._layout_raw(path)
        except KeyError:
            raise
        except Exception as error:  # damaged object headers surface as many exception types
            raise CorruptFileError(f"{self.where}: cannot read the layout of {path} "
                                   f"({type(error).__name__}: {error})") from None
        return tuple(int(s) for s in shape), np.dtype(dtype)

    @abstractmethod
    def close(self) -> None: ...

    def read(self, path: str, index: Any = ()) -> np.ndarray:
        """Array ``path`` (or ``index`` of it: an int frame, a slice...) in its logical dtype, residuals
        added back.

        Raises ``CorruptFileError`` naming the file when the data cannot be decoded or fails its checksum.
        """
        array = self._read_stored(path, index, depth=0)
        spec = field_for_path(path)
        if spec is not None and spec.dtype == "bool":
            return array != 0
        return array

    def _read_stored(self, path: str, index: Any, depth: int) -> np.ndarray:
        """The values of ``path`` at ``index`` in the storage dtype: stored values plus, for a residual, the
        values of its base (itself possibly a residual, resolved first; modulo 2^bits)."""
        frame = int(index) if isinstance(index, (int, np.integer)) and not isinstance(index, bool) else None
        last = self._last_base_frame
        if frame is not None and last is not None and last[0] == path and last[1] == frame:
            return last[2].copy()  # a copy: the caller may write into what it gets
        array = self._decode_stored(path, index, depth)
        if frame is not None and depth > 0:  # read as a base: only the residual's addition sees this array
            self._last_base_frame = (path, frame, array)
        return array

    def _decode_stored(self, path: str, index: Any, depth: int) -> np.ndarray:
        try:
            base = self.residual_base(path)
            array = np.asarray(self._read_raw(path, index))
        except KeyError:
            raise CorruptFileError(f"{self.where}: field {path} is missing") from None
        except CorruptFileError:
            raise
        except Exception as error:  # h5py/zarr/blosc raise many types for damaged chunks
            raise CorruptFileError(f"{self.where}: cannot read {path} ({type(error).__name__}: {error})") from None
        if base is None:
            return array
        if depth >= MAX_RESIDUAL_DEPTH:
            raise residual_chain_error(self.where, path)
        shape, _ = self.layout(path)
        base_shape, _ = self.layout(base)
        if base_shape == shape:
            base_values = self._read_stored(base, index, depth + 1)
        else:  # a per-episode base: the same for every frame, read once per handle (one image per pad)
            kept = self._episode_bases
            whole = kept.get(base)
            if whole is None:
                whole = kept[base] = self._read_stored(base, (), depth + 1)
            base_values = np.broadcast_to(whole, shape)[index]
        if not array.flags.writeable:
            array = array.copy()
        np.add(array, base_values, out=array, casting="unsafe")  # unsigned: wraps modulo 2^bits
        return array

    def load(self) -> Episode:
        """Every array the format defines, read whole (paths a newer minor version added are skipped)."""
        arrays = {p: self.read(p) for p in self.paths() if field_for_path(p) is not None}
        return Episode(meta=self.meta, arrays=arrays)

    def __enter__(self) -> EpisodeHandle:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class EpisodeStore(ABC):
    """One storage backend. ``write`` produces a complete, durable episode at ``relpath`` (a temporary
    name chosen by the dataset writer); ``open`` reads one."""

    storage: str
    suffix: str

    @abstractmethod
    def write(self, episode: Episode, loc: Location, relpath: str, level: int = ZSTD_LEVEL) -> None:
        """Write ``episode`` at ``relpath``, compressed at Blosc ``level``."""

    @abstractmethod
    def open(self, loc: Location, relpath: str) -> EpisodeHandle: ...
