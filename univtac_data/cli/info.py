"""``univtac-data info PATH [--json]``: what a dataset holds."""

from __future__ import annotations

import argparse
import json
from collections import Counter
from typing import Any

from univtac_data.storage import Dataset


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    parser = subparsers.add_parser("info", help="summarise a dataset: episodes, frames, size, sensors, tasks")
    parser.add_argument("path", help="dataset directory or fsspec URL")
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    return parser


def summarise(dataset: Dataset) -> dict[str, Any]:
    """The numbers ``info`` prints, from the index (no episode is opened)."""
    rows = list(dataset.index.values())
    frames = sum(r.n_frames for r in rows)
    size = sum(r.bytes for r in rows)
    return {
        "path": dataset.loc.url,
        "format_version": dataset.info.format_version,
        "storage": dataset.info.storage,
        "episodes": len(rows),
        "frames": frames,
        "bytes": size,
        "bytes_per_frame": round(size / frames) if frames else 0,
        "duration_s": round(sum(r.duration_ns for r in rows) / 1e9, 3),
        "sensors": dict(sorted(Counter(r.sensor for r in rows).items())),
        "kinds": dict(sorted(Counter(r.kind for r in rows).items())),
        "names": dict(sorted(Counter(r.name for r in rows).items())),
        "success_rate": _success_rate(rows),
    }


def _success_rate(rows: list[Any]) -> float | None:
    judged = [r.success for r in rows if r.success is not None]
    return round(sum(judged) / len(judged), 4) if judged else None


def _human(size: int) -> str:
    value = float(size)
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if value < 1024 or unit == "TiB":
            return f"{value:.1f} {unit}" if unit != "B" else f"{int(value)} B"
        value /= 1024
    raise AssertionError("unreachable")


def run(args: argparse.Namespace) -> int:
    summary = summarise(Dataset.open(args.path))
    if args.json:
        print(json.dumps(summary, indent=2))
        return 0
    counts = lambda d: ", ".join(f"{k} ({v})" for k, v in d.items()) or "-"  # noqa: E731
    lines = [
        f"dataset         {summary['path']}",
        f"format          {summary['format_version']} ({summary['storage']})",
        f"episodes        {summary['episodes']}",
        f"frames          {summary['frames']}  ({summary['duration_s']} s)",
        f"size on disk    {_human(summary['bytes'])}  ({_human(summary['bytes_per_frame'])} per frame)",
        f"sensors         {counts(summary['sensors'])}",
        f"kinds           {counts(summary['kinds'])}",
        f"tasks/shapes    {counts(summary['names'])}",
    ]
    if summary["success_rate"] is not None:
        lines.append(f"success rate    {summary['success_rate']:.1%}")
    print("\n".join(lines))
    return 0
