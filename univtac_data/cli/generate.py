"""``univtac-data generate indenters``: make the encoder-pretraining corpus."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from univtac_data.schema.sensors import SENSORS
from univtac_data.storage import Dataset
from univtac_data.storage.errors import DatasetError

DEFAULT_OUT = "out/indenters"


EXAMPLES = """examples:
  univtac-data generate indenters                                   the default corpus in out/indenters
  univtac-data generate indenters --sensor all --episodes-per-shape 10 --workers 8 --out out/big
  univtac-data generate indenters --shapes sphere,cone --contact elastic --format zarr --out out/elastic
  univtac-data list shapes                                          the names --shapes accepts

One writer per dataset: a second run into the same --out is refused while the first runs (exit 2)."""


def _positive(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a positive integer (got {text!r})") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer (got {value})")
    return value


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    parser = subparsers.add_parser("generate", help="generate a dataset (indenters: the encoder corpus)",
                                   description="Generate a dataset in MuJoCo on the CPU.", epilog=EXAMPLES,
                                   formatter_class=argparse.RawDescriptionHelpFormatter)
    kinds = parser.add_subparsers(dest="kind", metavar="KIND", required=True)
    ind = kinds.add_parser(
        "indenters", help="a gripper pressing, twisting and shifting against the 14 indenters",
        description="Generate indenter episodes: closed-loop grasps to a random depth, then small rotations and "
                    "moves that shear the gel. Rerun the same command to resume after an interruption.",
        epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ind.add_argument("--out", default=DEFAULT_OUT, help=f"dataset directory or URL (default {DEFAULT_OUT})")
    ind.add_argument("--sensor", default="gelsight_mini", choices=[*SENSORS, "all"],
                     help="sensor model, or all three (default gelsight_mini)")
    ind.add_argument("--shapes", default="all",
                     help="'all' or a comma-separated list of indenter names (univtac-data list shapes)")
    ind.add_argument("--episodes-per-shape", type=int, default=2, help="episodes per shape and sensor (default 2)")
    ind.add_argument("--frames-per-episode", type=int, default=60, help="recorded frames per episode (default 60)")
    ind.add_argument("--rate", type=float, default=60.0, help="recording rate, Hz (default 60)")
    ind.add_argument("--contact", choices=("geometric", "elastic"), default="geometric",
                     help="tactile contact model (default geometric)")
    ind.add_argument("--gel", choices=("half_space", "layer"), default="half_space",
                     help="elastic contact: the gel as a half-space, or as a layer of the sensor's thickness "
                          "bonded to its backing (stiffer, deformation local to the contact; the rigid pad is "
                          "calibrated against the half-space) (default half_space)")
    ind.add_argument("--seed", type=int, default=0, help="base seed; each episode derives its own (default 0)")
    ind.add_argument("--format", choices=("hdf5", "zarr"), default="hdf5", help="storage backend (default hdf5)")
    ind.add_argument("--workers", type=_positive, default=None, metavar="N",
                     help="parallel workers, at least 1 (default: the CPU count)")
    ind.add_argument("--executor", choices=("local", "ray"), default="local",
                     help="a local process pool, or Ray tasks (default local)")
    ind.add_argument("--ray-address", default=None, help="Ray cluster address (default: start a local Ray)")
    ind.add_argument("--compression-level", type=int, default=None, metavar="1-9",
                     help="Blosc-Zstandard level of the episode files, 1 (fastest) to 9 (smallest); readers need "
                          "not know it (default: 1 for geometric, 3 for elastic contact)")
    return parser


def _shape_list(text: str) -> list[str]:
    from univtac_data.generators.indenters.shapes import INDENTER_NAMES

    if text == "all":
        return list(INDENTER_NAMES)
    shapes = [s.strip() for s in text.split(",") if s.strip()]
    unknown = [s for s in shapes if s not in INDENTER_NAMES]
    if unknown or not shapes:
        raise DatasetError(f"--shapes: unknown indenter {', '.join(unknown) or '(none)'}; "
                           f"known: {', '.join(INDENTER_NAMES)}")
    return shapes


def run(args: argparse.Namespace) -> int:
    from univtac_data.generators.indenters.corpus import corpus_specs
    from univtac_data.generators.runner import default_workers, run_corpus

    for name, value in (("--episodes-per-shape", args.episodes_per_shape), ("--frames-per-episode",
                                                                              args.frames_per_episode)):
        if value < 1:
            raise DatasetError(f"{name} must be at least 1 (got {value})")
    if args.rate <= 0:
        raise DatasetError(f"--rate must be positive (got {args.rate})")
    if args.gel != "half_space" and args.contact != "elastic":
        raise DatasetError(f"--gel {args.gel} applies to --contact elastic only (got --contact {args.contact})")
    sensors = list(SENSORS) if args.sensor == "all" else [args.sensor]
    specs = corpus_specs(sensors, _shape_list(args.shapes), args.episodes_per_shape, base_seed=args.seed,
                         frames=args.frames_per_episode, contact_method=args.contact, gel=args.gel,
                         record_rate_hz=args.rate)
    workers = args.workers if args.workers is not None else default_workers()
    summary = run_corpus(args.out, specs, storage=args.format, workers=workers, executor=args.executor,
                         ray_address=args.ray_address, progress=True,
                         compression_level=args.compression_level)
    dataset = Dataset.open(args.out)
    frames = sum(r.n_frames for r in dataset.index.values())
    size = sum(r.bytes for r in dataset.index.values())
    print(f"{args.out}: {len(dataset)} episodes, {frames} frames, {size / 2**20:.1f} MiB "
          f"({size / max(frames, 1) / 1024:.0f} KiB per frame)")
    print(f"this run: {summary.written} written, {summary.skipped_existing} already there, "
          f"{len(summary.failed)} failed, {summary.frames} frames in {summary.elapsed_s:.1f} s "
          f"({summary.frames_per_s:.0f} frames/s with {workers} {args.executor} worker(s))")
    for line in summary.failed:
        print(f"failed: {line}", file=sys.stderr)
    return 1 if summary.failed else 0
