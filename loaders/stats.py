"""Normalisation statistics of actions and low-dimensional states, computed once per dataset and saved.

The file is ``meta/stats.json`` inside the dataset, written atomically. It records the SHA-256 digest of
every episode it was computed from (the index's ``sha256`` column); when the index no longer matches
(episodes added, removed or rewritten) the statistics are stale and are recomputed and saved again.
Statistics cover every episode of the dataset, whatever split a loader uses (as LeRobot does): the
validation episodes shift mean and std by a fraction of a percent, and one file serves every split.

Which arrays: every per-frame floating-point field of the ``small`` codec class (``robot/action``,
``robot/ee_pose``, ``robot/gripper_width_m``, ``robot/finger_pos_m``, ``tactile/{pad}/object_pose``,
the forces and slip, object poses). Per component (statistics over frames, not over components):
``mean``, ``std`` (population), ``min``, ``max``, each with the shape of one frame (``(8,)`` for
``robot/action``, ``()`` for scalars), and ``count``, the number of frames.
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from univtac_data.schema.fields import field_for_path
from univtac_data.storage import Dataset

STATS_PATH = "meta/stats.json"
STATS_VERSION = 1  # bump when what is computed changes; older files are then recomputed


def is_lowdim(path: str) -> bool:
    """Per-frame floating-point arrays of the ``small`` codec class: the ones statistics cover."""
    spec = field_for_path(path)
    return (spec is not None and spec.sampling == "per_frame" and spec.codec == "small"
            and spec.dtype.startswith("float"))


@dataclass(frozen=True)
class FieldStats:
    """Statistics of one array over frames. Arrays are float64 with the shape of one frame."""

    mean: np.ndarray
    std: np.ndarray   # population standard deviation (ddof = 0)
    min: np.ndarray
    max: np.ndarray
    count: int        # frames

    @classmethod
    def of(cls, values: np.ndarray) -> FieldStats:
        """Statistics of ``values``, shape (T, ...) with T >= 1."""
        data = np.asarray(values, np.float64)
        return cls(mean=data.mean(0), std=data.std(0), min=data.min(0), max=data.max(0), count=len(data))

    def merge(self, other: FieldStats) -> FieldStats:
        """Statistics of both sets of frames together (Chan et al.'s pairwise update; exact)."""
        n = self.count + other.count
        delta = other.mean - self.mean
        mean = self.mean + delta * (other.count / n)
        m2 = self.std ** 2 * self.count + other.std ** 2 * other.count + delta ** 2 * self.count * other.count / n
        return FieldStats(mean=mean, std=np.sqrt(m2 / n), min=np.minimum(self.min, other.min),
                          max=np.maximum(self.max, other.max), count=n)

    def to_json(self) -> dict[str, object]:
        return {"mean": self.mean.tolist(), "std": self.std.tolist(), "min": self.min.tolist(),
                "max": self.max.tolist(), "count": self.count}

    @classmethod
    def from_json(cls, data: dict[str, object]) -> FieldStats:
        return cls(**{k: np.asarray(data[k], np.float64) for k in ("mean", "std", "min", "max")},
                   count=int(data["count"]))  # type: ignore[call-overload]


def merge_all(parts: Sequence[dict[str, FieldStats]]) -> dict[str, FieldStats]:
    """Per-path merge of several statistics tables (paths missing from a table are skipped there)."""
    out: dict[str, FieldStats] = {}
    for part in parts:
        for path, stats in part.items():
            out[path] = out[path].merge(stats) if path in out else stats
    return out


def episode_digests(ds: Dataset) -> dict[str, str]:
    """Episode id -> SHA-256 digest, from the index: the key the saved statistics are valid for."""
    return {episode_id: row.sha256 for episode_id, row in sorted(ds.index.items())}


def compute_stats(ds: Dataset) -> dict[str, FieldStats]:
    """Statistics of every low-dimensional array over every episode of ``ds`` (reads those arrays whole)."""
    per_episode: list[dict[str, FieldStats]] = []
    for episode_id in ds.episode_ids:
        with ds.open_episode(episode_id) as handle:
            per_episode.append({p: FieldStats.of(handle.read(p)) for p in handle.paths() if is_lowdim(p)})
    return merge_all(per_episode)


def read_saved_stats(ds: Dataset) -> dict[str, FieldStats] | None:
    """The saved statistics if present, readable and computed from exactly the indexed episodes."""
    if not ds.loc.exists(STATS_PATH):
        return None
    try:
        data = json.loads(ds.loc.read_bytes(STATS_PATH))
        if data.get("stats_version") != STATS_VERSION or data.get("episodes") != episode_digests(ds):
            return None
        return {path: FieldStats.from_json(value) for path, value in data["fields"].items()}
    except (ValueError, KeyError, TypeError, AttributeError):
        return None  # a damaged file is recomputed like a stale one


def save_stats(ds: Dataset, stats: dict[str, FieldStats]) -> None:
    """Write ``meta/stats.json`` atomically (readers see the old file or the new one)."""
    doc = {"stats_version": STATS_VERSION, "episodes": episode_digests(ds),
           "fields": {path: stats[path].to_json() for path in sorted(stats)}}
    ds.loc.write_bytes_atomic(STATS_PATH, json.dumps(doc, indent=1, sort_keys=True).encode())


def load_or_compute_stats(ds: Dataset) -> tuple[dict[str, FieldStats], bool]:
    """``(stats, computed)``: the saved statistics when fresh, else computed now and saved.

    A dataset that cannot be written (read-only mount) still gets its statistics, in memory only, with a
    ``UserWarning`` saying so: they are then recomputed by every run.
    """
    saved = read_saved_stats(ds)
    if saved is not None:
        return saved, False
    stats = compute_stats(ds)
    try:
        save_stats(ds, stats)
    except OSError as error:
        warnings.warn(f"{ds.loc.url_of(STATS_PATH)}: cannot save statistics ({error}); using them unsaved",
                      UserWarning, stacklevel=2)
    return stats, True
