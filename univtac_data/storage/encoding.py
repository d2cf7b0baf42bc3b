"""Chunking and compression per codec class: one table, used by both backends and quoted in the spec.

Why these choices (the spec's 'Encoding' section says the same):

* images and depth are chunked one frame per chunk: a loader reads a single frame without decoding its
  neighbours (ManiSkill and LeRobot users trip over whole-trajectory chunks and video decoding);
* Blosc with Zstandard is lossless, fast to decode and available to HDF5 (hdf5plugin) and Zarr alike; level 1
  compresses in half the time of level 3 for about 15 % more bytes (benchmarks/codecs.py), and generation
  writes every frame once. LZ4 would halve both write and decode time but makes images 45 % larger, which
  pushes elastic-contact frames over the size budget (spec/format.md, section 9);
* depth is integer micrometres, byte-shuffled like everything else: on generated frames (all 14 indenters,
  both contact models) that is a quarter smaller, and faster to write and to read, than the bit-shuffle the
  first release used (benchmarks/codecs.py);
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
ZSTD_LEVEL = 1


@dataclass(frozen=True)
class Encoding:
    """How one array is laid out on disk."""

    chunks: tuple[int, ...]
    shards: tuple[int, ...] | None  # zarr only; None: no sharding
    blosc_cname: Literal["zstd", "lz4", "lz4hc", "blosclz", "zlib"]
    blosc_clevel: int
    shuffle: Literal["byte", "bit"]
    storage_dtype: str  # bool fields are stored as uint8 0/1


def encoding_for(spec: FieldSpec, shape: tuple[int, ...]) -> Encoding:
    """The encoding of an array of ``shape`` for field ``spec``."""
    storage_dtype = "uint8" if spec.dtype == "bool" else spec.dtype
    if spec.sampling == "per_episode" or not shape:
        return Encoding(tuple(max(1, s) for s in shape), None, "zstd", ZSTD_LEVEL, "byte", storage_dtype)
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
    return Encoding((chunk_t, *rest_chunks), shards, "zstd", ZSTD_LEVEL, "byte", storage_dtype)


def encoded_arrays(episode: Episode) -> Iterator[tuple[str, np.ndarray, Encoding]]:
    """Each array of a checked episode, in path order, in its storage dtype, with its encoding."""
    for path in sorted(episode.arrays):
        spec = field_for_path(path)
        if spec is None:
            raise ValueError(f"episode {episode.meta.episode_id}: {path} is not a field of the format")
        array = episode.arrays[path]
        encoding = encoding_for(spec, array.shape)
        yield path, array.astype(encoding.storage_dtype, copy=False), encoding
