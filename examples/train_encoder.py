"""Train the reference UniVTAC encoder on a univtac-data dataset, then probe its frozen features.

    python examples/train_encoder.py --data PATH [PATH ...]   # any indenter corpus
    python examples/train_encoder.py --demo                   # factory data in a temporary directory

Steps: (1) hold out whole episodes per shape (``EpisodeMeta.name``), deterministically by a hash of
the episode id; (2) train ``UniVTACEncoder`` (examples/univtac_encoder.py) on the others with the paper's
loss, logging the three terms; (3) save a reconstruction figure of held-out frames (input I_marked,
predicted and true I_pure and D, predicted and true markers); (4) fit a linear probe (softmax regression)
on frozen features of the training episodes to classify the shape, and report its accuracy on the
held-out episodes, beside the same probe on a randomly initialised encoder and chance; once over every
frame and once over the frames in contact (``--contact-mm``; frames before the grasp look alike for all
shapes).

``--demo`` uses the test factories, whose images do not depend on the shape name: the probe cannot beat
chance there; it is a smoke test of the pipeline. Real numbers need the indenter generator's corpus.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from univtac_encoder import UniVTACEncoder, univtac_loss  # noqa: E402

from univtac_data.loaders import Resize, TactileFrameDataset  # noqa: E402
from univtac_data.loaders.split import split_position  # noqa: E402
from univtac_data.storage import Dataset  # noqa: E402


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--data", nargs="+", help="dataset path(s); indenter episodes named by shape")
    p.add_argument("--demo", action="store_true", help="build a factory dataset instead of --data")
    p.add_argument("--demo-dir", type=Path, help="where --demo writes (default: a temporary directory)")
    p.add_argument("--demo-shapes", type=int, default=4, help="distinct shape names in the demo data")
    p.add_argument("--demo-episodes", type=int, default=3, help="episodes per demo shape")
    p.add_argument("--demo-frames", type=int, default=12, help="frames per demo episode")
    p.add_argument("--sensor", help="train on this sensor only (default: the first in the data)")
    p.add_argument("--steps", type=int, default=200, help="optimiser steps")
    p.add_argument("--batch-size", type=int, default=16)
    p.add_argument("--image-size", type=int, nargs=2, default=(72, 96), metavar=("H", "W"),
                   help="training resolution (area-resized from the sensor's)")
    p.add_argument("--lr", type=float, default=1e-3)
    p.add_argument("--workers", type=int, default=2, help="DataLoader worker processes")
    p.add_argument("--held-out", type=float, default=0.25, help="share of each shape's episodes held out")
    p.add_argument("--probe-steps", type=int, default=300, help="full-batch steps of the linear probe")
    p.add_argument("--contact-mm", type=float, default=0.01,
                   help="a frame is in contact when its depth map reaches this (the contact-only probe)")
    p.add_argument("--log-every", type=int, default=20)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--figure", type=Path, default=HERE.parent / "docs/figures/encoder_reconstruction.png")
    p.add_argument("--out-json", type=Path, help="write losses and probe accuracies here")
    args = p.parse_args(argv)
    if bool(args.data) == args.demo:
        p.error("give exactly one of --data PATH or --demo")
    return args


def build_demo(root: Path, shapes: int, episodes: int, frames: int) -> list[str]:
    """A factory dataset with ``shapes`` names x ``episodes`` episodes (tests/factories.py, repo only)."""
    sys.path.insert(0, str(HERE.parent / "tests"))
    from factories import make_episode

    from univtac_data.storage import DatasetWriter

    writer = DatasetWriter.open(root, storage="hdf5", sensors=["gelsight_mini"])
    for s in range(shapes):
        for e in range(episodes):
            k = s * episodes + e
            writer.add(make_episode("gelsight_mini", frames, f"shape{s}_ep{e}", seed=k, name=f"shape{s}"))
    return [str(root)]


def held_out_split(paths: list[str], sensor: str | None, fraction: float) -> tuple[str, list[str], list[str]]:
    """``(sensor, train_ids, held_out_ids)``: per shape name, the episodes with the smallest hash positions
    are held out (at least one when the shape has two or more episodes), so every shape is in both."""
    rows = [row for path in paths for row in Dataset.open(path).index.values()]
    sensor = sensor or sorted({r.sensor for r in rows})[0]
    by_name: dict[str, list[str]] = {}
    for row in rows:
        if row.sensor == sensor:
            by_name.setdefault(row.name, []).append(row.episode_id)
    train, held = [], []
    for ids in by_name.values():
        ids = sorted(ids, key=split_position)
        n_held = min(len(ids) - 1, max(1, round(fraction * len(ids)))) if len(ids) > 1 else 0
        held += ids[:n_held]
        train += ids[n_held:]
    if not held:
        raise SystemExit("no shape has two episodes: nothing to hold out for the probe")
    return sensor, sorted(train), sorted(held)


@torch.no_grad()
def features(models: dict[str, UniVTACEncoder], loader: torch.utils.data.DataLoader[Any], names: list[str]) \
        -> tuple[dict[str, torch.Tensor], torch.Tensor, torch.Tensor]:
    """({label: features (S, 512)}, labels (S,), max depth in mm (S,)) of every sample, each model in eval
    mode. One pass over the data serves every model (reading and resizing frames costs more than a forward
    pass)."""
    for model in models.values():
        model.eval()
    feats: dict[str, list[torch.Tensor]] = {label: [] for label in models}
    labels, depth = [], []
    for batch in loader:
        for label, model in models.items():
            feats[label].append(model.encode(batch["marked_rgb"]))
        labels.append(torch.tensor([names.index(n) for n in batch["name"]]))
        depth.append(batch["depth_mm"].flatten(1).amax(1))
    return {label: torch.cat(f) for label, f in feats.items()}, torch.cat(labels), torch.cat(depth)


def linear_probe(train: tuple[torch.Tensor, torch.Tensor], test: tuple[torch.Tensor, torch.Tensor],
                 n_classes: int, steps: int, seed: int) -> float:
    """Accuracy on ``test`` of softmax regression fitted on standardised ``train`` features."""
    torch.manual_seed(seed)
    mean, std = train[0].mean(0), train[0].std(0).clamp_min(1e-6)
    x_train, x_test = (train[0] - mean) / std, (test[0] - mean) / std
    probe = nn.Linear(x_train.shape[1], n_classes)
    opt = torch.optim.Adam(probe.parameters(), lr=1e-2, weight_decay=1e-3)
    for _ in range(steps):
        opt.zero_grad()
        nn.functional.cross_entropy(probe(x_train), train[1]).backward()
        opt.step()
    with torch.no_grad():
        return float((probe(x_test).argmax(1) == test[1]).float().mean())


def figure_indices(dataset: TactileFrameDataset, n: int) -> list[int]:
    """``n`` sample indices for the figure: from episodes of ``n`` different shapes spread over the sorted
    names, in each the first pad's frame three quarters of the way through (after the grasp, so the gel is
    in contact; evenly spaced dataset indices often land on frame 0, before contact)."""
    table = dataset.table
    by_name: dict[str, int] = {}
    for e, ref in enumerate(dataset.episodes):
        by_name.setdefault(ref.name, e)
    names = sorted(by_name)
    picks = [names[int(k)] for k in np.unique(np.linspace(0, len(names) - 1, min(n, len(names))).astype(int))]
    idx = []
    for name in picks:
        e = by_name[name]
        rows = np.flatnonzero(table.episode == e)
        target = (3 * int(table.frame[rows].max())) // 4
        idx.append(int(rows[np.argmin(np.abs(table.frame[rows] - target))]))
    return idx


def save_figure(model: UniVTACEncoder, dataset: TactileFrameDataset, path: Path, n: int = 4) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    idx = figure_indices(dataset, n)
    n = len(idx)  # fewer rows when there are fewer shapes
    batch = torch.utils.data.default_collate([dataset[int(k)] for k in idx])
    model.eval()
    with torch.no_grad():
        pred = model(batch["marked_rgb"])
    h, w = batch["marked_rgb"].shape[-2:]
    depth_max = float(max(batch["depth_mm"].max(), pred["depth_mm"].max(), 1e-3))
    titles = ["input I_marked", "pred I_pure", "true I_pure", "pred D (mm)", "true D (mm)", "markers"]
    fig, axes = plt.subplots(n, 6, figsize=(13, 2.1 * n), squeeze=False)
    for r in range(n):
        rgb = lambda t: t[r].permute(1, 2, 0).clamp(0, 1).numpy()  # noqa: E731
        panels = [rgb(batch["marked_rgb"]), rgb(pred["pure_rgb"]), rgb(batch["pure_rgb"]),
                  pred["depth_mm"][r, 0].numpy(), batch["depth_mm"][r, 0].numpy()]
        for c, image in enumerate(panels):
            axes[r, c].imshow(image, **({} if c < 3 else {"vmin": 0, "vmax": depth_max, "cmap": "viridis"}))
        to_px = lambda m: ((m[r] + 1) / 2 * torch.tensor([w - 1, h - 1])).numpy()  # noqa: E731
        axes[r, 5].imshow(rgb(batch["marked_rgb"]))
        true_px, pred_px = to_px(batch["markers"]), to_px(pred["markers"])
        axes[r, 5].scatter(true_px[:, 0], true_px[:, 1], s=6, c="lime", label="true")
        axes[r, 5].scatter(pred_px[:, 0], pred_px[:, 1], s=6, c="red", marker="x", label="pred")
        label = f"{batch['name'][r]}\n{batch['episode_id'][r]} {batch['pad'][r]} f{int(batch['frame'][r])}"
        axes[r, 0].set_ylabel(label, fontsize=7)
        for c in range(6):
            axes[r, c].set_xticks([])
            axes[r, c].set_yticks([])
            if r == 0:
                axes[r, c].set_title(titles[c], fontsize=9)
    axes[0, 5].legend(fontsize=6, loc="lower right")
    fig.suptitle("UniVTAC encoder reconstructions on held-out episodes", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    args = parse_args(argv)
    torch.manual_seed(args.seed)
    with tempfile.TemporaryDirectory(prefix="univtac-encoder-") as tmp:
        if args.demo:
            root = args.demo_dir or Path(tmp) / "demo"
            paths = build_demo(root, args.demo_shapes, args.demo_episodes, args.demo_frames)
        else:
            paths = [os.fspath(p) for p in args.data]
        return run(args, paths)


def run(args: argparse.Namespace, paths: list[str]) -> dict[str, Any]:
    sensor, train_ids, held_ids = held_out_split(paths, args.sensor, args.held_out)
    resize = Resize(*args.image_size)
    train = TactileFrameDataset(paths, sensors=sensor, episodes=train_ids, transform=resize)
    held = TactileFrameDataset(paths, sensors=sensor, episodes=held_ids, transform=resize)
    names = sorted(set(train.names) | set(held.names))
    n_markers = train[0]["markers"].shape[0]
    print(f"sensor {sensor}: {len(train_ids)} training episodes ({len(train)} pad samples), {len(held_ids)} "
          f"held out ({len(held)}); {len(names)} shapes; {n_markers} markers; images {tuple(args.image_size)}")
    loader = torch.utils.data.DataLoader(train, batch_size=args.batch_size, shuffle=True, drop_last=True,
                                         num_workers=args.workers, persistent_workers=args.workers > 0,
                                         generator=torch.Generator().manual_seed(args.seed))
    model = UniVTACEncoder(*args.image_size, n_markers)
    random_model = UniVTACEncoder(*args.image_size, n_markers)  # same architecture, never trained
    opt = torch.optim.AdamW(model.parameters(), lr=args.lr, weight_decay=1e-4)
    history: list[dict[str, float]] = []
    step, start = 0, time.perf_counter()
    while step < args.steps:
        for batch in loader:
            model.train()
            losses = univtac_loss(model(batch["marked_rgb"]), batch)
            opt.zero_grad()
            losses["total"].backward()
            opt.step()
            history.append({k: v.item() for k, v in losses.items()})
            step += 1
            if step % args.log_every == 0 or step in (1, args.steps):
                recent = history[-args.log_every:]
                mean = {k: sum(h[k] for h in recent) / len(recent) for k in recent[0]}
                print(f"step {step:5d}  total {mean['total']:.4f}  shape {mean['shape']:.4f}  "
                      f"contact {mean['contact']:.4f}  pose {mean['pose']:.4f}  ({time.perf_counter() - start:.0f} s)",
                      flush=True)
            if step >= args.steps:
                break
    window = max(1, min(args.log_every, len(history) // 2))
    train_seconds = time.perf_counter() - start
    first = {k: sum(h[k] for h in history[:window]) / window for k in history[0]}
    last = {k: sum(h[k] for h in history[-window:]) / window for k in history[0]}
    save_figure(model, held, args.figure)
    eval_loader = lambda ds: torch.utils.data.DataLoader(ds, batch_size=64, num_workers=0)  # noqa: E731
    probe_train_ds = TactileFrameDataset(paths, sensors=sensor, episodes=train_ids, transform=resize,
                                         fields=["marked_rgb", "depth_mm"])
    probe_held_ds = TactileFrameDataset(paths, sensors=sensor, episodes=held_ids, transform=resize,
                                        fields=["marked_rgb", "depth_mm"])
    encoders = {"trained": model, "random_init": random_model}
    f_train, y_train, d_train = features(encoders, eval_loader(probe_train_ds), names)
    f_held, y_held, d_held = features(encoders, eval_loader(probe_held_ds), names)

    def probe_all(train_mask: torch.Tensor, held_mask: torch.Tensor) -> dict[str, float]:
        """Probe accuracies (trained, random init) and the baselines, on the samples the masks keep."""
        if not held_mask.any() or not train_mask.any():
            return {}
        out = {label: linear_probe((f_train[label][train_mask], y_train[train_mask]),
                                   (f_held[label][held_mask], y_held[held_mask]), len(names), args.probe_steps,
                                   args.seed) for label in encoders}
        counts = torch.bincount(y_held[held_mask], minlength=len(names))
        return {**out, "chance": 1.0 / len(names), "majority": float(counts.max()) / int(held_mask.sum()),
                "held_samples": int(held_mask.sum())}

    # Every frame, and only frames in contact: before the grasp closes the gel is flat and the frames of
    # all shapes look alike, so they cap the all-frames accuracy below 1.
    accuracy = probe_all(torch.ones_like(y_train, dtype=torch.bool), torch.ones_like(y_held, dtype=torch.bool))
    accuracy_contact = probe_all(d_train >= args.contact_mm, d_held >= args.contact_mm)
    result = {"data": paths, "sensor": sensor, "steps": len(history), "image_size": list(args.image_size),
              "train_episodes": train_ids, "held_out_episodes": held_ids, "shapes": names,
              "loss_first": first, "loss_last": last,
              "probe_accuracy": accuracy, "probe_accuracy_contact": accuracy_contact,
              "contact_mm": args.contact_mm, "train_seconds": train_seconds,
              "seconds": time.perf_counter() - start, "figure": str(args.figure)}
    print(f"loss {first['total']:.4f} -> {last['total']:.4f} (mean of the first and last {window} steps)")
    for label, acc in (("all frames", accuracy), (f"frames in contact (>= {args.contact_mm} mm)", accuracy_contact)):
        if acc:
            print(f"linear probe on held-out episodes, {label} ({acc['held_samples']} samples): trained "
                  f"{acc['trained']:.3f}, random init {acc['random_init']:.3f}, chance {acc['chance']:.3f}, "
                  f"majority {acc['majority']:.3f}")
    if not all(math.isfinite(v) for v in last.values()):
        raise SystemExit("training diverged (non-finite loss)")
    if args.out_json:
        args.out_json.parent.mkdir(parents=True, exist_ok=True)
        args.out_json.write_text(json.dumps(result, indent=1) + "\n")
    return result


if __name__ == "__main__":
    main()
