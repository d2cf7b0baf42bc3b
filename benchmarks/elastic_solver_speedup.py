"""The elastic contact solver against the one before its preconditioning, in the indenter generator, paired.

    OMP_NUM_THREADS=1 python benchmarks/elastic_solver_speedup.py [--passes 3]

The elastic rows of ``benchmarks/generate_throughput.py`` (every sensor, half-space and bonded layer; 14 indenter
shapes x 40 frames, generated, compressed and written; frames per CPU-second of the process, best of the
passes), each run twice in the same process, once with today's ``solve_elastic`` and once with the one at
``BASELINE_COMMIT`` (the Polonsky-Keer CG without a preconditioner, in array code), loaded from git and
swapped in. The passes interleave all rows and both solvers, so a slow spell of a shared machine falls on both.
Also the solves' mean iterations and CPU ms per call.

Writes benchmarks/results/elastic_solver_speedup.json and docs/figures/elastic_solver_speedup.png (``--replot``:
redraw the chart from the committed JSON).
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")  # one core, as the numbers claim

import argparse  # noqa: E402
import importlib.util  # noqa: E402
import json  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from pathlib import Path  # noqa: E402
from types import ModuleType  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

from common import FIGURES, RESULTS, ROOT, machine  # noqa: E402  (benchmarks/ is on sys.path when run as a script)
from generate_throughput import one, rate_of  # noqa: E402

import univtac_data.generators.tactile.contact_elastic as contact_elastic  # noqa: E402
from univtac_data.generators.allocator import keep_freed_memory  # noqa: E402
from univtac_data.generators.indenters.shapes import INDENTER_NAMES  # noqa: E402
from univtac_data.schema.sensors import SENSORS  # noqa: E402

BASELINE_COMMIT = "ccc2d50"  # main before the preconditioned solve
GELS = ("half_space", "layer")


def _module_at(commit: str, source_path: str, name: str) -> ModuleType:
    """The file ``source_path`` at ``commit``, loaded from git as ``univtac_data.generators.tactile.<name>``."""
    source = subprocess.run(["git", "show", f"{commit}:{source_path}"], cwd=ROOT, capture_output=True, text=True,
                            check=True).stdout
    path = Path(tempfile.mkdtemp()) / f"{name}.py"
    path.write_text(source)
    spec = importlib.util.spec_from_file_location(f"univtac_data.generators.tactile.{name}", path)
    module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    return module


def baseline_module(commit: str) -> ModuleType:
    """``generators/tactile/contact_elastic.py`` at ``commit`` with the influence coefficients of its time
    (``kernels.py`` at ``commit``); its other imports (contact types, sensor grid) are today's, which it shares."""
    kernels = _module_at(commit, "generators/tactile/kernels.py", "_baseline_kernels")
    module = _module_at(commit, "generators/tactile/contact_elastic.py", "_baseline_contact_elastic")
    module.kernel_set, module.convolve = kernels.kernel_set, kernels.convolve  # type: ignore[attr-defined]
    return module


def counted(solve: Callable[..., object], tally: dict[str, float]) -> Callable[..., object]:
    """``solve`` that adds its CPU seconds, iterations and calls to ``tally``."""
    def run(*args: object, **kwargs: object) -> object:
        start = time.process_time()
        result = solve(*args, **kwargs)
        tally["cpu_s"] += time.process_time() - start
        tally["iterations"] += result.iterations  # type: ignore[attr-defined]
        tally["calls"] += 1
        return result
    return run


def plot(result: dict[str, Any]) -> None:
    """Frames per CPU-second of each elastic row with the baseline and today's solver, side by side."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = result["rows"]
    labels = [f"{r['sensor']}\n{r['gel']}" for r in rows]
    x = np.arange(len(rows))
    fig, ax = plt.subplots(figsize=(9, 4))
    for offset, solver, label in ((-0.2, "baseline", f"before ({result['baseline_commit']})"), (0.2, "today", "today")):
        ax.bar(x + offset, [r[solver]["frames_per_s_per_core"] for r in rows], 0.4, label=label)
    for i, r in enumerate(rows):
        ax.text(i + 0.2, r["today"]["frames_per_s_per_core"], f"{r['speedup']:.2f}x", ha="center", va="bottom",
                fontsize=8)
    ax.set_xticks(x, labels, fontsize=8)
    ax.set_ylabel("frames / CPU-second, one core (best pass)")
    ax.set_title("Elastic indenter generation: the solver before and after preconditioning (paired passes)")
    ax.legend()
    fig.tight_layout()
    FIGURES.mkdir(parents=True, exist_ok=True)
    fig.savefig(FIGURES / "elastic_solver_speedup.png", dpi=120)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--passes", type=int, default=3)
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--replot", action="store_true", help="redraw the chart from the committed JSON")
    args = parser.parse_args()
    if args.replot:
        plot(json.loads((RESULTS / "elastic_solver_speedup.json").read_text()))
        return
    keep_freed_memory()  # as the generator's workers do
    solvers = {"baseline": baseline_module(BASELINE_COMMIT).solve_elastic, "today": contact_elastic.solve_elastic}
    configs = [(sensor, gel, solver) for sensor in SENSORS for gel in GELS for solver in solvers]
    rates: dict[tuple[str, str, str], list[float]] = {c: [] for c in configs}
    tallies = {c: {"cpu_s": 0.0, "iterations": 0, "calls": 0} for c in configs}
    original = contact_elastic.solve_elastic
    try:
        with tempfile.TemporaryDirectory() as tmp:
            for sensor, gel, solver in configs:  # untimed: numba's kernels built or loaded once per process
                contact_elastic.solve_elastic = solvers[solver]
                one(sensor, "elastic", INDENTER_NAMES[0], 3, os.path.join(tmp, "warm-up"), 10_000, gel)
                shutil.rmtree(os.path.join(tmp, "warm-up"), ignore_errors=True)
            for k_pass in range(args.passes):
                for config in configs:
                    sensor, gel, solver = config
                    contact_elastic.solve_elastic = counted(solvers[solver], tallies[config])  # type: ignore[assignment]
                    out = os.path.join(tmp, f"{sensor}-{gel}-{solver}")
                    runs = [one(sensor, "elastic", shape, args.frames, out, i, gel)
                            for i, shape in enumerate(INDENTER_NAMES)]
                    shutil.rmtree(out)
                    rates[config].append(rate_of(runs))
                    print(f"pass {k_pass + 1}: {sensor} {gel} {solver}: {rates[config][-1]:.1f} frames/s/core",
                          file=sys.stderr, flush=True)
    finally:
        contact_elastic.solve_elastic = original
    rows = []
    for sensor in SENSORS:
        for gel in GELS:
            row: dict[str, object] = {"sensor": sensor, "gel": gel}
            for solver in solvers:
                r, tally = rates[(sensor, gel, solver)], tallies[(sensor, gel, solver)]
                row[solver] = {"frames_per_s_per_core": round(max(r), 1), "passes": [round(x, 1) for x in r],
                               "median": round(float(np.median(r)), 1),
                               "solve_cpu_ms": round(1e3 * tally["cpu_s"] / max(tally["calls"], 1), 2),
                               "iterations_per_solve": round(tally["iterations"] / max(tally["calls"], 1), 1)}
            row["speedup"] = round(row["today"]["frames_per_s_per_core"]  # type: ignore[index]
                                   / row["baseline"]["frames_per_s_per_core"], 2)  # type: ignore[index]
            rows.append(row)
    result = {"machine": {**machine(threads_used=1, packages=("numpy", "scipy", "numba", "mujoco")),
                          "note": "shared 2-core machine: absolute rates are noisy, the paired ratios less so"},
              "baseline_commit": BASELINE_COMMIT, "shapes": list(INDENTER_NAMES), "frames_per_episode": args.frames,
              "passes": args.passes, "rows": rows}
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "elastic_solver_speedup.json").write_text(json.dumps(result, indent=2) + "\n")
    plot(result)
    print(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
