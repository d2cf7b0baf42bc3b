"""Indenter generation end to end, one core: frames per second per sensor and contact model (physics,
tactile, compression, write), bytes per frame on disk, where the time goes, and what the paper-size
corpus (205,826 frames) would take on a 2-core machine.

    python benchmarks/generate_throughput.py [--frames 40] [--shapes all] [--passes 3]

Frames per second per core are frames over the CPU seconds of the process (simulation, tactile model,
compression and write), so other jobs on the machine do not inflate them; wall-clock rates are recorded too.
Each row runs ``--passes`` times, the passes interleaved across the rows so that a slow spell of a shared
machine falls on every row alike. The quoted rate is the best pass, as ``timeit`` reports the best of its
repeats (other tenants of a VM only ever slow a run down); every pass's rate and their median are recorded.
Each sensor and contact model first runs a short untimed episode: the compiled kernels are built (or loaded
from numba's on-disk cache) once per process, which a generator worker pays once, not per frame.

Contact models: geometric; elastic on a half-space (the default); elastic on a gel layer bonded to its backing
(``--gel layer``), whose rows also show how much larger its forces are.

``--split`` adds ``--passes`` more passes of every row in which every compiled entry point is timed
(``compiled_split.py``): the row's CPU ms a frame inside compiled code (its least over the passes) and the ceiling
rate, frames / compiled seconds, which no rewrite of the Python between the kernels could beat without the
kernels doing less work.

Writes benchmarks/results/generate_throughput.json and docs/figures/generate_throughput.png.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")  # one core, as the numbers claim

import argparse  # noqa: E402
import cProfile  # noqa: E402
import json  # noqa: E402
import pstats  # noqa: E402
import shutil  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from common import FIGURES, RESULTS, machine  # noqa: E402
from compiled_split import CompiledClock  # noqa: E402

from univtac_data.generators.allocator import keep_freed_memory  # noqa: E402
from univtac_data.generators.indenters.corpus import IndenterEpisodeSpec, run_indenter_episode  # noqa: E402
from univtac_data.generators.indenters.shapes import INDENTER_NAMES  # noqa: E402
from univtac_data.generators.runner import compression_level_for  # noqa: E402
from univtac_data.schema.sensors import SENSORS  # noqa: E402
from univtac_data.storage import Location, write_episode_file  # noqa: E402

PAPER_FRAMES = 205_826
UNIVTAC_BYTES_PER_FRAME = 242 * 2**30 / 191_173  # 242 GiB for 191,173 frames (format-lessons.md)
STAGES = {  # profile entries (function name, file suffix) -> stage
    ("mj_step", ""): "physics (MuJoCo)",
    ("mj_geomDistance", ""): "physics (MuJoCo)",
    ("gap_field", "gap_field.py"): "gap field",
    ("solve_contact", "contact.py"): "contact solve",
    ("solve_shear", "shear.py"): "shear and slip",
    ("render_shaded", "optics.py"): "optics",
    ("draw_markers", "markers.py"): "markers",
    ("write_episode_file", "dataset.py"): "compress and write",
}


MODELS = (("geometric", "half_space"), ("elastic", "half_space"), ("elastic", "layer"))


def one(sensor: str, method: str, shape: str, frames: int, out: str, index: int, gel: str = "half_space") \
        -> dict[str, float]:
    """One episode; CPU seconds of this process (what one core spends, whatever else the machine runs) and
    wall seconds (which include waiting for the disk)."""
    spec = IndenterEpisodeSpec(sensor, shape, index, frames=frames, contact_method=method,  # type: ignore[arg-type]
                               gel=gel)  # type: ignore[arg-type]
    cpu0, wall0 = time.process_time(), time.perf_counter()
    episode = run_indenter_episode(spec)
    cpu1 = time.process_time()
    written = write_episode_file(Location.parse(out), "hdf5", episode, compression_level=compression_level_for(spec))
    cpu2, wall2 = time.process_time(), time.perf_counter()
    return {"frames": frames, "simulate_cpu_s": cpu1 - cpu0, "write_cpu_s": cpu2 - cpu1, "wall_s": wall2 - wall0,
            "bytes": written.row.bytes, "max_normal_force_n": episode.meta.safety.max_normal_force_n}


def rate_of(runs: list[dict[str, float]]) -> float:
    """Frames per CPU-second of a pass's episodes."""
    return sum(r["frames"] for r in runs) / sum(r["simulate_cpu_s"] + r["write_cpu_s"] for r in runs)


def _stage_of(path: str, name: str) -> str | None:
    for (fn, suffix), stage in STAGES.items():
        if suffix and name == fn and path.endswith(suffix):
            return stage
        if not suffix and path == "~" and fn in name:  # a C function (MuJoCo): pstats files it under "~"
            return stage
    return None


def profile_stages(sensor: str, method: str, shape: str, frames: int, out: str) -> dict[str, float]:
    profiler = cProfile.Profile()
    profiler.runcall(one, sensor, method, shape, frames, out, 999)
    stats = pstats.Stats(profiler)
    total = max(v[3] for v in stats.stats.values())  # type: ignore[attr-defined]
    shares: dict[str, float] = {}
    for (path, _line, name), value in stats.stats.items():  # type: ignore[attr-defined]
        stage = _stage_of(path, name)
        if stage is not None:
            shares[stage] = shares.get(stage, 0.0) + value[3] / total
    shares["other (control, recording, Python)"] = max(0.0, 1.0 - sum(shares.values()))
    return {k: round(v, 3) for k, v in shares.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--shapes", default="all", help="'all' (the 14) or a comma-separated list")
    parser.add_argument("--passes", type=int, default=3, help="runs of every row; the best is quoted (default 3)")
    parser.add_argument("--split", action="store_true",
                        help="as many more passes of every row with every compiled entry point timed: its compiled "
                             "ms a frame and the ceiling rate (compiled_split.py)")
    args = parser.parse_args()
    keep_freed_memory()  # as the generator's workers do (generators/allocator.py)
    shapes = list(INDENTER_NAMES) if args.shapes == "all" else args.shapes.split(",")
    configs = [(sensor, method, gel) for sensor in SENSORS for method, gel in MODELS]
    passes: dict[tuple[str, str, str], list[list[dict[str, float]]]] = {c: [] for c in configs}
    with tempfile.TemporaryDirectory() as tmp:
        for sensor, method, gel in configs:
            # untimed: the compiled kernels (numba) are built or loaded once per process, a one-time cost
            # that a worker pays on its first frame, not per frame
            one(sensor, method, shapes[0], 3, os.path.join(tmp, f"warm-up-{sensor}-{method}-{gel}"), 10_000, gel)
        for k_pass in range(args.passes):
            for sensor, method, gel in configs:
                out = os.path.join(tmp, f"{sensor}-{method}-{gel}-{k_pass}")
                passes[(sensor, method, gel)].append(
                    [one(sensor, method, shape, args.frames, out, k, gel) for k, shape in enumerate(shapes)])
                shutil.rmtree(out)   # the bytes are measured; three passes of every row would fill a small disk
                print(f"pass {k_pass + 1}: {sensor} {method} {gel}: "
                      f"{rate_of(passes[(sensor, method, gel)][-1]):.1f} frames/s/core", file=sys.stderr)
        rows = []
        for sensor, method, gel in configs:
            rates = [rate_of(runs) for runs in passes[(sensor, method, gel)]]
            runs = passes[(sensor, method, gel)][int(np.argmax(rates))]   # the best pass
            frames = sum(r["frames"] for r in runs)
            seconds = sum(r["simulate_cpu_s"] + r["write_cpu_s"] for r in runs)
            row = {
                "sensor": sensor, "method": method, "gel": gel, "frames": frames,
                "frames_per_s_per_core": round(frames / seconds, 1),
                "frames_per_s_per_core_passes": [round(r, 1) for r in rates],
                "frames_per_s_per_core_median": round(float(np.median(rates)), 1),
                "frames_per_s_wall": round(frames / sum(r["wall_s"] for r in runs), 1),
                "compress_write_share_of_cpu": round(sum(r["write_cpu_s"] for r in runs) / seconds, 3),
                "bytes_per_frame": round(sum(r["bytes"] for r in runs) / frames),
                "paper_corpus_hours_on_2_cores": round(PAPER_FRAMES / (2 * frames / seconds) / 3600, 2),
                # per episode, the largest normal force on either pad (N): median and max over the shapes
                "episode_max_normal_force_n_median": round(float(np.median([r["max_normal_force_n"]
                                                                            for r in runs])), 2),
                "episode_max_normal_force_n_max": round(max(r["max_normal_force_n"] for r in runs), 2),
            }
            rows.append(row)
            print(json.dumps(row), file=sys.stderr)
        profile = {f"{sensor} {m}": profile_stages(sensor, m, "cross", args.frames,
                                                   os.path.join(tmp, f"profile-{sensor}-{m}"))
                   for sensor, m in (("gelsight_mini", "geometric"), ("gelsight_mini", "elastic"), ("gf225", "geometric"))}
        if args.split:  # last: the wrappers stay installed and slow every call a little
            clock = CompiledClock()
            clock.install()
            ceilings: dict[tuple[str, str, str], list[tuple[float, float]]] = {c: [] for c in configs}
            for k_pass in range(args.passes):  # interleaved, as the timed passes
                for sensor, method, gel in configs:
                    clock.seconds.clear()
                    out = os.path.join(tmp, f"{sensor}-{method}-{gel}-split-{k_pass}")
                    frames = sum(one(sensor, method, shape, args.frames, out, k, gel)["frames"]
                                 for k, shape in enumerate(shapes))
                    shutil.rmtree(out)
                    compiled_s = sum(clock.seconds.values())
                    ceilings[(sensor, method, gel)].append((1000 * compiled_s / frames, frames / compiled_s))
                    print(f"split pass {k_pass + 1}: {sensor} {method} {gel}: compiled "
                          f"{1000 * compiled_s / frames:.2f} ms a frame, "
                          f"ceiling {frames / compiled_s:.1f} frames/s/core", file=sys.stderr)
            for row, config in zip(rows, configs):  # the pass with the least compiled time: the highest ceiling
                compiled_ms, ceiling = min(ceilings[config])
                row["compiled_ms_per_frame"] = round(compiled_ms, 3)
                row["ceiling_frames_per_s_per_core"] = round(ceiling, 1)
                row["ceiling_frames_per_s_per_core_passes"] = [round(f, 1) for _, f in ceilings[config]]
    result = {
        "machine": machine(threads_used=1), "shapes": shapes, "frames_per_episode": args.frames,
        "passes": args.passes,
        "targets": {"geometric_frames_per_s": 100, "elastic_frames_per_s": 25,
                    "bytes_per_frame_max": round(UNIVTAC_BYTES_PER_FRAME / 5)},
        "univtac_bytes_per_frame": round(UNIVTAC_BYTES_PER_FRAME), "rows": rows,
        "time_share_cross": profile,
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "generate_throughput.json").write_text(json.dumps(result, indent=2) + "\n")
    chart(result, FIGURES / "generate_throughput.png")
    print(json.dumps(result, indent=2))


def chart(result: dict, path: os.PathLike[str]) -> None:  # type: ignore[type-arg]
    rows = result["rows"]
    labels = [f"{r['sensor']}\n{r['method']}" + (" (layer)" if r.get("gel") == "layer" else "") for r in rows]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(15, 4.8))
    colours = ["tab:blue" if r["method"] == "geometric" else "tab:green" if r.get("gel") == "layer" else "tab:orange"
               for r in rows]
    best = [r["frames_per_s_per_core"] for r in rows]
    slowest = [min(r.get("frames_per_s_per_core_passes", [b])) for r, b in zip(rows, best)]
    # bar: the best pass; whisker: down to the slowest pass
    ax1.bar(labels, best, color=colours, yerr=[np.subtract(best, slowest), np.zeros(len(rows))], capsize=3)
    ax1.axhline(result["targets"]["geometric_frames_per_s"], color="tab:blue", ls="--", lw=1, label="target, geometric")
    ax1.axhline(result["targets"]["elastic_frames_per_s"], color="tab:orange", ls="--", lw=1, label="target, elastic")
    if all("ceiling_frames_per_s_per_core" in r for r in rows):  # --split: what the compiled work alone allows
        ax1.scatter(labels, [r["ceiling_frames_per_s_per_core"] for r in rows], marker="_", s=600, color="black",
                    zorder=3, label="ceiling: compiled work only")
    ax1.set_ylabel("frames / s / core, end to end (best pass; whisker: slowest)")
    ax1.legend(fontsize=8, loc="upper center")
    ax1.tick_params(axis="x", labelsize=7)
    ax2.bar(labels, [r["bytes_per_frame"] / 1024 for r in rows], color=colours)
    ax2.axhline(result["targets"]["bytes_per_frame_max"] / 1024, color="k", ls="--", lw=1,
                label="target: UniVTAC / 5")
    ax2.set_ylabel("KiB per frame on disk (both pads, lossless)")
    ax2.legend(fontsize=8)
    ax2.tick_params(axis="x", labelsize=7)
    fig.suptitle(f"Indenter generation, one core ({result['machine']['cpu']})", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
