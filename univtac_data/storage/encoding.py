"""Chunking and compression per codec class: one table, used by both backends and quoted in the spec.

Why these choices (the spec's 'Encoding' section says the same):

* images and depth are chunked one frame per chunk: a loader reads a single frame without decoding its
  neighbours (ManiSkill and LeRobot users trip over whole-trajectory chunks and video decoding);
* Blosc with Zstandard is lossless, fast to decode and available to HDF5 (hdf5plugin) and Zarr alike; level 1
  compresses residual images in half the time of level 3 for 7 to 14 % more bytes (benchmarks/codecs.py),
  and generation writes every frame once. LZ4 writes faster and decodes in 59 to 71 % of the time but makes
  residual images 1.7 to 2.2 times larger (spec/format.md, section 9). Writers take another level per episode
  (``write_episode_file(..., compression_level=)``): the generator writes elastic episodes at level 3, which
  brings GF225 elastic frames inside the size budget for about an eighth of their rate; decoding does not
  depend on the level;
* depth is integer micrometres, byte-shuffled like everything else: on generated frames (all 14 indenters,
  both contact models) that is about a third smaller, and faster to write and to read, than bit-shuffle
  (benchmarks/codecs.py);
* tactile images are stored as residuals (format 2.0): ``marked_rgb`` minus ``pure_rgb`` is zero away from
  the markers, and ``pure_rgb`` minus the episode's ``pure_ref_rgb`` is zero away from the contact, so the
  compressor sees mostly zeros. On generated frames an image pair takes a third of its plain bytes with the
  geometric contact model and two thirds with the elastic one, and less time to compress and to decompress
  (benchmarks/codecs.py); decoding adds one uint8 addition per image;
* Blosc blocks of 512 KiB instead of Blosc's automatic size (tens of KiB at level 1): Zstandard finds more
  of the long zero runs in larger blocks, and fewer blocks cost less (benchmarks/codecs.py compares
  automatic, 128 KiB and 512 KiB blocks; spec/format.md, section 9, quotes it); the block size is in each
  chunk's header, so readers need nothing new;
* every chunk carries a checksum (HDF5 Fletcher-32, Zarr CRC32C) so flipped bytes are found on read;
* Zarr shards group up to ``SHARD_FRAMES`` frames into one object: few files on object stores, while the
  chunk stays the unit of reading.
"""

from __future__ import annotations

from dataclasses import dataclass

from collections.abc import Iterator
from typing import Literal

import numpy as np

from univtac_data.episode import Episode
from univtac_data.schema.fields import FieldSpec, field_for_path

SHARD_FRAMES = 128
DENSE_CHUNK_FRAMES = 64
SMALL_CHUNK_FRAMES = 4096
ZSTD_LEVEL = 1  # Blosc compression level writers use unless told otherwise
ZSTD_LEVELS = range(1, 10)  # the levels a writer accepts (Blosc's 1..9; 0 would store uncompressed)
FRAME_BLOCK_BYTES = 1 << 19  # Blosc block size of one-frame chunks (0 elsewhere: Blosc chooses)
#: The attribute of an array stored as a residual: the path of the array it is a residual of.
RESIDUAL_ATTR = "residual_of"


@dataclass(frozen=True)
class Encoding:
    """How one array is laid out on disk."""

    chunks: tuple[int, ...]
    shards: tuple[int, ...] | None  # zarr only; None: no sharding
    blosc_cname: Literal["zstd", "lz4", "lz4hc", "blosclz", "zlib"]
    blosc_clevel: int
    shuffle: Literal["byte", "bit"]
    storage_dtype: str  # bool fields are stored as uint8 0/1
    blosc_blocksize: int = 0  # bytes; 0 lets Blosc choose
    frame_chunks: bool = False  # per-frame array chunked one frame per chunk (images, depth, masks)


def encoding_for(spec: FieldSpec, shape: tuple[int, ...], level: int = ZSTD_LEVEL) -> Encoding:
    """The encoding of an array of ``shape`` for field ``spec``, compressed at Blosc ``level``."""
    storage_dtype = "uint8" if spec.dtype == "bool" else spec.dtype
    if spec.sampling == "per_episode" or not shape:
        return Encoding(tuple(max(1, s) for s in shape), None, "zstd", level, "byte", storage_dtype)
    frames, rest = shape[0], tuple(shape[1:])
    if spec.codec in ("image", "depth"):
        chunk_t = 1
        shard_t = min(max(frames, 1), SHARD_FRAMES)
    elif spec.codec == "dense":
        chunk_t = min(max(frames, 1), DENSE_CHUNK_FRAMES)
        shard_t = chunk_t * max(1, SHARD_FRAMES // chunk_t) if frames > chunk_t else chunk_t
    else:
        chunk_t = min(max(frames, 1), SMALL_CHUNK_FRAMES)
        shard_t = None  # type: ignore[assignment]
    rest_chunks = tuple(max(1, s) for s in rest)
    shards = None if shard_t is None or shard_t == chunk_t else (shard_t, *rest_chunks)
    frame_chunks = spec.codec in ("image", "depth")
    return Encoding((chunk_t, *rest_chunks), shards, "zstd", level, "byte", storage_dtype,
                    FRAME_BLOCK_BYTES if frame_chunks else 0, frame_chunks)


@dataclass(frozen=True)
class EncodedArray:
    """One array of an episode as a writer stores it: the logical values in the storage dtype, the encoding,
    and the sibling array it is stored as a residual of (``None``: stored as is)."""

    path: str
    data: np.ndarray
    encoding: Encoding
    residual_of: str | None
    base: np.ndarray | None  # the values of ``residual_of``, in the storage dtype

    def stored(self, frame: int | None = None) -> np.ndarray:
        """What goes on disk: the whole array, or one frame of it; ``(data - base) mod 256`` for a residual."""
        data = self.data if frame is None else self.data[frame]
        if self.base is None:
            return data
        base = self.base if frame is None or self.base.ndim < self.data.ndim else self.base[frame]
        return np.subtract(data, base, dtype=data.dtype)  # unsigned: wraps modulo 2^bits, as the spec says


def residual_base_path(path: str, spec: FieldSpec) -> str | None:
    """The concrete sibling path that ``path`` (a concrete path of ``spec``) is a residual of, if any."""
    if spec.residual_of is None:
        return None
    return path.rsplit("/", 1)[0] + "/" + spec.residual_of.rsplit("/", 1)[1]


def encoded_arrays(episode: Episode, level: int = ZSTD_LEVEL) -> Iterator[EncodedArray]:
    """Each array of a checked episode, in path order, in its storage dtype, with its encoding at Blosc
    ``level``; image fields whose residual base the episode holds are marked as residuals of it."""
    for path in sorted(episode.arrays):
        spec = field_for_path(path)
        if spec is None:
            raise ValueError(f"episode {episode.meta.episode_id}: {path} is not a field of the format")
        array = episode.arrays[path]
        encoding = encoding_for(spec, array.shape, level)
        # numpy's bool is one byte, 0 or 1: stored as uint8 it is a view, not a copy of every mask of the episode
        data = (array.view(np.uint8) if array.dtype == np.bool_ and encoding.storage_dtype == "uint8"
                else array.astype(encoding.storage_dtype, copy=False))
        base_path = residual_base_path(path, spec)
        base = episode.arrays.get(base_path) if base_path is not None else None
        if base is None or not data.size:
            yield EncodedArray(path, data, encoding, None, None)
        else:
            yield EncodedArray(path, data, encoding, base_path, base.astype(encoding.storage_dtype, copy=False))
