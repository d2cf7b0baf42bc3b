"""``univtac-data info PATH [--json]``: what a dataset holds, and whether its files are all there.

Exit status: 0 the summary, nothing wrong seen; 1 the summary with warnings (an indexed file missing or of
another size than the manifest records, no index, episodes that disagree on their settings); 2 unusable input.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from typing import Any

from univtac_data.storage import Dataset


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "info", help="summarise a dataset: episodes, frames, size, sensors, tasks; check its files are there",
        description="Summarise a dataset from its index, and check cheaply (sizes, no hashing) that every indexed "
                    "file is there with the size the manifest records. Exit 0: fine; 1: warnings (printed on "
                    "stderr; run 'univtac-data validate' for the deep check); 2: unusable input.",
        epilog="examples:\n  univtac-data info out/indenters\n  univtac-data info out/indenters --json | jq .episodes",
        formatter_class=argparse.RawDescriptionHelpFormatter)
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


# per kind, the index fields every episode of one folder should share (task episodes end when they succeed, so
# only indenter episodes must have equal lengths)
SHARED_FIELDS = {"indenter": ("format_version", "nominal_rate_hz", "n_frames"), "task": ("format_version", "nominal_rate_hz")}


def disagreements(dataset: Dataset) -> list[str]:
    """One line per index field that the folder's episodes of one kind should share but do not."""
    out = []
    rows = list(dataset.index.values())
    for kind in sorted({r.kind for r in rows}):
        mine = [r for r in rows if r.kind == kind]
        for key in SHARED_FIELDS.get(kind, ("format_version", "nominal_rate_hz")):
            values = Counter(getattr(r, key) for r in mine)
            if len(values) > 1:
                listed = ", ".join(f"{v} ({n} episode{'s' if n > 1 else ''})" for v, n in sorted(values.items(), key=lambda kv: -kv[1]))
                out.append(f"{dataset.loc.url}: {kind} episodes disagree on {key}: {listed} (a folder mixing runs "
                           f"of different settings)")
    return out


def problems(dataset: Dataset) -> list[str]:
    """Everything ``info`` warns about, one line each."""
    out = []
    if not dataset.index_found:
        on_disk = len(dataset.episode_files_on_disk())
        out.append(f"{dataset.loc.url_of('meta/episodes.parquet')}: the index is missing ({on_disk} episode files "
                   f"on disk); run 'univtac-data reindex {dataset.loc.url}'")
    return out + dataset.check_files() + disagreements(dataset)


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
    dataset = Dataset.open(args.path)
    summary = summarise(dataset)
    warnings = problems(dataset)
    for line in warnings:
        print(f"warning: {line}", file=sys.stderr)
    if args.json:
        print(json.dumps({**summary, "warnings": warnings}, indent=2))
        return 1 if warnings else 0
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
    return 1 if warnings else 0
