"""Validation throughput: frames per second with 1 and 2 worker processes, HDF5 and Zarr.

Builds a dataset of factory episodes (tests/factories.py: spec-conforming synthetic data at the sensor's
full image size), validates it with every rule group, and writes
``benchmarks/results/validate_throughput.json`` (with the machine) and ``docs/figures/validate_throughput.png``.

    python benchmarks/validate_throughput.py [--episodes 16] [--frames 60] [--repeats 3]

Numbers are with a warm page cache (the dataset was just written): they measure decoding, hashing and the
rules, the part a faster disk does not remove.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from factories import make_episode  # noqa: E402

from univtac_data import __version__  # noqa: E402
from univtac_data.storage import DatasetWriter  # noqa: E402
from univtac_data.validators import validate  # noqa: E402
from common import machine as machine_info  # noqa: E402  (benchmarks/ is on sys.path when run as a script)


def build(root: Path, storage: str, n_episodes: int, n_frames: int, sensor: str) -> int:
    """Write the dataset; return its bytes on disk."""
    writer = DatasetWriter.open(root, storage=storage, sensors=[sensor])
    for k in range(n_episodes):
        writer.add(make_episode(sensor, n_frames, f"ep{k}", seed=k, cameras=("head",)))
    return sum(f.stat().st_size for f in root.rglob("*") if f.is_file())


def measure(root: Path, workers: int, repeats: int) -> list[float]:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        report = validate(root, workers=workers)
        times.append(time.perf_counter() - start)
        if not report.ok:
            raise SystemExit(f"benchmark dataset does not validate: {report.failed_episodes()}")
    return times


def chart(results: list[dict[str, object]], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    storages = sorted({str(r["storage"]) for r in results})
    workers = sorted({int(r["workers"]) for r in results})  # type: ignore[call-overload]
    fig, ax = plt.subplots(figsize=(6, 3.6), dpi=120)
    width = 0.8 / len(workers)
    for j, n in enumerate(workers):
        values = [next(float(r["frames_per_s"]) for r in results  # type: ignore[arg-type]
                       if r["storage"] == s and r["workers"] == n) for s in storages]
        bars = ax.bar([i + (j - (len(workers) - 1) / 2) * width for i in range(len(storages))], values, width,
                      label=f"{n} worker{'s' if n > 1 else ''}")
        ax.bar_label(bars, fmt="%.0f", fontsize=8)
    ax.set_xticks(range(len(storages)), storages)
    ax.set_ylabel("frames validated per second")
    ax.set_title(title, fontsize=9)
    ax.legend(frameon=False)
    ax.spines[["top", "right"]].set_visible(False)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=16)
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--sensor", default="gelsight_mini")
    parser.add_argument("--workers", default="1,2", help="comma-separated worker counts")
    args = parser.parse_args()
    worker_counts = [int(w) for w in args.workers.split(",")]
    results = []
    load_before = [round(x, 2) for x in os.getloadavg()]  # other jobs on the machine skew the numbers
    with tempfile.TemporaryDirectory(prefix="univtac-validate-bench-") as tmp:
        for storage in ("hdf5", "zarr"):
            root = Path(tmp) / storage
            size = build(root, storage, args.episodes, args.frames, args.sensor)
            frames = args.episodes * args.frames
            validate(root, workers=max(worker_counts))  # start the forkserver once, outside the timings
            # Interleave the worker counts repeat by repeat, so drifting load from other jobs hits all alike.
            timings: dict[int, list[float]] = {w: [] for w in worker_counts}
            for _ in range(args.repeats):
                for workers in worker_counts:
                    timings[workers] += measure(root, workers, 1)
            for workers in worker_counts:
                times = timings[workers]
                best = min(times)
                results.append({
                    "storage": storage, "workers": workers, "frames": frames, "bytes": size,
                    "seconds": [round(t, 4) for t in times], "seconds_median": round(statistics.median(times), 4),
                    "frames_per_s": round(frames / best, 1), "mib_per_s": round(size / best / 2 ** 20, 2),
                })
                print(f"{storage:5s} workers={workers}: {frames / best:8.1f} frames/s "
                      f"({size / best / 2 ** 20:.1f} MiB/s, best of {args.repeats})", flush=True)
    machine = {**machine_info(packages=("numpy", "h5py", "zarr")), "load_average_before": load_before,
               "load_average_after": [round(x, 2) for x in os.getloadavg()]}
    out = {
        "benchmark": "validate_throughput", "univtac_data": __version__, "machine": machine,
        "dataset": {"source": "tests/factories.make_episode", "sensor": args.sensor, "episodes": args.episodes,
                    "frames_per_episode": args.frames, "cameras": ["head (64x48)"], "groups": "all"},
        "note": "warm page cache; worker counts interleaved; frames_per_s uses the best of the repeats; "
                "a shared machine: see the load averages",
        "results": results,
    }
    result_path = ROOT / "benchmarks" / "results" / "validate_throughput.json"
    result_path.parent.mkdir(parents=True, exist_ok=True)
    result_path.write_text(json.dumps(out, indent=1) + "\n")
    title = (f"univtac-data validate, {args.episodes} x {args.frames} frames {args.sensor}\n"
             f"{machine['cpu']}, {machine['cores']} cores")
    chart(results, ROOT / "docs" / "figures" / "validate_throughput.png", title)
    print(f"wrote {result_path.relative_to(ROOT)} and docs/figures/validate_throughput.png")


if __name__ == "__main__":
    main()
