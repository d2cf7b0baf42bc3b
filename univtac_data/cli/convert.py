"""``univtac-data convert SRC DST --to {hdf5,zarr}``: lossless conversion, verified after writing."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from tqdm import tqdm

from univtac_data.episode import content_hash
from univtac_data.storage import STORES, CorruptFileError, Dataset, DatasetWriter


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "convert", help="copy a dataset into another storage backend or the current format version, losslessly, "
                        "and verify it",
        description="Copy every episode of SRC into DST in the chosen backend and the current format version "
                    "(an older version is upgraded: metadata restamped, images stored as residuals), then reopen "
                    "DST and check each episode's content hash against the source. Rerun to resume an "
                    "interrupted conversion.",
    )
    parser.add_argument("src", help="source dataset directory or URL")
    parser.add_argument("dst", help="destination directory or URL (new, or a partial conversion to resume)")
    parser.add_argument("--to", required=True, choices=sorted(STORES), help="storage backend of DST")
    return parser


def convert(src: str, dst: str, to: str, progress: bool = True) -> int:
    """Convert and verify; returns the number of episodes converted. Raises ``DatasetError`` on failure."""
    source = Dataset.open(src)
    writer = DatasetWriter.open(dst, storage=to, sensors=sorted(source.info.sensors))
    expected: dict[str, str] = {}
    for episode_id in tqdm(source.episode_ids, desc="convert", unit="episode", disable=not progress,
                           file=sys.stderr):
        # an older format's episode is upgraded on the way (the writer stamps its own version)
        episode = source.load_episode(episode_id).in_current_format()
        expected[episode_id] = content_hash(episode)
        if not writer.has(episode_id):
            writer.add(episode)
    target = Dataset.open(dst)
    for episode_id in tqdm(source.episode_ids, desc="verify", unit="episode", disable=not progress,
                           file=sys.stderr):
        if episode_id not in target.index:
            raise CorruptFileError(f"{target.loc.url}: episode {episode_id} missing after conversion")
        got = content_hash(target.load_episode(episode_id))
        if got != expected[episode_id]:
            path = target.loc.url_of(target.index[episode_id].path)
            raise CorruptFileError(f"{path}: content differs from the source episode (hash {got[:12]} "
                                   f"!= {expected[episode_id][:12]})")
    problems = target.verify_checksums()
    if problems:
        raise CorruptFileError(problems[0])
    return len(expected)


def run(args: argparse.Namespace) -> int:
    count = convert(args.src, args.dst, args.to, progress=sys.stderr.isatty())
    print(f"converted {count} episodes to {args.to} at {args.dst}; content hashes verified")
    return 0
