"""How hard MuJoCo's pads press a held object against what the tactile model says for the same frames.

The task scenes hold objects with explicit pad-object contact pairs (``scene/contact_pairs.py``: one stiffness
for every sensor); the tactile model computes each pad's normal force from the gel's overlap with the object
(the images' ``normal_force_n``). This runs an expert recorded, and on every frame where both pads press
(tactile force over 0.05 N each) divides MuJoCo's summed normal force on the two pads (``scene.pad_forces``) by
the tactile model's: a ratio the same on every sensor means the pads' contact is not what sets one sensor
apart from another.

    python benchmarks/pad_force_ratio.py [--tasks lift_can,put_bottle_in_shelf] [--seeds 100,101,102]

Seeds from 100 up (development seeds, not the evaluation's). Writes benchmarks/results/pad_force_ratio.json and
docs/figures/pad_force_ratio.png.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "egl")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
from typing import Any  # noqa: E402

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from common import FIGURES, RESULTS, machine  # noqa: E402

from univtac_data.generators.scene.gripper import PADS  # noqa: E402
from univtac_data.generators.scene.pad_forces import pad_forces  # noqa: E402
from univtac_data.generators.tasks.base import TaskConfig  # noqa: E402
from univtac_data.generators.tasks.expert_rollout import expert_rollout  # noqa: E402
from univtac_data.generators.tasks.registry import TASK_NAMES, make_task  # noqa: E402
from univtac_data.schema.sensors import SENSORS  # noqa: E402

HELD_FORCE_N = 0.05  # a pad presses when the tactile model gives it more than this


def held_frames(task_name: str, sensor: str, seed: int) -> dict[str, Any]:
    """One recorded expert run: per held frame, the indentation (mm), MuJoCo's and the tactile model's normal
    force summed over both pads (N)."""
    task = make_task(task_name, TaskConfig(sensor=sensor, cameras=False))
    depth, mujoco_n, tactile_n = [], [], []
    with expert_rollout(task, seed, record=True) as run:
        sim = run.session.sim
        for step in run.steps():
            state = run.take(step)
            gel = [float(sim.frames[-1].tactile[pad].normal_force_n) for pad in PADS]
            if min(gel) > HELD_FORCE_N:
                pads = pad_forces(sim.model, sim.data)
                depth.append(state.indentation_mm)
                mujoco_n.append(sum(pads[pad].normal_n for pad in PADS))
                tactile_n.append(sum(gel))
    ratio = np.asarray(mujoco_n) / np.asarray(tactile_n)
    return {"task": task_name, "sensor": sensor, "seed": seed, "held_frames": len(ratio),
            "indentation_mm_median": float(np.median(depth)), "mujoco_n_median": float(np.median(mujoco_n)),
            "tactile_n_median": float(np.median(tactile_n)), "ratio_median": float(np.median(ratio)),
            "ratio_p10_p90": [float(np.percentile(ratio, 10)), float(np.percentile(ratio, 90))]}


def chart(rows: list[dict[str, Any]], tasks: list[str], sensors: list[str]) -> None:
    fig, axes = plt.subplots(1, len(tasks), figsize=(4.2 * len(tasks), 3.6), squeeze=False, sharey=True)
    for ax, task in zip(axes[0], tasks):
        for i, sensor in enumerate(sensors):
            mine = [r for r in rows if r["task"] == task and r["sensor"] == sensor]
            x = i + np.linspace(-0.2, 0.2, len(mine))
            med = [r["ratio_median"] for r in mine]
            lo = [r["ratio_median"] - r["ratio_p10_p90"][0] for r in mine]
            hi = [r["ratio_p10_p90"][1] - r["ratio_median"] for r in mine]
            ax.errorbar(x, med, yerr=[lo, hi], fmt="o", capsize=3)
        ax.axhline(1.0, color="#999999", lw=0.8, ls="--")
        ax.set_xticks(range(len(sensors)), [SENSORS[s].display_name for s in sensors], fontsize=8)
        ax.set_title(task, fontsize=9)
    axes[0][0].set_ylabel("MuJoCo pad force / tactile model force\n(median, 10-90 % of held frames; a dot a seed)",
                          fontsize=8)
    fig.tight_layout()
    fig.savefig(FIGURES / "pad_force_ratio.png", dpi=120)
    plt.close(fig)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", default="lift_can,put_bottle_in_shelf")
    parser.add_argument("--seeds", default="100,101,102")
    args = parser.parse_args()
    tasks = args.tasks.split(",")
    unknown = [t for t in tasks if t not in TASK_NAMES]
    if unknown:
        parser.error(f"unknown task(s) {', '.join(unknown)}; known: {', '.join(TASK_NAMES)}")
    seeds = [int(s) for s in args.seeds.split(",")]
    sensors = sorted(SENSORS)
    rows = []
    for task in tasks:
        for sensor in sensors:
            for seed in seeds:
                row = held_frames(task, sensor, seed)
                rows.append(row)
                print(f"{task} {sensor} seed {seed}: {row['held_frames']} held frames, indentation "
                      f"{row['indentation_mm_median']:.2f} mm, MuJoCo {row['mujoco_n_median']:.2f} N, tactile "
                      f"{row['tactile_n_median']:.2f} N, ratio {row['ratio_median']:.2f}", file=sys.stderr)
    out = {"machine": machine(), "held_force_n": HELD_FORCE_N, "rows": rows}
    (RESULTS / "pad_force_ratio.json").write_text(json.dumps(out, indent=1) + "\n")
    chart(rows, tasks, sensors)
    return 0


if __name__ == "__main__":
    sys.exit(main())
