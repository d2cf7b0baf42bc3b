"""``univtac-data reindex PATH``: rebuild the index and manifest from the episodes on disk."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from univtac_data.storage import DatasetWriter


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "reindex", help="rebuild meta/episodes.parquet and meta/manifest.json from the episodes on disk",
        description="Rebuild the index and the SHA-256 manifest from the episode files, hashing each. Removes "
                    "temporaries left by killed writers. Takes the dataset's writer lock: refused (exit 2) while "
                    "a writer is adding episodes. Exit 1 when an episode file could not be indexed.",
        epilog="examples:\n  univtac-data reindex out/indenters          after 'info' warns the index is missing",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("path", help="dataset directory or fsspec URL")
    return parser


def run(args: argparse.Namespace) -> int:
    report = DatasetWriter.reindex_dataset(args.path)
    for line in report.skipped:
        print(f"skipped: {line}", file=sys.stderr)
    print(f"indexed {len(report.indexed)} episodes, skipped {len(report.skipped)}, "
          f"removed {len(report.removed_temporaries)} temporary leftovers")
    return 1 if report.skipped else 0
