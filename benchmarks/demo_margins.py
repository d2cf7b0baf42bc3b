"""How much room the demonstrations leave a policy: the expert's peak indentation against the gel's safe limit,
and how far the fingers close in one recorded step just before they touch.

A policy trained on the demonstrations learns when the fast close ends from what it sees. If it ends it one
recorded step late, each pad goes about half of one step's closing deeper than the expert's grasp (the
fingers close symmetrically), so the expert's margin divided by half a step's closing is how many steps of
timing error the grasp tolerates before it is unsafe. Reads datasets written by ``univtac-data generate task`` and writes
``benchmarks/results/demo_margins.json`` and ``docs/figures/demo_margins.png``.

    python benchmarks/demo_margins.py DATASET [DATASET ...]

Episodes that start with the object already held (no frame before both pads touch) have no approach and are
counted apart.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import FIGURES, RESULTS  # noqa: E402

from univtac_data.storage import Dataset, DatasetError  # noqa: E402


@dataclass(frozen=True)
class ApproachMargin:
    """One episode's first grasp: the peak indentation (mm, both pads, the whole episode), its margin to the
    safe limit (mm), and the fingers' closing over the recorded step before both pads touch (mm of opening;
    None when the episode starts in contact)."""

    peak_indentation_mm: float
    margin_mm: float
    closing_mm_per_step: float | None

    @property
    def late_steps_to_unsafe(self) -> float | None:
        """How many recorded steps late the fast close may end before a pad passes the safe limit: the margin
        over half a step's closing (None without an approach, inf when the fingers did not move)."""
        if self.closing_mm_per_step is None:
            return None
        per_pad_mm = self.closing_mm_per_step / 2
        return self.margin_mm / per_pad_mm if per_pad_mm > 0 else float("inf")


def approach_margin(opening_m: np.ndarray, normal_force_left_n: np.ndarray, normal_force_right_n: np.ndarray,
                    peak_indentation_mm: float, safe_indentation_mm: float) -> ApproachMargin:
    """The margin of one episode from its measured gripper opening (m, per frame), each pad's normal force (N,
    per frame) and its safety summary's peak indentation (mm)."""
    both = (np.asarray(normal_force_left_n) > 0) & (np.asarray(normal_force_right_n) > 0)
    first = int(np.argmax(both)) if both.any() else None
    closing = None
    if first is not None and first >= 2:
        closing = float((opening_m[first - 2] - opening_m[first - 1]) * 1000.0)
    return ApproachMargin(peak_indentation_mm, safe_indentation_mm - peak_indentation_mm, closing)


def json_number(value: float | None) -> float | None:
    """``value``, or None where JSON has no number (fingers that did not move give an infinite tolerance)."""
    return value if value is not None and np.isfinite(value) else None


def dataset_margins(path: Path) -> dict[str, object]:
    dataset = Dataset.open(path)
    if not dataset.episode_ids:
        raise SystemExit(f"{path}: the dataset has no episodes")
    margins = []
    task = rate = sensor = None
    for episode_id in dataset.episode_ids:
        with dataset.open_episode(episode_id) as handle:
            meta = handle.meta
            task, rate, sensor = meta.name, meta.nominal_rate_hz, meta.sensor
            safe = dataset.sensor(meta.sensor).safe_indentation_mm
            margins.append(approach_margin(handle.read("robot/gripper_width_m"),
                                           handle.read("tactile/left/normal_force_n"),
                                           handle.read("tactile/right/normal_force_n"),
                                           meta.safety.max_indentation_mm, safe))
    approached = [m for m in margins if m.closing_mm_per_step is not None]
    late = [m.late_steps_to_unsafe for m in approached]
    return {
        "dataset": path.name, "task": task, "sensor": sensor, "rate_hz": rate, "episodes": len(margins),
        "safe_indentation_mm": safe,
        "peak_indentation_mm": {"median": statistics.median(m.peak_indentation_mm for m in margins),
                                "max": max(m.peak_indentation_mm for m in margins)},
        "margin_mm": {"median": statistics.median(m.margin_mm for m in margins),
                      "min": min(m.margin_mm for m in margins)},
        "episodes_starting_in_contact": len(margins) - len(approached),
        "closing_mm_per_step": ({"median": statistics.median(m.closing_mm_per_step for m in approached),  # type: ignore[type-var]
                                 "max": max(m.closing_mm_per_step for m in approached)}  # type: ignore[type-var]
                                if approached else None),
        "late_steps_to_unsafe": ({"median": json_number(statistics.median(late)), "min": json_number(min(late))}
                                 if late else None),
        "one_step_late_unsafe": sum(1 for steps in late if steps < 1),
        "two_steps_late_unsafe": sum(1 for steps in late if steps < 2),
        "per_episode": [{**asdict(m), "late_steps_to_unsafe": json_number(m.late_steps_to_unsafe)} for m in margins],
    }


def chart(rows: list[dict[str, object]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.0), dpi=120)
    top = 0.0
    for row in rows:
        points = [(e["closing_mm_per_step"] / 2, e["margin_mm"]) for e in row["per_episode"]  # type: ignore[attr-defined]
                  if e["closing_mm_per_step"] is not None]
        if not points:
            continue
        x, y = zip(*points)
        top = max(top, *x, *y)
        ax.scatter(x, y, s=12, alpha=0.7, label=f"{row['task']} ({row['rate_hz']:g} Hz)")
    for steps, style in ((1, "--"), (2, ":")):
        ax.plot([0, top * 1.05 / steps], [0, top * 1.05], color="0.4", lw=1, ls=style)
        ax.text(top * 1.05 / steps, top * 1.05, f"{steps} step{'s' if steps > 1 else ''} late", ha="center",
                va="bottom", fontsize=8, color="0.3")
    ax.set_xlabel("half the fingers' closing in the step before contact (mm per pad)")
    ax.set_ylabel("expert's margin to the safe indentation (mm)")
    ax.set_xlim(left=0)
    ax.set_ylim(bottom=0)
    ax.set_title("Room the demonstrations leave a policy (one point an episode)", fontsize=9)
    ax.legend(frameon=False, fontsize=8)
    ax.spines[["top", "right"]].set_visible(False)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)


def _steps(value: float | None) -> str:
    return "no number of" if value is None else f"{value:.2f}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("datasets", nargs="+", type=Path)
    parser.add_argument("--json", type=Path, default=RESULTS / "demo_margins.json")
    parser.add_argument("--chart", type=Path, default=FIGURES / "demo_margins.png")
    args = parser.parse_args(argv)
    try:
        rows = [dataset_margins(path) for path in args.datasets]
    except DatasetError as error:  # a missing or damaged dataset: one line naming it, no traceback
        raise SystemExit(f"demo_margins: {error}") from None
    for row in rows:
        closing = row["closing_mm_per_step"]
        print(f"{row['task']}: peak {row['peak_indentation_mm']['median']:.2f} mm median "  # type: ignore[index]
              f"(max {row['peak_indentation_mm']['max']:.2f}) of {row['safe_indentation_mm']} safe; "  # type: ignore[index]
              + (f"closing {closing['median']:.2f} mm a step before contact; "  # type: ignore[index]
                 f"{_steps(row['late_steps_to_unsafe']['median'])} steps late is unsafe (median; "  # type: ignore[index]
                 f"under one step in {row['one_step_late_unsafe']}, under two in {row['two_steps_late_unsafe']} "
                 f"of {row['episodes']})"
                 if closing else "every episode starts in contact"))
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"rows": rows}, indent=1, allow_nan=False) + "\n")
    chart(rows, args.chart)
    print(f"wrote {args.json} and {args.chart}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
