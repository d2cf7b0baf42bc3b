"""Which contact model is good enough to pretrain on: the encoder recipe (examples/pretrain_encoder.py) trained
with one budget on corpora made by each sensor and contact model, held-out linear-probe accuracy against the
one-core time it takes to generate the corpus.

    python benchmarks/encoder_contact_models.py [--episodes 10] [--frames 30] [--steps 800]
        [--sensors gelsight_mini,gf225,xense_ws] [--contacts geometric,elastic] [--work out/encoder_contact_models]
    python benchmarks/encoder_contact_models.py --replot     # the chart again, from the JSON

Every corpus has the same shapes, episodes and frames (a sensor's two corpora the same presses: an episode's seed
depends on the sensor, shape and index, not on the contact model); every encoder trains the same number of optimiser steps (not a wall-clock
budget: the machine may be shared), on one thread, and is probed on held-out episodes beside a random-init
encoder of the same architecture. Generation time is given two ways: the frames divided by the generator's
one-core rate for that sensor and model on a quiet machine (``benchmarks/results/generate_throughput.json``),
and the wall time measured here. Writes benchmarks/results/encoder_contact_models.json and
docs/figures/encoder_contact_models.png.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.ticker  # noqa: E402

from common import FIGURES, RESULTS, ROOT, machine  # noqa: E402

sys.path.insert(0, str(ROOT / "examples"))
import pretrain_encoder  # noqa: E402

NAME = "encoder_contact_models"


def one_core_rates() -> dict[tuple[str, str], float]:
    """(sensor, contact) -> frames per CPU-second of ``generate indenters`` (half-space gel), quiet machine."""
    rows = json.loads((RESULTS / "generate_throughput.json").read_text())["rows"]
    return {(r["sensor"], r["method"]): float(r["frames_per_s_per_core"]) for r in rows if r["gel"] == "half_space"}


def run_one(sensor: str, contact: str, args: argparse.Namespace) -> dict[str, Any]:
    out_dir = args.work / f"{sensor}-{contact}"
    result_path = out_dir / "result.json"
    if result_path.exists():  # resumable: a finished configuration is read back, not redone
        return json.loads(result_path.read_text())
    out_dir.mkdir(parents=True, exist_ok=True)
    result = pretrain_encoder.main([
        "--generate", str(args.episodes), "--frames", str(args.frames), "--sensor", sensor, "--contact", contact,
        "--out-dir", str(out_dir), "--steps", str(args.steps), "--threads", "1", "--seed", "0",
        "--log-every", "200", "--out-json", str(result_path)])
    return result


def summary(sensor: str, contact: str, result: dict[str, Any], rates: dict[tuple[str, str], float],
            frames: int) -> dict[str, Any]:
    trained, random_init = result["probe"]["trained"], result["probe"]["random_init"]
    rate = rates.get((sensor, contact))
    return {
        "sensor": sensor, "contact": contact, "corpus_frames": frames,
        "generate_one_core_s": frames / rate if rate else None, "generator_frames_per_s_per_core": rate,
        "generate_wall_s_here": result["seconds"]["generate"],
        "probe_accuracy": trained["accuracy"], "probe_episode_bootstrap95": trained["episode_bootstrap95"],
        "probe_wilson95": trained["wilson95"], "random_init_accuracy": random_init["accuracy"],
        "per_shape": trained["per_shape"], "pose_errors": result["trained_heads_errors"],
        "train_steps": result["steps"], "train_s": result["seconds"]["train"],
        "held_out_episodes": result["held_out_episodes"], "held_out_samples": result["held_out_samples"],
    }


def chart(rows: list[dict[str, Any]], path: Path) -> None:
    fig, ax = plt.subplots(figsize=(9.0, 4.6))
    markers = {"geometric": "o", "elastic": "s"}
    colours = {"gelsight_mini": "tab:blue", "gf225": "tab:orange", "xense_ws": "tab:green"}
    for r in rows:
        lo, hi = r["probe_episode_bootstrap95"]
        acc = 100 * r["probe_accuracy"]
        ax.errorbar(r["generate_one_core_s"], acc, yerr=[[acc - 100 * lo], [100 * hi - acc]],
                    fmt=markers[r["contact"]], color=colours.get(r["sensor"], "k"), capsize=3,
                    label=f"{r['sensor']}, {r['contact']}")
        ax.scatter([r["generate_one_core_s"]], [100 * r["random_init_accuracy"]], marker=markers[r["contact"]],
                   facecolors="none", edgecolors=colours.get(r["sensor"], "k"))
    ax.set_xscale("log")
    times = [r["generate_one_core_s"] for r in rows]
    ax.set_xlim(min(times) / 1.3, max(times) * 1.3)
    ax.xaxis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
    ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax.set_xticks([t for t in (10, 20, 30, 50, 100, 200, 500, 1000) if min(times) / 1.3 <= t <= max(times) * 1.3])
    ax.set_xlabel("one-core seconds to generate the corpus (log)")
    ax.set_ylabel("held-out 14-shape linear probe, %")
    ax.set_title("Pretraining corpus: contact model and sensor\n(filled: trained encoder, 95 % episode bootstrap; "
                 "hollow: random init)", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=10, help="episodes per shape")
    parser.add_argument("--frames", type=int, default=30, help="frames per episode")
    parser.add_argument("--steps", type=int, default=800, help="optimiser steps per encoder")
    parser.add_argument("--sensors", default="gelsight_mini,gf225,xense_ws")
    parser.add_argument("--contacts", default="geometric,elastic")
    parser.add_argument("--work", type=Path, default=Path("out/encoder_contact_models"))
    parser.add_argument("--replot", action="store_true", help="redraw the chart from the committed JSON only")
    args = parser.parse_args()
    if args.replot:
        chart(json.loads((RESULTS / f"{NAME}.json").read_text())["rows"], FIGURES / f"{NAME}.png")
        return
    rates = one_core_rates()
    frames = 14 * args.episodes * args.frames
    rows = []
    for sensor in args.sensors.split(","):
        for contact in args.contacts.split(","):
            print(f"== {sensor} {contact}", flush=True)
            rows.append(summary(sensor, contact, run_one(sensor, contact, args), rates, frames))
            print(f"   probe {100 * rows[-1]['probe_accuracy']:.1f} % (random init "
                  f"{100 * rows[-1]['random_init_accuracy']:.1f} %)", flush=True)
    result = {"machine": machine(threads_used=1, packages=("numpy", "torch", "mujoco")),
              "settings": {"episodes_per_shape": args.episodes, "frames_per_episode": args.frames,
                           "train_steps": args.steps, "image_size": [48, 64], "threads": 1},
              "command": "python benchmarks/encoder_contact_models.py " + " ".join(sys.argv[1:]), "rows": rows}
    (RESULTS / f"{NAME}.json").write_text(json.dumps(result, indent=1) + "\n")
    chart(rows, FIGURES / f"{NAME}.png")
    print(f"wrote {RESULTS / (NAME + '.json')} and {FIGURES / (NAME + '.png')}")


if __name__ == "__main__":
    main()
