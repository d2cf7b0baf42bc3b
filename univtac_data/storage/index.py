"""The Parquet episode index (``meta/episodes.parquet``) and the SHA-256 manifest (``meta/manifest.json``).

Both are derived from the episodes on disk: ``reindex`` rebuilds them. Every index row carries its episode
id, and readers key by it; row order means nothing.
"""

from __future__ import annotations

import io
import json

import pyarrow as pa
import pyarrow.parquet as pq
from pydantic import ValidationError

from univtac_data.schema.models import IndexRow, Manifest
from univtac_data.storage.errors import CorruptFileError
from univtac_data.storage.fs import Location

INDEX_PATH = "meta/episodes.parquet"
MANIFEST_PATH = "meta/manifest.json"
INFO_PATH = "meta/info.json"

INDEX_SCHEMA = pa.schema([
    ("episode_id", pa.string()), ("path", pa.string()), ("format_version", pa.string()), ("kind", pa.string()),
    ("name", pa.string()), ("sensor", pa.string()), ("seed", pa.int64()), ("n_frames", pa.int64()),
    ("nominal_rate_hz", pa.float64()), ("duration_ns", pa.int64()), ("success", pa.bool_()),
    ("max_indentation_mm", pa.float64()), ("max_slip_mm", pa.float64()), ("bytes", pa.int64()),
    ("sha256", pa.string()),
])
assert INDEX_SCHEMA.names == list(IndexRow.model_fields), "index schema and IndexRow drifted"


def write_index(loc: Location, rows: list[IndexRow]) -> None:
    """Replace the index atomically; rows sorted by episode id for stable bytes."""
    ordered = sorted(rows, key=lambda r: r.episode_id)
    table = pa.Table.from_pylist([r.model_dump() for r in ordered], schema=INDEX_SCHEMA)
    sink = io.BytesIO()
    pq.write_table(table, sink, compression="zstd")
    loc.write_bytes_atomic(INDEX_PATH, sink.getvalue())


def read_index(loc: Location) -> dict[str, IndexRow]:
    """Episode id -> row. Raises ``CorruptFileError`` naming the file when it cannot be read."""
    where = loc.url_of(INDEX_PATH)
    if not loc.exists(INDEX_PATH):
        return {}
    try:
        # single-threaded: the index is small, and Arrow's thread pool, once started, can abort the process
        # at interpreter exit ("terminate called without an active exception", seen in CI-like runs)
        table = pq.read_table(io.BytesIO(loc.read_bytes(INDEX_PATH)), use_threads=False)
    except (pa.ArrowException, OSError) as error:
        raise CorruptFileError(f"{where}: not a readable Parquet file ({error}); run 'univtac-data reindex'") \
            from None
    missing = set(INDEX_SCHEMA.names) - set(table.column_names)
    if missing:
        raise CorruptFileError(f"{where}: index lacks columns {sorted(missing)}; run 'univtac-data reindex'")
    rows: dict[str, IndexRow] = {}
    for record in table.select(INDEX_SCHEMA.names).to_pylist():
        try:
            row = IndexRow.model_validate(record)
        except ValidationError as error:
            raise CorruptFileError(f"{where}: bad row {record.get('episode_id')!r} ({error.errors()[0]['msg']})") \
                from None
        if row.episode_id in rows:
            raise CorruptFileError(f"{where}: episode {row.episode_id} is listed twice")
        rows[row.episode_id] = row
    return rows


def write_manifest(loc: Location, manifest: Manifest) -> None:
    data = json.dumps(manifest.model_dump(mode="json"), indent=1, sort_keys=True).encode()
    loc.write_bytes_atomic(MANIFEST_PATH, data)


def read_manifest(loc: Location) -> Manifest:
    where = loc.url_of(MANIFEST_PATH)
    if not loc.exists(MANIFEST_PATH):
        return Manifest()
    try:
        return Manifest.model_validate_json(loc.read_bytes(MANIFEST_PATH))
    except ValidationError as error:
        raise CorruptFileError(f"{where}: not a valid manifest ({error.errors()[0]['msg']}); "
                               "run 'univtac-data reindex'") from None
