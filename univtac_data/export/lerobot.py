"""Export a univtac-data dataset as a LeRobot v3.0 dataset (``univtac-data export lerobot SRC DST``).

What is written (the layout of LeRobot's ``codebase_version`` v3.0)::

    DST/meta/info.json                          codebase_version, fps, features, totals, path templates
    DST/meta/stats.json                         per-feature min/max/mean/std/count and q01..q99 over all frames
    DST/meta/tasks.parquet                      one row per task string (index: the task, column task_index)
    DST/meta/episodes/chunk-000/file-000.parquet one row per episode: length, dataset_from/to_index, data and
                                                video file indices and time spans, per-episode stats, and the
                                                univtac-data episode id and metadata (for the way back)
    DST/data/chunk-XXX/file-XXX.parquet         one row per frame, many episodes per file (about 100 MB each)
    DST/videos/<key>/chunk-XXX/file-XXX.mp4     with --video: each image feature, episodes one after another

Without ``--video`` the images are PNG bytes inside the data Parquet (LeRobot's ``image`` dtype). The
export is written into a temporary folder beside DST and renamed at the end: a killed export leaves no DST.
"""

from __future__ import annotations

import io
import json
import math
import os
import shutil
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from univtac_data.export.lerobot_features import ROBOT_TYPE, Feature, check_same_layout, lerobot_features
from univtac_data.export.video import Mp4Writer, require_av
from univtac_data.storage import Dataset
from univtac_data.storage.errors import DatasetError

CODEBASE_VERSION = "v3.0"
CHUNKS_SIZE = 1000          # files per chunk folder (LeRobot's default)
DATA_FILE_MB = 100          # a data file is closed once it passes this size (LeRobot's default)
VIDEO_FILE_MB = 200
QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)
FILE_PATTERN = "chunk-{chunk_index:03d}/file-{file_index:03d}"
DATA_PATH = "data/" + FILE_PATTERN + ".parquet"
VIDEO_PATH = "videos/{video_key}/" + FILE_PATTERN + ".mp4"
EPISODES_PATH = "meta/episodes/" + FILE_PATTERN + ".parquet"


def task_text(kind: str, name: str) -> str:
    """The LeRobot task string of an episode (LeRobot conditions language policies on it)."""
    return f"press the {name} indenter into both tactile pads" if kind == "indenter" else name.replace("_", " ")


def frame_stride(rate_hz: float, fps: int | None, where: str) -> tuple[int, int]:
    """``(fps, stride)``: LeRobot needs an integer frame rate; ``--fps`` keeps every ``stride``-th frame."""
    if fps is None:
        if abs(rate_hz - round(rate_hz)) > 1e-9:
            raise DatasetError(f"{where}: recorded at {rate_hz} Hz, not an integer rate; pass --fps with a rate "
                               "that divides it")
        return int(round(rate_hz)), 1
    if fps <= 0:
        raise DatasetError(f"--fps must be a positive integer (got {fps})")
    stride = rate_hz / fps
    if abs(stride - round(stride)) > 1e-9 or round(stride) < 1:
        raise DatasetError(f"{where}: --fps {fps} does not divide the recorded rate {rate_hz} Hz")
    return fps, int(round(stride))


def feature_stats(values: np.ndarray, feature: Feature) -> dict[str, np.ndarray]:
    """LeRobot's per-feature statistics of one episode's ``values`` (frames first).

    Images: per channel, scaled to [0, 1], shape (3, 1, 1), as LeRobot computes them. Depth maps: one number
    each (shape (1, 1), broadcasting over the map) rather than per pixel. Everything else: per element.
    """
    x = values.astype(np.float64)
    if feature.visual:
        x = x.reshape(-1, 3) / 255.0
        shape: tuple[int, ...] = (3, 1, 1)
    elif feature.key.endswith(".depth_um") or feature.key.startswith("observation.depth."):
        x = x.reshape(-1, 1)
        shape = (1, 1)
    else:
        x = x.reshape(len(x), -1)
        shape = feature.shape
    out = {"min": x.min(0), "max": x.max(0), "mean": x.mean(0), "std": x.std(0)}
    out.update({f"q{round(q * 100):02d}": np.quantile(x, q, axis=0) for q in QUANTILES})
    stats = {k: v.reshape(shape) for k, v in out.items()}
    stats["count"] = np.array([len(values)])
    return stats


def merge_stats(parts: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """Dataset statistics from per-episode ones: exact min, max, mean and std; quantiles as the
    count-weighted mean of the episodes' quantiles (what LeRobot's ``aggregate_stats`` does)."""
    counts = np.array([p["count"][0] for p in parts], np.float64)
    weights = (counts / counts.sum()).reshape((-1,) + (1,) * parts[0]["mean"].ndim)
    means = np.stack([p["mean"] for p in parts])
    mean = (weights * means).sum(0)
    var = (weights * (np.stack([p["std"] for p in parts]) ** 2 + (means - mean) ** 2)).sum(0)
    out = {"min": np.min([p["min"] for p in parts], 0), "max": np.max([p["max"] for p in parts], 0),
           "mean": mean, "std": np.sqrt(var), "count": np.array([int(counts.sum())])}
    for key in parts[0]:
        if key.startswith("q"):
            out[key] = (weights * np.stack([p[key] for p in parts])).sum(0)
    return out


def _hf_feature(feature: Feature) -> dict[str, Any]:
    """The feature as Hugging Face ``datasets`` describes it in a Parquet schema (what LeRobot reads)."""
    if feature.dtype == "image":
        return {"_type": "Image"}
    if feature.shape == (1,):
        return {"dtype": feature.dtype, "_type": "Value"}
    if len(feature.shape) == 1:
        return {"feature": {"dtype": feature.dtype, "_type": "Value"}, "length": feature.shape[0], "_type": "List"}
    return {"shape": list(feature.shape), "dtype": feature.dtype, "_type": f"Array{len(feature.shape)}D"}


def _png(rgb: np.ndarray) -> bytes:
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(rgb).save(buffer, format="PNG", compress_level=1)
    return buffer.getvalue()


def _column(values: np.ndarray, feature: Feature) -> pa.Array:
    """Frames of one feature as an Arrow column of the type ``_hf_feature`` declares."""
    if feature.dtype == "image":
        return pa.StructArray.from_arrays(
            [pa.array([_png(v) for v in values], pa.binary()), pa.array([None] * len(values), pa.string())],
            names=["bytes", "path"])
    flat = pa.array(np.ascontiguousarray(values).reshape(-1))
    if feature.shape == (1,):
        return flat
    if len(feature.shape) == 1:
        return pa.FixedSizeListArray.from_arrays(flat, feature.shape[0])
    # datasets' ArrayND storage: nested variable-size lists
    column = flat
    for size in reversed(feature.shape):
        count = len(column) // size
        column = pa.ListArray.from_arrays(pa.array(np.arange(count + 1, dtype=np.int32) * size), column)
    return column


@dataclass
class _RollingFiles:
    """Numbered files of one kind (``chunk-XXX/file-XXX``); a new file starts past ``limit_mb``."""

    root: Path
    pattern: str
    limit_mb: int
    chunk_index: int = 0
    file_index: int = 0
    started: bool = False

    def path(self) -> Path:
        return self.root / self.pattern.format(chunk_index=self.chunk_index, file_index=self.file_index)

    def next_needed(self) -> bool:
        return self.started and self.path().stat().st_size > self.limit_mb * 1e6

    def advance(self) -> None:
        self.file_index += 1
        if self.file_index == CHUNKS_SIZE:
            self.chunk_index, self.file_index = self.chunk_index + 1, 0


@dataclass
class ExportReport:
    """What an export wrote."""

    dst: str
    episodes: int
    frames: int
    fps: int
    video: bool
    features: list[str] = field(default_factory=list)


class _LeRobotWriter:
    """Owns the temporary export folder while episodes are appended; ``finish`` writes ``meta/``."""

    def __init__(self, tmp: Path, features: list[Feature], fps: int, video: bool) -> None:
        self.tmp, self.features, self.fps, self.video = tmp, features, fps, video
        self.data_files = _RollingFiles(tmp, DATA_PATH, DATA_FILE_MB)
        self.video_files = {f.key: _RollingFiles(tmp, VIDEO_PATH.replace("{video_key}", f.key), VIDEO_FILE_MB)
                            for f in features if f.dtype == "video"}
        self.videos: dict[str, Mp4Writer] = {}
        self.video_frames: dict[str, int] = {}
        self.video_info: dict[str, dict[str, Any]] = {}
        self.tasks: dict[str, int] = {}
        self.episode_rows: list[dict[str, Any]] = []
        self.episode_stats: list[dict[str, dict[str, np.ndarray]]] = []
        self.total_frames = 0
        self.table_features = [f for f in features if f.dtype != "video"]
        hf = {f.key: _hf_feature(f) for f in self.table_features}
        for name, dtype in (("timestamp", "float32"), ("frame_index", "int64"), ("episode_index", "int64"),
                            ("index", "int64"), ("task_index", "int64")):
            hf[name] = {"dtype": dtype, "_type": "Value"}
        self.schema_metadata = {b"huggingface": json.dumps({"info": {"features": hf}}).encode()}
        self.parquet: pq.ParquetWriter | None = None

    def _data_writer(self, table: pa.Table) -> pq.ParquetWriter:
        files = self.data_files
        if self.parquet is not None and files.next_needed():
            self.parquet.close()
            self.parquet = None
            files.advance()
        if self.parquet is None:
            files.path().parent.mkdir(parents=True, exist_ok=True)
            self.parquet = pq.ParquetWriter(files.path(), table.schema, compression="zstd")
            files.started = True
        return self.parquet

    def _append_video(self, key: str, frames: np.ndarray) -> dict[str, Any]:
        files = self.video_files[key]
        writer = self.videos.get(key)
        if writer is not None and files.next_needed():
            writer.close()
            writer = None
            files.advance()
        if writer is None:
            files.path().parent.mkdir(parents=True, exist_ok=True)
            writer = self.videos[key] = Mp4Writer(str(files.path()), frames.shape[2], frames.shape[1], self.fps)
            files.started = True
        start = writer.frames_written
        for frame in frames:
            writer.write(frame)
        return {f"videos/{key}/chunk_index": files.chunk_index, f"videos/{key}/file_index": files.file_index,
                f"videos/{key}/from_timestamp": start / self.fps,
                f"videos/{key}/to_timestamp": writer.frames_written / self.fps}

    def add(self, values: dict[str, np.ndarray], task: str, extra: dict[str, Any]) -> None:
        """One episode: ``values`` maps each feature key to its (frames, *shape) array."""
        episode_index = len(self.episode_rows)
        n = len(next(iter(values.values())))
        task_index = self.tasks.setdefault(task, len(self.tasks))
        columns = {f.key: _column(values[f.key], f) for f in self.table_features}
        columns["timestamp"] = pa.array((np.arange(n) / self.fps).astype(np.float32))
        columns["frame_index"] = pa.array(np.arange(n, dtype=np.int64))
        columns["episode_index"] = pa.array(np.full(n, episode_index, np.int64))
        columns["index"] = pa.array(np.arange(self.total_frames, self.total_frames + n, dtype=np.int64))
        columns["task_index"] = pa.array(np.full(n, task_index, np.int64))
        table = pa.table(columns).replace_schema_metadata(self.schema_metadata)
        writer = self._data_writer(table)
        writer.write_table(table)
        row: dict[str, Any] = {
            "episode_index": episode_index, "tasks": [task], "length": n,
            "data/chunk_index": self.data_files.chunk_index, "data/file_index": self.data_files.file_index,
            "dataset_from_index": self.total_frames, "dataset_to_index": self.total_frames + n,
        }
        for f in self.features:
            if f.dtype == "video":
                row.update(self._append_video(f.key, values[f.key]))
        row.update({"meta/episodes/chunk_index": 0, "meta/episodes/file_index": 0})
        stats = {f.key: feature_stats(values[f.key], f) for f in self.features}
        for key, name, dtype in (("timestamp", "timestamp", np.float32), ("frame_index", "frame_index", np.int64),
                                 ("episode_index", "episode_index", np.int64), ("index", "index", np.int64),
                                 ("task_index", "task_index", np.int64)):
            column = columns[name].to_numpy().astype(dtype)[:, None]
            stats[key] = feature_stats(column, Feature(key, str(np.dtype(dtype)), (1,), None, ()))
        for key, s in stats.items():
            for name, value in s.items():
                row[f"stats/{key}/{name}"] = value.reshape(-1).tolist()
        row.update(extra)
        self.episode_rows.append(row)
        self.episode_stats.append(stats)
        self.total_frames += n

    def finish(self, dataset_info: dict[str, Any]) -> None:
        if self.parquet is not None:
            self.parquet.close()
        for key, writer in self.videos.items():
            writer.close()
        meta = self.tmp / "meta"
        (meta / "episodes/chunk-000").mkdir(parents=True, exist_ok=True)
        pq.write_table(pa.Table.from_pylist(self.episode_rows), self.tmp / EPISODES_PATH.format(
            chunk_index=0, file_index=0), compression="zstd")
        tasks = pa.table({"task_index": pa.array(list(self.tasks.values()), pa.int64()),
                          "__index_level_0__": pa.array(list(self.tasks), pa.string())})
        pandas_meta = {"index_columns": ["__index_level_0__"], "column_indexes": [], "columns": [
            {"name": "task_index", "field_name": "task_index", "pandas_type": "int64", "numpy_type": "int64",
             "metadata": None},
            {"name": None, "field_name": "__index_level_0__", "pandas_type": "unicode", "numpy_type": "object",
             "metadata": None}], "creator": {"library": "pyarrow", "version": pa.__version__},
            "pandas_version": "2.2.0"}
        pq.write_table(tasks.replace_schema_metadata({b"pandas": json.dumps(pandas_meta).encode()}),
                       meta / "tasks.parquet")
        stats = {key: {k: v.tolist() for k, v in merge_stats([s[key] for s in self.episode_stats]).items()}
                 for key in self.episode_stats[0]}
        (meta / "stats.json").write_text(json.dumps(stats, indent=2))
        features: dict[str, Any] = {}
        for f in self.features:
            features[f.key] = f.info()
            if f.dtype == "video":
                features[f.key]["info"] = self.video_info_of(f)
        for name, dtype in (("timestamp", "float32"), ("frame_index", "int64"), ("episode_index", "int64"),
                            ("index", "int64"), ("task_index", "int64")):
            features[name] = {"dtype": dtype, "shape": [1], "names": None}
        info = {
            "codebase_version": CODEBASE_VERSION, "robot_type": ROBOT_TYPE,
            "total_episodes": len(self.episode_rows), "total_frames": self.total_frames,
            "total_tasks": len(self.tasks), "chunks_size": CHUNKS_SIZE, "data_files_size_in_mb": DATA_FILE_MB,
            "video_files_size_in_mb": VIDEO_FILE_MB, "fps": self.fps,
            "splits": {"train": f"0:{len(self.episode_rows)}"}, "data_path": DATA_PATH,
            "video_path": VIDEO_PATH if self.video else None, "features": features, **dataset_info,
        }
        (meta / "info.json").write_text(json.dumps(info, indent=4))

    def video_info_of(self, feature: Feature) -> dict[str, Any]:
        from univtac_data.export.video import CODEC, PIX_FMT

        return {"video.height": feature.shape[0], "video.width": feature.shape[1],
                "video.codec": "h264" if CODEC == "libx264" else CODEC, "video.pix_fmt": PIX_FMT,
                "video.is_depth_map": False, "video.fps": self.fps, "video.channels": 3, "has_audio": False}


def _feature_values(handle: Any, feature: Feature, stride: int) -> np.ndarray:
    parts = [handle.read(src)[::stride] for src in feature.sources]
    parts = [p.reshape(len(p), 1) if p.ndim == 1 else p for p in parts]
    values = np.concatenate(parts, axis=-1) if len(parts) > 1 else parts[0]
    return values.astype(feature.dtype, copy=False) if not feature.visual else values


def export_lerobot(src: str, dst: str | os.PathLike[str], *, fps: int | None = None, video: bool = False,
                   episode_ids: list[str] | None = None,
                   progress: Callable[[int, int, str], None] | None = None) -> ExportReport:
    """Write the episodes of the dataset at ``src`` as a LeRobot v3.0 dataset at the new local folder ``dst``.

    ``fps``: the exported frame rate (default the recorded one; it must divide it). ``video``: images as MP4
    (H.264) instead of PNG inside the Parquet. Raises ``DatasetError`` (one line) on bad input; DST is
    created only when everything is written.
    """
    if video:
        require_av()
    source = Dataset.open(src)
    ids = list(episode_ids) if episode_ids is not None else source.episode_ids
    if not ids:
        raise DatasetError(f"{src}: the dataset has no episodes to export")
    target = Path(dst).absolute()
    if target.exists() and (not target.is_dir() or any(target.iterdir())):
        raise DatasetError(f"{target}: already exists and is not empty; export into a new folder")
    if not target.parent.is_dir():
        raise DatasetError(f"{target.parent}: no such folder (the parent of the export)")
    if not os.access(target.parent, os.W_OK):
        raise DatasetError(f"{target.parent}: not writable")
    tmp = target.parent / f".tmp-{target.name}-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    try:
        report = _export_into(source, ids, tmp, fps, video, progress)
        if target.exists():
            target.rmdir()  # empty, checked above
        os.replace(tmp, target)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    report.dst = str(target)
    return report


def _export_into(source: Dataset, ids: list[str], tmp: Path, fps: int | None, video: bool,
                 progress: Callable[[int, int, str], None] | None) -> ExportReport:
    writer: _LeRobotWriter | None = None
    first = None
    out_fps = 0
    for k, episode_id in enumerate(ids):
        with source.open_episode(episode_id) as handle:
            meta = handle.meta
            where = handle.where
            if first is None:
                first = meta
                out_fps, stride = frame_stride(meta.nominal_rate_hz, fps, where)
                features = lerobot_features(meta, source.sensor(meta.sensor), "video" if video else "image")
                writer = _LeRobotWriter(tmp, features, out_fps, video)
            else:
                try:
                    check_same_layout(first, meta, where)
                except ValueError as error:
                    raise DatasetError(str(error)) from None
                if abs(meta.nominal_rate_hz - first.nominal_rate_hz) > 1e-9:
                    raise DatasetError(f"{where}: recorded at {meta.nominal_rate_hz} Hz but episode "
                                       f"{first.episode_id} at {first.nominal_rate_hz} Hz; export them separately")
            assert writer is not None
            values = {f.key: _feature_values(handle, f, stride) for f in writer.features}
            markers_ref = {pad: handle.read(f"tactile/{pad}/markers_ref_px").reshape(-1).tolist()
                           for pad in meta.pads}
        extra = {"univtac/episode_id": episode_id, "univtac/meta": meta.model_dump_json(),
                 "univtac/frame_stride": stride,
                 **{f"univtac/tactile/{pad}/markers_ref_px": ref for pad, ref in markers_ref.items()}}
        writer.add(values, task_text(meta.kind, meta.name), extra)
        if progress is not None:
            progress(k + 1, len(ids), episode_id)
    assert writer is not None and first is not None
    sensor = source.sensor(first.sensor)
    writer.finish({"univtac": {"source": source.loc.url, "format_version": first.format_version,
                               "sensor": sensor.model_dump(mode="json"), "recorded_rate_hz": first.nominal_rate_hz,
                               "primitive_names": first.primitive_names}})
    return ExportReport(dst="", episodes=len(ids), frames=writer.total_frames, fps=out_fps, video=video,
                        features=[f.key for f in writer.features])


def print_progress(done: int, total: int, episode_id: str) -> None:
    """Plain progress lines (the export runs in CI logs and batch jobs as often as in a terminal)."""
    if done == total or done % max(1, math.ceil(total / 20)) == 0:
        print(f"exported {done}/{total} episodes (last: {episode_id})", file=sys.stderr, flush=True)
