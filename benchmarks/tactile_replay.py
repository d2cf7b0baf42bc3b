"""The tactile model alone, on the frames the task experts make: CPU ms a pad-frame and a fingerprint of every
output, for speed work that must not change the data.

    python benchmarks/tactile_replay.py [--tasks pull_out_key,insert_hdmi] [--seeds 1] [--repeats 5] [--name NAME]
                                        [--before OLDER.json]

Each task's expert runs once (no cameras) while ``simulate_frame``'s inputs are kept (the gap field inside its
box, the motion since contact onset, the contact state); then those calls are replayed ``--repeats`` times into
reused buffers, and the best pass's CPU time a call is the figure. Physics, the expert, writing and the gap
field are left out, so the rate does not drift with them: on this VM whole-episode rates spread 10-15 % between
passes, replayed tactile frames a few percent. ``sha256`` hashes every array and number each call returns
(images, micrometres, mask, pressure, markers, forces, slip): run the script at two commits (a ``git
worktree`` of the older one) and compare the JSONs: equal hashes mean the change kept the data bit for bit.
``--before`` takes the older run's JSON: each row then says whether its hash is the same, and the chart shows
both runs.

Writes benchmarks/results/NAME.json and docs/figures/NAME.png (``--name``, default tactile_replay).
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MUJOCO_GL", "egl")

import argparse  # noqa: E402
import hashlib  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from common import FIGURES, RESULTS, machine  # noqa: E402

from univtac_data.generators.allocator import keep_freed_memory  # noqa: E402
from univtac_data.generators.scene import sim as sim_module  # noqa: E402
from univtac_data.generators.tactile import GAP_FAR_MM, PixelBuffers  # noqa: E402
from univtac_data.generators.tactile import simulate_frame as tactile_frame  # noqa: E402
from univtac_data.generators.tasks.base import TaskConfig  # noqa: E402
from univtac_data.generators.tasks.collect import TaskEpisodeSpec, run_expert  # noqa: E402
from univtac_data.generators.tasks.registry import TASK_NAMES  # noqa: E402

DEFAULT_TASKS = "lift_bottle,put_bottle_in_shelf,insert_hole,insert_tube,insert_hdmi,pull_out_key"


@dataclass
class RecordedCall:
    """One ``simulate_frame`` call of a recorded episode: the gap inside its box (outside it reads GAP_FAR_MM)."""

    profile: Any
    shape: tuple[int, int]
    box: tuple[slice, slice]
    gap_in_box: np.ndarray
    kwargs: dict[str, Any]

    def gap(self) -> np.ndarray:
        gap = np.full(self.shape, GAP_FAR_MM)
        gap[self.box] = self.gap_in_box
        return gap


def record_calls(task: str, seeds: int) -> list[RecordedCall]:
    """Run the task's expert on ``seeds`` seeds and keep every tactile call's inputs."""
    calls: list[RecordedCall] = []
    original = sim_module.simulate_frame

    def keeping(profile: Any, gap: np.ndarray, **kwargs: Any) -> Any:
        box = kwargs.get("gap_box") or (slice(0, gap.shape[0]), slice(0, gap.shape[1]))
        calls.append(RecordedCall(profile, gap.shape, box, gap[box].copy(),
                                  {k: v for k, v in kwargs.items() if k not in ("out", "gap_box")}))
        return original(profile, gap, **kwargs)

    sim_module.simulate_frame = keeping
    try:
        for seed in range(seeds):
            run_expert(TaskEpisodeSpec(task, seed, TaskConfig(cameras=False)))
    finally:
        sim_module.simulate_frame = original
    return calls


def replay(calls: list[RecordedCall], repeats: int) -> dict[str, Any]:
    """CPU ms a call (best pass and every pass) and the SHA-256 of the outputs of the first pass."""
    gaps = [c.gap() for c in calls]
    h, w = calls[0].shape
    # a few buffer sets in turn, as an episode's rows would be, without its growing memory
    buffers = [PixelBuffers(**{name: np.empty(shape, dtype) for name, (shape, dtype) in PixelBuffers.layout(h, w).items()})
               for _ in range(4)]
    digest = hashlib.sha256()
    passes = []
    for rep in range(repeats):
        spent = 0.0
        for i, (call, gap) in enumerate(zip(calls, gaps)):
            start = time.process_time()
            frame = tactile_frame(call.profile, gap, out=buffers[i % len(buffers)], gap_box=call.box, **call.kwargs)
            spent += time.process_time() - start
            if rep == 0:
                for value in (frame.pure_rgb, frame.marked_rgb, frame.depth_um, frame.contact_mask, frame.pressure_mpa,
                              frame.markers_px, frame.shear_force_n, np.float64(frame.normal_force_n),
                              np.float64(frame.slip_mm)):
                    digest.update(np.ascontiguousarray(value).tobytes())
        passes.append(1000.0 * spent / len(calls))
    return {"calls": len(calls), "ms_per_call": min(passes), "ms_per_call_passes": passes, "sha256": digest.hexdigest()}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", default=DEFAULT_TASKS, help="comma-separated task names, or 'all'")
    parser.add_argument("--seeds", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--name", default="tactile_replay")
    parser.add_argument("--before", help="an earlier run's JSON to compare with (same tasks)")
    args = parser.parse_args()
    tasks = list(TASK_NAMES) if args.tasks == "all" else args.tasks.split(",")
    unknown = [t for t in tasks if t not in TASK_NAMES]
    if unknown:
        parser.error(f"unknown task(s) {unknown}; choose from {list(TASK_NAMES)}")
    before = {}
    if args.before:
        try:
            before = {r["task"]: r for r in json.loads(Path(args.before).read_text())["rows"]}
        except (OSError, ValueError, KeyError, TypeError) as err:
            parser.error(f"--before {args.before}: not a tactile_replay JSON ({err})")
    keep_freed_memory()  # as the generator's workers do
    rows = []
    for task in tasks:
        calls = record_calls(task, args.seeds)
        row = {"task": task, **replay(calls, args.repeats)}
        if task in before:
            row["before_ms_per_call"] = before[task]["ms_per_call"]
            row["same_as_before"] = before[task]["sha256"] == row["sha256"]
        rows.append(row)
        print(f"{task:20s} {row['calls']:5d} pad-frames  {row['ms_per_call']:.3f} ms each (best of {args.repeats})  "
              f"sha256 {row['sha256'][:16]}", file=sys.stderr)
    result = {"machine": machine(threads_used=1), "seeds": args.seeds, "repeats": args.repeats,
              "before": args.before, "rows": rows}
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / f"{args.name}.json").write_text(json.dumps(result, indent=1))
    fig, ax = plt.subplots(figsize=(7, 0.8 + 0.55 * len(rows)))
    ys = np.arange(len(rows))
    height = 0.4 if before else 0.7
    if before:
        ax.barh(ys + height / 2, [r.get("before_ms_per_call", np.nan) for r in rows], height, color="#bbbbbb",
                label=f"before ({os.path.basename(args.before)})")
    ax.barh(ys - height / 2 if before else ys, [r["ms_per_call"] for r in rows], height, color="#4c72b0",
            label="this run")
    for y, r in zip(ys, rows):
        y_now = y - height / 2 if before else y
        ax.plot([min(r["ms_per_call_passes"]), max(r["ms_per_call_passes"])], [y_now, y_now], color="black", lw=1)
        if "same_as_before" in r:
            ax.text(max(r["ms_per_call"], r["before_ms_per_call"]) * 1.02, y,
                    "same arrays" if r["same_as_before"] else "arrays differ", va="center", fontsize=8)
    ax.set_yticks(ys, [r["task"] for r in rows])
    longest = max(max(r["ms_per_call_passes"] + [r.get("before_ms_per_call", 0.0)]) for r in rows)
    ax.set_xlim(0, longest * 1.6)  # room for the labels and the legend right of the bars
    ax.legend(fontsize=8, loc="lower right")
    ax.set_xlabel("CPU ms per pad-frame, tactile model alone (best pass; line: every pass)")
    ax.set_title("Tactile model on replayed task frames (one core)")
    fig.tight_layout()
    FIGURES.mkdir(parents=True, exist_ok=True)
    fig.savefig(FIGURES / f"{args.name}.png", dpi=110)
    return 0


if __name__ == "__main__":
    sys.exit(main())
