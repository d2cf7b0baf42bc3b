"""Loader throughput: TactileFrameDataset against the naive per-item-reopen pattern, in one run.

Builds a benchmark dataset with the test factories (default 8 episodes x 100 frames, gelsight_mini,
320 x 240, both pads: 1,600 pad samples) in a temporary directory, then times full epochs through
``torch.utils.data.DataLoader`` (batch 32, shuffled, ``--workers`` processes, persistent workers, one
warm-up epoch discarded) for:

* ``naive``: ACT's EpisodicDataset pattern, ``h5py.File(path)`` opened and closed for every item,
  float32 targets made in the worker;
* ``ours_float``: ``TactileFrameDataset`` (per-worker LRU of open handles, marker and pose tracks read
  once per episode), float32 targets made in the worker;
* ``ours_compact``: ``TactileFrameDataset(compact=True)`` (uint8 images, int16 um depth through the
  worker pipe) and ``to_float(batch)`` in the main process, inside the timed loop;
* the same two on the Zarr backend, and a ``ceiling`` of workers that read nothing and return zero
  tensors of the same shapes (the cost of moving samples between processes alone).

Then profiles one process (cProfile over ``--profile-items`` items) to say where the time goes. Writes
``benchmarks/results/loader_throughput.json`` and ``docs/figures/loader_throughput.png``.

Run: ``python benchmarks/loader_throughput.py`` (about two minutes on 2 cores).
"""

from __future__ import annotations

import argparse
import cProfile
import json
import os
import pstats
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import h5py
import hdf5plugin  # noqa: F401  (registers the Blosc filter the episodes are compressed with)
import numpy as np
import torch

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

from factories import make_dataset  # noqa: E402

from univtac_data.loaders import ENCODER_TARGETS, TactileFrameDataset, to_float  # noqa: E402
from univtac_data.loaders.frames import FRAME_FIELDS, convert_target  # noqa: E402
from univtac_data.storage import Dataset  # noqa: E402
from common import machine  # noqa: E402  (benchmarks/ is on sys.path when run as a script)


class NaiveEpisodic(torch.utils.data.Dataset[dict[str, Any]]):
    """ACT's EpisodicDataset pattern: open the episode's HDF5 file for every item, read, close.

    Same samples (keys, shapes, dtypes, values) as ``TactileFrameDataset`` with the encoder targets.
    """

    def __init__(self, root: str) -> None:
        ds = Dataset.open(root)
        self.files = [os.path.join(root, ds.index[e].path) for e in ds.episode_ids]
        self.n_frames = [ds.index[e].n_frames for e in ds.episode_ids]
        profile = ds.sensor(ds.index[ds.episode_ids[0]].sensor)
        self.width, self.height = profile.image_width_px, profile.image_height_px
        self.rows = [(k, t, pad) for k, n in enumerate(self.n_frames) for t in range(n) for pad in ("left", "right")]

    def __len__(self) -> int:
        return len(self.rows)

    def __getitem__(self, index: int) -> dict[str, Any]:
        k, t, pad = self.rows[index]
        with h5py.File(self.files[k], "r", locking=False) as root:
            arrays = {key: root[f"tactile/{pad}/{FRAME_FIELDS[key]}"][t] for key in ENCODER_TARGETS}
        return dict(convert_target(key, value, self.width, self.height) for key, value in arrays.items())


class ZeroSamples(torch.utils.data.Dataset[dict[str, Any]]):
    """Reads nothing: zero tensors shaped like a 320 x 240 sample, float32 or compact."""

    def __init__(self, n: int, compact: bool) -> None:
        self.n, self.compact = n, compact

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, index: int) -> dict[str, Any]:
        image = torch.uint8 if self.compact else torch.float32
        return {"marked_rgb": torch.zeros(3, 240, 320, dtype=image), "pure_rgb": torch.zeros(3, 240, 320, dtype=image),
                ("depth_um" if self.compact else "depth_mm"): torch.zeros(1, 240, 320,
                                                                         dtype=torch.int16 if self.compact else None),
                "markers": torch.zeros(63, 2), "object_pose": torch.zeros(7)}


class TimedLoader:
    """A DataLoader with persistent workers, timed one epoch at a time (after one warm-up epoch)."""

    def __init__(self, dataset: torch.utils.data.Dataset[Any], workers: int, batch_size: int,
                 post: Callable[[dict[str, Any]], dict[str, Any]] | None = None) -> None:
        self.loader = torch.utils.data.DataLoader(dataset, batch_size=batch_size, shuffle=True, num_workers=workers,
                                                  persistent_workers=workers > 0,
                                                  generator=torch.Generator().manual_seed(0))
        self.post = post
        self.rates: list[float] = []
        self.epoch()  # warm-up: starts the workers, opens files, warms allocators
        self.rates.clear()

    def epoch(self) -> float:
        start, n = time.perf_counter(), 0
        for batch in self.loader:
            if self.post is not None:
                batch = self.post(batch)
            n += len(batch["object_pose"])
        self.rates.append(n / (time.perf_counter() - start))
        return self.rates[-1]

    def result(self) -> dict[str, Any]:
        return {"samples_per_s": float(np.median(self.rates)), "epochs": self.rates}


def per_item_rate(dataset: torch.utils.data.Dataset[Any], n: int) -> float:
    """Items per second of ``dataset[k]`` in this process (no DataLoader, no collate)."""
    order = np.random.default_rng(1).permutation(len(dataset))[:n]  # type: ignore[arg-type]
    for k in order[:16]:
        dataset[int(k)]
    start = time.perf_counter()
    for k in order:
        dataset[int(k)]
    return n / (time.perf_counter() - start)


def profile_items(dataset: TactileFrameDataset, n: int) -> dict[str, Any]:
    """Where one process spends its time per item (cProfile, cumulative seconds per stage)."""
    for k in range(32):  # open the episodes and warm the allocator first
        dataset[k * 37 % len(dataset)]
    order = np.random.default_rng(0).permutation(len(dataset))[:n]
    profiler = cProfile.Profile()
    start = time.perf_counter()
    profiler.enable()
    samples = [dataset[int(k)] for k in order]
    batch = torch.utils.data.default_collate(samples)
    profiler.disable()
    wall = time.perf_counter() - start
    stats = pstats.Stats(profiler)
    cumulative = {f"{Path(f).name}:{name}": v[3] for (f, _, name), v in stats.stats.items()}  # type: ignore[attr-defined]

    def total(*names: str) -> float:
        return sum(v for k, v in cumulative.items() if any(k.endswith(s) for s in names))

    read = total("frames.py:read_raw")
    decode = total("backend.py:read")
    convert = total("frames.py:convert_target", "frames.py:convert_compact")
    collate = total("collate.py:default_collate")
    del batch
    return {"items": n, "wall_s": wall, "per_item_ms": 1e3 * wall / n,
            "stages_ms_per_item": {"read_total": 1e3 * read / n, "of_which_decode_hdf5_or_zarr": 1e3 * decode / n,
                                   "convert_to_tensors": 1e3 * convert / n, "collate": 1e3 * collate / n}}


def profile_naive(dataset: NaiveEpisodic, n: int) -> dict[str, Any]:
    """Per-item time of the naive pattern, split into file open/close and the rest (cProfile)."""
    order = np.random.default_rng(0).permutation(len(dataset))[:n]
    profiler = cProfile.Profile()
    start = time.perf_counter()
    profiler.enable()
    for k in order:
        dataset[int(k)]
    profiler.disable()
    wall = time.perf_counter() - start
    stats = pstats.Stats(profiler)
    opens = sum(v[3] for (f, _, name), v in stats.stats.items()  # type: ignore[attr-defined]
                if f.endswith("files.py") and name in ("__init__", "close"))
    return {"items": n, "per_item_ms": 1e3 * wall / n, "open_close_ms_per_item": 1e3 * opens / n}


def plot(results: dict[str, Any], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = results["runs"]
    names = list(runs)
    rates = [runs[n]["samples_per_s"] for n in names]
    colours = ["#999999" if n == "naive_hdf5" else "#cccccc" if n.startswith("ceiling") else "#3b75af" for n in names]
    fig, ax = plt.subplots(figsize=(8, 3.6))
    ax.barh(names, rates, color=colours)
    for y, rate in enumerate(rates):
        ax.text(rate, y, f" {rate:,.0f}", va="center", fontsize=8)
    ax.axvline(2000, color="#c44", linestyle="--", linewidth=1)
    ax.text(2000, len(names) - 0.5, " target 2,000/s", color="#c44", fontsize=8, va="top")
    ax.invert_yaxis()
    m = results["machine"]
    ax.set_xlabel(f"pad samples per second (320 x 240, five targets; {results['config']['workers']} workers, "
                  f"batch {results['config']['batch_size']})")
    ax.set_title(f"TactileFrameDataset throughput - {m['cpu']}, {m['cores']} cores, torch {m['torch']}",
                 fontsize=9)
    ax.set_xlim(0, max(max(rates) * 1.18, 2300))
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=8)
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--batch-size", type=int, default=32)
    parser.add_argument("--epochs", type=int, default=3, help="timed rounds (one epoch per configuration each)")
    parser.add_argument("--profile-items", type=int, default=400)
    parser.add_argument("--out", type=Path, default=REPO / "benchmarks/results/loader_throughput.json")
    parser.add_argument("--figure", type=Path, default=REPO / "docs/figures/loader_throughput.png")
    args = parser.parse_args(argv)

    with tempfile.TemporaryDirectory(prefix="univtac-bench-") as tmp:
        roots = {}
        for storage in ("hdf5", "zarr"):
            start = time.perf_counter()
            roots[storage] = str(make_dataset(Path(tmp) / storage, storage, args.episodes, n_frames=args.frames))
            print(f"built {storage} dataset ({args.episodes} x {args.frames} frames) in "
                  f"{time.perf_counter() - start:.1f} s", flush=True)
        n = args.episodes * args.frames * 2
        w, b, e = args.workers, args.batch_size, args.epochs
        load_before = os.getloadavg()
        plan: dict[str, Callable[[], TimedLoader]] = {
            "naive_hdf5": lambda: TimedLoader(NaiveEpisodic(roots["hdf5"]), w, b),
            "ours_float_hdf5": lambda: TimedLoader(TactileFrameDataset(roots["hdf5"]), w, b),
            "ours_compact_hdf5": lambda: TimedLoader(TactileFrameDataset(roots["hdf5"], compact=True), w, b),
            "ours_compact_hdf5+to_float_cpu": lambda: TimedLoader(TactileFrameDataset(roots["hdf5"], compact=True),
                                                                  w, b, post=to_float),
            "ours_float_zarr": lambda: TimedLoader(TactileFrameDataset(roots["zarr"]), w, b),
            "ours_compact_zarr": lambda: TimedLoader(TactileFrameDataset(roots["zarr"], compact=True), w, b),
            "ceiling_float_no_io": lambda: TimedLoader(ZeroSamples(n, compact=False), w, b),
            "ceiling_compact_no_io": lambda: TimedLoader(ZeroSamples(n, compact=True), w, b),
        }
        loaders = {name: make() for name, make in plan.items()}
        # Rounds interleave the configurations, so that load from other processes hits all of them alike.
        for round_ in range(e):
            for name, loader in loaders.items():
                rate = loader.epoch()
                print(f"round {round_ + 1} {name:32s} {rate:8.0f} samples/s", flush=True)
        runs: dict[str, dict[str, Any]] = {name: loader.result() for name, loader in loaders.items()}
        del loaders
        single = {"naive_hdf5": per_item_rate(NaiveEpisodic(roots["hdf5"]), args.profile_items),
                  "ours_float_hdf5": per_item_rate(TactileFrameDataset(roots["hdf5"]), args.profile_items),
                  "ours_compact_hdf5": per_item_rate(TactileFrameDataset(roots["hdf5"], compact=True),
                                                     args.profile_items),
                  "ours_float_zarr": per_item_rate(TactileFrameDataset(roots["zarr"]), args.profile_items)}
        profiles = {
            "ours_float_hdf5": profile_items(TactileFrameDataset(roots["hdf5"]), args.profile_items),
            "ours_compact_hdf5": profile_items(TactileFrameDataset(roots["hdf5"], compact=True), args.profile_items),
            "naive_hdf5": profile_naive(NaiveEpisodic(roots["hdf5"]), args.profile_items),
        }
        load_after = os.getloadavg()
    base = runs["naive_hdf5"]["samples_per_s"]
    best = max(runs["ours_float_hdf5"]["samples_per_s"], runs["ours_compact_hdf5"]["samples_per_s"])
    same_output = runs["ours_float_hdf5"]["samples_per_s"] / base
    results = {
        "machine": machine(packages=("numpy", "torch", "h5py")),
        "config": {"episodes": args.episodes, "frames": args.frames, "pad_samples": n, "sensor": "gelsight_mini",
                   "image": "320x240", "targets": list(ENCODER_TARGETS), "workers": w, "batch_size": b,
                   "timed_epochs": e},
        "runs": runs,
        "speedup_vs_naive": {k: v["samples_per_s"] / base for k, v in runs.items()},
        "single_process_items_per_s": single,
        "single_process_speedup_vs_naive": {k: v / single["naive_hdf5"] for k, v in single.items()},
        "targets": {"speedup_3x_best": best / base >= 3.0, "speedup_float_vs_float": same_output,
                    "rate_2000_per_s": best >= 2000.0},
        "load_average_1_5_15min": {"before": load_before, "after": load_after},
        "profile_one_process": profiles,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=1) + "\n")
    plot(results, args.figure)
    for name, prof in profiles.items():
        print(name, json.dumps(prof.get("stages_ms_per_item", prof)), f"(wall {prof['per_item_ms']:.2f} ms/item)")
    print(f"best/naive = {best / base:.2f}x; wrote {args.out} and {args.figure}")
    return results


if __name__ == "__main__":
    main()
