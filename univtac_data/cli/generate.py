"""``univtac-data generate indenters|task``: make the encoder-pretraining corpus or expert task demonstrations."""

from __future__ import annotations

import argparse
import math
import sys
from typing import Any

from univtac_data.schema.sensors import SENSORS
from univtac_data.storage import Dataset
from univtac_data.storage.errors import DatasetError
from univtac_data.cli.args import camera_size, positive_int

DEFAULT_OUT = "out/indenters"


EXAMPLES = """examples:
  univtac-data generate indenters                                   the default corpus in out/indenters
  univtac-data generate indenters --sensor all --episodes-per-shape 10 --workers 8 --out out/big
  univtac-data generate indenters --shapes sphere,cone --contact elastic --format zarr --out out/elastic
  univtac-data list shapes                                          the names --shapes accepts
  univtac-data generate task lift_can --episodes 10 --out out/lift_can   expert demonstrations of a task
  univtac-data generate task all --episodes 5 --no-cameras          every task, no camera images

One writer per dataset: a second run into the same --out is refused while the first runs (exit 2)."""



def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    parser = subparsers.add_parser("generate", help="generate a dataset (indenters: the encoder corpus; task: expert demonstrations)",
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
    ind.add_argument("--workers", type=positive_int, default=None, metavar="N",
                     help="parallel workers, at least 1 (default: the CPU count)")
    ind.add_argument("--executor", choices=("local", "ray"), default="local",
                     help="a local process pool, or Ray tasks (default local)")
    ind.add_argument("--ray-address", default=None, help="Ray cluster address (default: start a local Ray)")
    ind.add_argument("--compression-level", type=int, default=None, metavar="1-9",
                     help="Blosc-Zstandard level of the episode files, 1 (fastest) to 9 (smallest); readers need "
                          "not know it (default: 1 for geometric, 3 for elastic contact; 2 for the GF225's geometric)")
    task = kinds.add_parser(
        "task", help="expert demonstrations of a benchmark task (lift_can, ...), successful ones kept",
        description="Run a task's scripted expert on seed after seed (from --seed) and keep the successful, safe "
                    "episodes until --episodes are there; reports the seeds tried and the expert's success rate. "
                    "Rerun the same command to resume after an interruption.",
        epilog="example: univtac-data generate task lift_can --episodes 10 --out out/lift_can --no-cameras",
    )
    task.add_argument("name", metavar="NAME", help="task name, or 'all' (univtac_data.generators.tasks.registry)")
    task.add_argument("--episodes", type=int, default=5, help="successful episodes wanted per task (default 5)")
    task.add_argument("--out", default=None, help="dataset directory or URL (default out/tasks)")
    task.add_argument("--sensor", default="gelsight_mini", choices=list(SENSORS), help="sensor model (default gelsight_mini)")
    task.add_argument("--contact", choices=("geometric", "elastic"), default="geometric",
                      help="tactile contact model of the images (default geometric)")
    task.add_argument("--rate", type=float, default=50.0,
                      help="policy steps and recorded frames per second; a whole number of 2 ms ticks (default 50); "
                           "the task's step limit is a time limit (max_steps x RATE / 50), as in evaluate")
    task.add_argument("--seed", type=int, default=0, help="first seed tried; seeds go up by one (default 0)")
    task.add_argument("--camera-size", type=camera_size, default=(480, 270), metavar="WxH", help="head and wrist camera size (default 480x270)")
    task.add_argument("--no-cameras", action="store_true", help="record no camera images (much faster)")
    task.add_argument("--keep-failures", action="store_true",
                      help="keep failed or unsafe episodes too, flagged (success false); they do not count")
    task.add_argument("--max-seeds", type=positive_int, default=None, help="give up after this many seeds (default 20 x episodes)")
    task.add_argument("--format", choices=("hdf5", "zarr"), default="hdf5", help="storage backend (default hdf5)")
    task.add_argument("--workers", type=positive_int, default=None, help="parallel workers (default: the CPU count)")
    task.add_argument("--executor", choices=("local", "ray"), default="local", help="a local process pool, or Ray tasks")
    task.add_argument("--ray-address", default=None, help="Ray cluster address (default: start a local Ray)")
    task.add_argument("--compression-level", type=int, default=1, metavar="1-9",
                      help="Blosc-Zstandard level of the episode files (default 1)")
    return parser


def run_task(args: argparse.Namespace) -> int:
    from univtac_data.generators.runner import default_workers
    from univtac_data.generators.tasks.base import TaskConfig
    from univtac_data.generators.tasks.collect import collect
    from univtac_data.generators.tasks.registry import TASK_NAMES, UnknownTaskError, task_class
    from univtac_data.storage.encoding import ZSTD_LEVELS

    names = list(TASK_NAMES) if args.name == "all" else [args.name]
    try:
        for name in names:
            task_class(name)
    except UnknownTaskError as error:
        raise DatasetError(str(error)) from None
    if args.episodes < 1:
        raise DatasetError(f"--episodes must be at least 1 (got {args.episodes})")
    if args.compression_level not in ZSTD_LEVELS:
        raise DatasetError(f"--compression-level must be {ZSTD_LEVELS.start} to {ZSTD_LEVELS.stop - 1} "
                           f"(got {args.compression_level})")
    try:
        config = TaskConfig(sensor=args.sensor, contact_method=args.contact, rate_hz=args.rate,
                            cameras=not args.no_cameras, camera_size=args.camera_size)
    except ValueError as error:
        raise DatasetError(f"--rate: {error}") from None
    out = args.out or "out/tasks"
    workers = args.workers if args.workers is not None else default_workers()
    status = 0
    for name in names:
        summary = collect(out, name, args.episodes, config=config, base_seed=args.seed, storage=args.format,
                          workers=workers, executor=args.executor, ray_address=args.ray_address,
                          keep_failures=args.keep_failures, compression_level=args.compression_level,
                          max_seeds=args.max_seeds, progress=True)
        have = summary.already + summary.kept
        print(f"{out}: {name}: {have} of {args.episodes} successful episodes; this run tried {summary.tried} seeds, "
              f"kept {summary.kept} (expert success {summary.success_rate:.0%}), {summary.frames} frames in "
              f"{summary.elapsed_s:.1f} s")
        if summary.failed_seeds:
            print(f"{name}: seeds without a kept success: {', '.join(map(str, summary.failed_seeds[:20]))}"
                  + (" ..." if len(summary.failed_seeds) > 20 else ""))
        for line in summary.errors:
            print(f"error: {name}: {line}", file=sys.stderr)
        if summary.stopped:
            print(f"{name}: {summary.stopped}", file=sys.stderr)
        if have < args.episodes or summary.errors:
            status = 1
    return status


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
    if args.kind == "task":
        return run_task(args)
    from univtac_data.generators.indenters.corpus import corpus_specs
    from univtac_data.generators.runner import default_workers, run_corpus

    for name, value in (("--episodes-per-shape", args.episodes_per_shape), ("--frames-per-episode",
                                                                              args.frames_per_episode)):
        if value < 1:
            raise DatasetError(f"{name} must be at least 1 (got {value})")
    if not (math.isfinite(args.rate) and args.rate > 0):  # NaN compares false both ways and never stops
        raise DatasetError(f"--rate must be a positive number of Hz (got {args.rate})")
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
