"""``univtac-data convert SRC DST --to {hdf5,zarr}``: lossless conversion, verified after writing."""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import dataclass, field
from typing import Any

from univtac_data.episode import content_hash
from univtac_data.progress import Progress
from univtac_data.storage import STORES, CorruptFileError, Dataset, DatasetError, DatasetWriter, Location


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "convert", help="copy a dataset into another storage backend or the current format version, losslessly, "
                        "and verify it",
        description="Copy every episode of SRC into DST in the chosen backend and the current format version "
                    "(an older version is upgraded: metadata restamped, images stored as residuals), then reopen "
                    "DST and check each episode's content hash against the source. Rerun to resume an "
                    "interrupted conversion. A damaged source episode is skipped and reported, and the command "
                    "then exits 1.",
        epilog="examples:\n  univtac-data convert out/indenters out/indenters-zarr --to zarr\n"
               "  univtac-data convert old-1.0-dataset new-dataset --to hdf5     upgrade a format 1.0 dataset",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("src", help="source dataset directory or URL")
    parser.add_argument("dst", help="destination directory or URL (new, or a partial conversion to resume)")
    parser.add_argument("--to", required=True, choices=sorted(STORES), help="storage backend of DST")
    return parser


@dataclass
class ConvertSummary:
    """What a conversion did: episode ids converted now, found already converted, and one line per failure."""

    converted: list[str] = field(default_factory=list)
    already_there: list[str] = field(default_factory=list)
    failed: list[str] = field(default_factory=list)

    @property
    def verified(self) -> int:
        return len(self.converted) + len(self.already_there)


def convert_dataset(src: str, dst: str, to: str, progress: bool = True) -> ConvertSummary:
    """Convert and verify every episode; a damaged episode is skipped and reported in ``failed``. Raises
    ``DatasetError`` only when a dataset as a whole is unusable (or locked by another writer)."""
    source_loc, target_loc = Location.parse(src), Location.parse(dst)
    if (source_loc.protocol, _real(source_loc)) == (target_loc.protocol, _real(target_loc)):
        raise DatasetError(f"{dst}: the destination is the source dataset; choose a new folder")
    source = Dataset.open(src)
    summary = ConvertSummary()
    expected: dict[str, str] = {}
    with DatasetWriter.open(dst, storage=to, sensors=sorted(source.info.sensors)) as writer:
        bar = Progress(len(source), desc="convert", enabled=progress)
        for episode_id in source.episode_ids:
            where = source.loc.url_of(source.index[episode_id].path)
            try:
                # an older format's episode is upgraded on the way (the writer stamps its own version)
                episode = source.load_episode(episode_id).in_current_format()
                expected[episode_id] = content_hash(episode)
                if writer.has(episode_id):
                    summary.already_there.append(episode_id)
                else:
                    writer.add(episode)
                    summary.converted.append(episode_id)
            except Exception as error:  # a damaged episode (any reader error) must not end the conversion
                summary.failed.append(_one_line(where, error))
            bar.update(1, failed=len(summary.failed))
        bar.close()
    target = Dataset.open(dst)
    for episode_id, wanted in expected.items():
        if episode_id not in target.index:
            summary.failed.append(f"{target.loc.url}: episode {episode_id} missing after conversion")
            continue
        path = target.loc.url_of(target.index[episode_id].path)
        try:
            got = content_hash(target.load_episode(episode_id))
        except Exception as error:
            summary.failed.append(_one_line(path, error))
            continue
        if got != wanted:
            summary.failed.append(f"{path}: content differs from the source episode (hash {got[:12]} != {wanted[:12]})")
    summary.failed += target.verify_checksums(list(expected))
    return summary


def convert(src: str, dst: str, to: str, progress: bool = True) -> int:
    """Convert and verify; returns the number of episodes verified in DST. Raises ``DatasetError`` on the first
    failure (``convert_dataset`` reports them all instead)."""
    summary = convert_dataset(src, dst, to, progress=progress)
    if summary.failed:
        raise CorruptFileError(summary.failed[0])
    return summary.verified


def _real(loc: Location) -> str:
    return os.path.realpath(loc.root) if loc.is_local else loc.root.rstrip("/")


def _one_line(where: str, error: BaseException) -> str:
    text = str(error).splitlines()[0] if str(error) else type(error).__name__
    return text if isinstance(error, DatasetError) and text.startswith(where) else \
        f"{where}: {type(error).__name__}: {text}"


def run(args: argparse.Namespace) -> int:
    summary = convert_dataset(args.src, args.dst, args.to, progress=True)
    for line in summary.failed:
        print(f"failed: {line}", file=sys.stderr)
    print(f"{args.dst} ({args.to}): {len(summary.converted)} converted, {len(summary.already_there)} already "
          f"converted, {len(summary.failed)} failed; content hashes verified")
    return 1 if summary.failed else 0
