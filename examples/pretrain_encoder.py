"""The encoder pretraining recipe: a tactile encoder that knows shape, contact and pose, in about an hour on a
laptop CPU, checked by linear probes on held-out episodes.

    python examples/pretrain_encoder.py --generate 40 --out-dir out/encoder_recipe   # make the corpus, train, probe
    python examples/pretrain_encoder.py --data out/indenters                          # an existing corpus

Steps:

1. Corpus: ``--generate N`` runs ``univtac-data generate indenters`` (N episodes per shape, one sensor, 14
   shapes) into ``OUT_DIR/corpus``; or ``--data PATH``. The frames in contact (peak depth >= ``--contact-mm``;
   before the grasp closes the gel is flat and every shape looks alike) are read once, area-resized to
   ``--image-size`` (the reconstruction targets at ``--target-size``) and cached beside the corpus.
2. Split by episode: per shape, a share ``--held-out`` of the episodes (smallest hash of the episode id) is
   held out; no frame of a held-out episode is used for training the encoder or fitting a probe.
   ``--train-episodes N`` trains on at most N of the others per shape (the held-out ones stay the same);
   ``--split-seed S`` hashes with another seed, holding out other episodes.
3. Train ``TactileEncoder`` (examples/tactile_encoder.py) with the three pathways: shape (I_pure
   reconstruction weighted toward the contact region, plus an episode-contrastive term between two augmented
   frames of one episode, the second turned by any angle so that the imprint's orientation cannot tell
   episodes apart: ``--rotate-deg``, ``--consistency-weight``), contact (D weighted toward the contact, markers M, peak depth) and pose (indenter
   position in the pad frame, and yaw modulo the shape's rotational symmetry, measured on the indenter
   definitions; dropped for round shapes).
4. Probe the frozen features of the trained encoder and of a random-init encoder of the same architecture:
   14-shape softmax regression (accuracy with a Wilson interval over frames and a bootstrap interval over
   held-out episodes), and ridge regressions for position (mm), symmetry-aware yaw (deg) and peak contact
   depth (mm). Writes a JSON result, a chart, and a checkpoint.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import pickle
import platform
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.nn import functional as F

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from tactile_encoder import (  # noqa: E402
    POOLS,
    Augment,
    EncoderConfig,
    RecipeWeights,
    TactileEncoder,
    indenter_in_pad,
    recipe_loss,
    rotational_symmetry,
    yaw_error_deg,
    yaw_target,
)

from univtac_data.loaders.split import split_position  # noqa: E402
from univtac_data.storage import Dataset  # noqa: E402
from univtac_data.storage.errors import DatasetError  # noqa: E402

PADS = ("left", "right")


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--data", type=Path, help="an indenter corpus (univtac-data generate indenters)")
    src.add_argument("--generate", type=int, metavar="N", help="generate N episodes per shape into OUT_DIR/corpus")
    src.add_argument("--table", type=Path, metavar="JSON", help="print the Markdown results table of a result file")
    p.add_argument("--out-dir", type=Path, default=Path("out/encoder_recipe"), help="corpus, cache, checkpoint")
    p.add_argument("--sensor", default="gelsight_mini")
    p.add_argument("--shapes", default="all", help="with --generate: all, or a comma-separated list")
    p.add_argument("--frames", type=int, default=40, help="with --generate: frames per episode")
    p.add_argument("--gen-workers", type=int, default=1, help="with --generate: worker processes")
    p.add_argument("--contact", default="geometric", choices=("geometric", "elastic"),
                   help="with --generate: the contact model")
    p.add_argument("--image-size", type=int, nargs=2, default=(48, 64), metavar=("H", "W"),
                   help="the encoder's input (marked image)")
    p.add_argument("--target-size", type=int, nargs=2, metavar=("H", "W"),
                   help="I_pure and D reconstruction targets (default: --image-size)")
    p.add_argument("--contact-mm", type=float, default=0.01, help="a frame is in contact at this peak depth")
    p.add_argument("--held-out", type=float, default=0.25, help="share of each shape's episodes held out")
    p.add_argument("--train-episodes", type=int, metavar="N",
                   help="train the encoder and fit the probes on at most N episodes per shape (default: all "
                        "that are not held out; the held-out episodes do not change)")
    p.add_argument("--split-seed", type=int, default=0,
                   help="seed of the episode-id hash that chooses the held-out episodes (default 0); another "
                        "seed measures the same recipe on other held-out episodes")
    p.add_argument("--steps", type=int, default=5000, help="optimiser steps (at most, with --max-minutes)")
    p.add_argument("--max-minutes", type=float, help="wall-clock budget of the training loop")
    p.add_argument("--batch-size", type=int, default=64)
    p.add_argument("--lr", type=float, default=2e-3)
    p.add_argument("--pool", default="avgmax", choices=POOLS,
                   help="features: global average of the last map, or average and maximum side by side")
    p.add_argument("--widths", type=int, nargs="+", default=list(EncoderConfig.widths),
                   help="channels of the encoder's stages (the last is the feature size per pooling)")
    p.add_argument("--space-to-depth", type=int, default=1, metavar="F",
                   help="feed the input's F x F pixel blocks as channels (2: 96 x 128 at the cost of 48 x 64)")
    p.add_argument("--consistency-weight", type=float, default=2.0,
                   help="weight of the episode-contrastive term")
    p.add_argument("--rotate-deg", type=float, default=180.0,
                   help="turn the consistency view by up to this many degrees either way (180: any turn)")
    p.add_argument("--temperature", type=float, default=RecipeWeights.temperature,
                   help="temperature of the episode-contrastive term")
    p.add_argument("--threads", type=int, default=2, help="torch CPU threads")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--log-every", type=int, default=50)
    p.add_argument("--out-json", type=Path, help="write the result here")
    p.add_argument("--figure", type=Path, help="write the probe chart here")
    args = p.parse_args(argv)
    sizes = [*args.image_size, *(args.target_size or ())]
    if min(sizes) < 1:
        p.error(f"--image-size and --target-size must be positive (got {' '.join(map(str, sizes))})")
    if args.space_to_depth < 1 or args.image_size[0] % args.space_to_depth or args.image_size[1] % args.space_to_depth:
        p.error(f"--space-to-depth {args.space_to_depth}: must be a positive divisor of --image-size "
                f"{args.image_size[0]} x {args.image_size[1]}")
    if args.train_episodes is not None and args.train_episodes < 1:
        p.error(f"--train-episodes must be at least 1 (got {args.train_episodes})")
    return args


# ----------------------------------------------------------------------------------------------- corpus

def generate_corpus(out: Path, sensor: str, episodes: int, frames: int, shapes: str, workers: int,
                    contact: str) -> tuple[Path, float]:
    """Run the corpus generator (resumable: an interrupted run picks up where it stopped). Returns the path
    and the wall time in s."""
    cmd = [sys.executable, "-m", "univtac_data.cli.main", "generate", "indenters", "--out", str(out),
           "--sensor", sensor,
           "--shapes", shapes, "--episodes-per-shape", str(episodes), "--frames-per-episode", str(frames),
           "--workers", str(workers), "--contact", contact]
    start = time.perf_counter()
    subprocess.run(cmd, check=True)
    return out, time.perf_counter() - start


@dataclass
class Corpus:
    """The frames in contact of one sensor's episodes, at training resolution, as tensors (N samples, one per
    frame and pad). ``episode`` indexes ``episode_ids``; ``label`` indexes ``shapes``."""

    marked: torch.Tensor    # (N, 3, H, W) uint8, the encoder's input
    pure: torch.Tensor      # (N, 3, h, w) uint8, at the reconstruction target's size
    depth: torch.Tensor     # (N, 1, h, w) float16, mm
    markers: torch.Tensor   # (N, M, 2) float32 in [-1, 1]
    peak: torch.Tensor      # (N,) float32, peak depth mm (native resolution)
    position: torch.Tensor  # (N, 3) float32, indenter in the pad frame, mm
    yaw: torch.Tensor       # (N,) float32, indenter yaw in the pad frame, rad
    order: torch.Tensor     # (N,) int64, rotational symmetry order of the shape (0: round)
    label: torch.Tensor     # (N,) int64
    episode: torch.Tensor   # (N,) int64
    frame: torch.Tensor     # (N,) int64
    pad: torch.Tensor       # (N,) int64, index into PADS
    episode_ids: list[str]
    shapes: list[str]

    def subset(self, mask: torch.Tensor) -> dict[str, torch.Tensor]:
        return {k: v[mask] for k, v in self.as_dict().items() if isinstance(v, torch.Tensor)}

    def as_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}  # dataclasses.asdict would deep-copy


def load_corpus(path: Path, sensor: str, size: tuple[int, int], contact_mm: float, cache: Path | None = None,
                target_size: tuple[int, int] | None = None) -> Corpus:
    """Read the frames in contact of ``sensor``'s episodes (cached in ``cache`` when given): the marked image
    at ``size``, the reconstruction targets (I_pure, D) at ``target_size`` (default: ``size``)."""
    target = tuple(target_size or size)
    ds = Dataset.open(path)
    ids = sorted(e for e, row in ds.index.items() if row.sensor == sensor)
    if not ids:
        raise SystemExit(f"{path}: no episode of sensor {sensor}")
    # the episodes' digests (index only): a corpus regenerated into the same directory is read again
    key = [str(path), sensor, list(size), contact_mm, list(target), [[e, ds.index[e].sha256] for e in ids]]
    if cache is not None and cache.exists():
        try:
            data = torch.load(cache, weights_only=False)
        except (OSError, RuntimeError, EOFError, pickle.UnpicklingError) as err:  # a cache is only ever a copy
            print(f"the cache {cache} is unreadable ({err}): reading the corpus again", flush=True)
            data = {"key": None}
        if data["key"] == key:
            return Corpus(**data["corpus"])
    _large_buffers_to_mmap()
    shapes = sorted({ds.index[e].name for e in ids})
    parts: dict[str, list[torch.Tensor]] = {}
    for e, eid in enumerate(ids):
        # a handle reads only the arrays asked for (load_episode decodes every array of the episode)
        with ds.open_episode(eid) as handle:
            _read_episode(handle, e, shapes, size, target, contact_mm, parts)
        if (e + 1) % 50 == 0:
            print(f"read {e + 1}/{len(ids)} episodes", flush=True)
    corpus = Corpus(**{k: torch.cat(v) for k, v in parts.items()}, episode_ids=ids, shapes=shapes)
    if cache is not None:
        cache.parent.mkdir(parents=True, exist_ok=True)
        part = cache.with_name(cache.name + ".part")  # a killed run leaves no half-written cache
        torch.save({"key": key, "corpus": corpus.as_dict()}, part)
        os.replace(part, cache)
    return corpus


def _large_buffers_to_mmap() -> None:
    """Have glibc serve buffers over 1 MiB by mmap: reading decodes tens of MB of frames per episode, and
    with the default (adaptive) threshold the freed buffers fragmented the heap, which grew by ~30 MB an
    episode (22 GB and an OOM kill for 420 episodes). No effect off glibc."""
    try:
        import ctypes
        libc = ctypes.CDLL("libc.so.6")
        libc.mallopt(-3, 1 << 20)  # M_MMAP_THRESHOLD
        libc.mallopt(-1, 1 << 20)  # M_TRIM_THRESHOLD
    except (OSError, AttributeError):
        pass


def _read_episode(handle: Any, e: int, shapes: list[str], size: tuple[int, int], target: tuple[int, ...],
                  contact_mm: float, parts: dict[str, list[torch.Tensor]]) -> None:
    """Append the frames in contact of one episode (both pads) to ``parts``: the marked image at ``size``,
    I_pure and D at ``target``."""
    shape = handle.meta.name
    yaw0 = float(handle.meta.generator.settings["yaw_rad"])
    for p, pad in enumerate(PADS):
        depth_um = handle.read(f"tactile/{pad}/depth_um")
        peak = depth_um.reshape(len(depth_um), -1).max(1) / 1000.0
        keep = np.flatnonzero(peak >= contact_mm)
        if not len(keep):
            continue
        pose = handle.read(f"tactile/{pad}/object_pose")[keep].astype(np.float64)
        pose[:, :3] *= 1000.0  # m -> mm
        position, yaw = indenter_in_pad(pose, pad, yaw0)
        native_h, native_w = depth_um.shape[1:3]
        def resize(a: np.ndarray, hw: tuple[int, ...]) -> torch.Tensor:
            return F.interpolate(torch.from_numpy(a).float(), size=tuple(hw), mode="area")

        images = {k: resize(np.moveaxis(handle.read(f"tactile/{pad}/{k}")[keep], -1, 1), hw).round().to(torch.uint8)
                  for k, hw in (("marked_rgb", size), ("pure_rgb", target))}
        markers = handle.read(f"tactile/{pad}/markers_px")[keep].astype(np.float32)
        markers = markers * np.array([2.0 / (native_w - 1), 2.0 / (native_h - 1)], np.float32) - 1.0
        n = len(keep)
        new = {
            "marked": images["marked_rgb"], "pure": images["pure_rgb"],
            "depth": resize(depth_um[keep][:, None].astype(np.float32) / 1000.0, target).half(),
            "markers": torch.from_numpy(markers), "peak": torch.from_numpy(peak[keep].astype(np.float32)),
            "position": torch.from_numpy(position.astype(np.float32)),
            "yaw": torch.from_numpy(yaw.astype(np.float32)),
            "order": torch.full((n,), rotational_symmetry(shape), dtype=torch.int64),
            "label": torch.full((n,), shapes.index(shape), dtype=torch.int64),
            "episode": torch.full((n,), e, dtype=torch.int64), "frame": torch.from_numpy(keep.astype(np.int64)),
            "pad": torch.full((n,), p, dtype=torch.int64),
        }
        for k, v in new.items():
            parts.setdefault(k, []).append(v)


def held_out_split(episode_ids: list[str], shapes_of: list[str], fraction: float, max_train: int | None = None,
                   split_seed: int = 0) -> tuple[list[str], list[str]]:
    """``(train_ids, held_ids)``: per shape, the episodes with the smallest hash positions are held out (at
    least one when the shape has two or more), so every shape is on both sides; disjoint by construction.
    ``max_train``: keep at most this many training episodes per shape (the next ones in hash order), so
    training on fewer episodes can be measured against the same held-out episodes. ``split_seed``: another
    seed of the hash (``loaders.split.split_position``) holds out other episodes, to see how much a result
    depends on which episodes it was measured on."""
    by_shape: dict[str, list[str]] = {}
    for eid, shape in zip(episode_ids, shapes_of):
        by_shape.setdefault(shape, []).append(eid)
    train, held = [], []
    for ids in by_shape.values():
        ids = sorted(ids, key=lambda eid: split_position(eid, split_seed))
        n_held = min(len(ids) - 1, max(1, round(fraction * len(ids)))) if len(ids) > 1 else 0
        held += ids[:n_held]
        train += ids[n_held:] if max_train is None else ids[n_held:n_held + max_train]
    return sorted(train), sorted(held)


def split_masks(corpus: Corpus, fraction: float, max_train: int | None = None, split_seed: int = 0) \
        -> tuple[torch.Tensor, torch.Tensor, list[str], list[str]]:
    """Sample masks (train, held out) of ``corpus`` by episode, and the episode ids on each side (with
    ``max_train``, the samples of the training episodes left out are in neither mask)."""
    first = {int(e): int(lab) for e, lab in zip(corpus.episode.tolist(), corpus.label.tolist())}
    present = sorted(first)
    ids = [corpus.episode_ids[e] for e in present]
    train_ids, held_ids = held_out_split(ids, [corpus.shapes[first[e]] for e in present], fraction, max_train,
                                         split_seed)
    position = {eid: i for i, eid in enumerate(corpus.episode_ids)}

    def mask(side: list[str]) -> torch.Tensor:
        return torch.isin(corpus.episode, torch.tensor([position[e] for e in side], dtype=torch.int64))

    return mask(train_ids), mask(held_ids), train_ids, held_ids


# ----------------------------------------------------------------------------------------------- training

def to_batch(corpus: Corpus, idx: torch.Tensor) -> dict[str, torch.Tensor]:
    return {"marked_rgb": corpus.marked[idx].float() / 255.0, "pure_rgb": corpus.pure[idx].float() / 255.0,
            "depth_mm": corpus.depth[idx].float(), "markers": corpus.markers[idx], "peak_depth_mm": corpus.peak[idx],
            "position_mm": corpus.position[idx], "yaw_rad": corpus.yaw[idx], "order": corpus.order[idx],
            "episode": corpus.episode[idx]}


def partners(corpus: Corpus, idx: torch.Tensor, gen: torch.Generator) -> torch.Tensor:
    """For each sample, another sample of the same episode (either pad, any frame in contact)."""
    order = torch.argsort(corpus.episode, stable=True)
    starts = torch.searchsorted(corpus.episode[order], corpus.episode[idx])
    ends = torch.searchsorted(corpus.episode[order], corpus.episode[idx], right=True)
    pick = starts + (torch.rand(len(idx), generator=gen) * (ends - starts)).long()
    return order[pick]


def make_model(corpus: Corpus, train_mask: torch.Tensor, size: tuple[int, int], seed: int,
               widths: tuple[int, ...] = EncoderConfig.widths, pool: str = "avg", space_to_depth: int = 1) \
        -> TactileEncoder:
    """A new encoder for ``corpus`` (input ``size``; the decoder's output is the size of the corpus's
    I_pure), its input normalisation taken from training images."""
    torch.manual_seed(seed)
    target = tuple(corpus.pure.shape[-2:])
    model = TactileEncoder(EncoderConfig(height=size[0], width=size[1], n_markers=corpus.markers.shape[1],
                                         widths=tuple(widths), pool=pool, space_to_depth=space_to_depth,
                                         **({} if target == tuple(size) else
                                            {"target_height": target[0], "target_width": target[1]})))
    images = corpus.marked[train_mask][:2000].float() / 255.0
    model.mean.copy_(images.mean((0, 2, 3)).view(1, 3, 1, 1))
    model.std.copy_(images.std((0, 2, 3)).clamp_min(1e-3).view(1, 3, 1, 1))
    return model


def learning_rate(lr: float, progress: float, warmup: float = 0.05) -> float:
    """Linear warm-up over the first ``warmup`` of training, then a cosine decay to zero at ``progress`` 1."""
    if progress < warmup:
        return lr * (0.1 + 0.9 * progress / warmup)
    return lr * 0.5 * (1 + math.cos(math.pi * min(1.0, (progress - warmup) / (1 - warmup))))


def train(model: TactileEncoder, corpus: Corpus, train_mask: torch.Tensor, steps: int, batch_size: int, lr: float,
          seed: int, log_every: int = 50, augment: Augment = Augment(), weights: RecipeWeights = RecipeWeights(),
          max_minutes: float | None = None) -> list[dict[str, float]]:
    """Train in place; returns the loss terms of every step. With ``max_minutes`` the schedule runs on
    whichever ends first, the steps or the wall-clock budget (the learning rate still anneals to zero, so
    a slower machine trains fewer steps but a finished schedule; the steps done are in the history)."""
    gen = torch.Generator().manual_seed(seed)
    pool = torch.nonzero(train_mask).flatten()
    opt = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=1e-4)
    history: list[dict[str, float]] = []
    start = time.perf_counter()
    model.train()
    progress = 0.0
    step = 0
    while progress < 1.0:
        step += 1
        for group in opt.param_groups:
            group["lr"] = learning_rate(lr, progress)
        idx = pool[torch.randint(len(pool), (batch_size,), generator=gen)]
        batch = to_batch(corpus, idx)
        view1 = augment.photometric(batch["marked_rgb"], gen)
        view2_idx = partners(corpus, idx, gen)
        view2 = augment.rotate(augment.shift(augment.photometric(corpus.marked[view2_idx].float() / 255.0, gen),
                                             gen), gen)
        pred = model(view1)
        view2_embedding = model.projection(model.encode(view2))
        losses = recipe_loss(pred, batch, view2_embedding, weights)
        opt.zero_grad()
        losses["total"].backward()
        opt.step()
        history.append({k: v.item() for k, v in losses.items()})
        progress = step / steps
        if max_minutes is not None:
            progress = max(progress, (time.perf_counter() - start) / (60 * max_minutes))
        if step % log_every == 0 or step == 1 or progress >= 1.0:
            recent = history[-log_every:]
            mean = {k: sum(h[k] for h in recent) / len(recent) for k in recent[0]}
            print(f"step {step:5d}  " + "  ".join(f"{k} {v:.4f}" for k, v in mean.items())
                  + f"  lr {opt.param_groups[0]['lr']:.2e}  ({time.perf_counter() - start:.0f} s)", flush=True)
    return history


def save_checkpoint(model: TactileEncoder, path: Path, shapes: list[str]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save({"config": model.config.to_dict(), "state_dict": model.state_dict(), "shapes": shapes,
                "symmetry": {s: rotational_symmetry(s) for s in shapes}}, path)


def load_checkpoint(path: Path) -> TactileEncoder:
    """The encoder saved by ``save_checkpoint``, in eval mode."""
    data = torch.load(path, weights_only=False)
    config = {**data["config"], "widths": tuple(data["config"]["widths"])}
    model = TactileEncoder(EncoderConfig(**config))
    model.load_state_dict(data["state_dict"])
    return model.eval()


# ----------------------------------------------------------------------------------------------- probes

@torch.no_grad()
def encode_all(model: TactileEncoder, corpus: Corpus, batch: int = 512) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """Features (N, F) of every sample and the model's own head outputs (eval mode, no augmentation)."""
    model.eval()
    feats, heads = [], {"position_mm": [], "yaw_cs": [], "peak_depth_mm": []}
    for s in range(0, len(corpus.label), batch):
        out = model(corpus.marked[s:s + batch].float() / 255.0)
        feats.append(out["features"])
        for k in heads:
            heads[k].append(out[k])
    return torch.cat(feats), {k: torch.cat(v) for k, v in heads.items()}


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson score interval of a proportion k / n."""
    if n == 0:
        return (float("nan"), float("nan"))
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return (centre - half, centre + half)


def episode_bootstrap(correct: torch.Tensor, episode: torch.Tensor, reps: int = 2000, seed: int = 0) \
        -> tuple[float, float]:
    """95 % interval of the accuracy, resampling whole held-out episodes (frames of one episode are
    correlated, so a frame-level interval is too narrow)."""
    eps, inverse = torch.unique(episode, return_inverse=True)
    hits = torch.zeros(len(eps)).index_add_(0, inverse, correct.float())
    counts = torch.zeros(len(eps)).index_add_(0, inverse, torch.ones_like(correct, dtype=torch.float))
    gen = torch.Generator().manual_seed(seed)
    pick = torch.randint(len(eps), (reps, len(eps)), generator=gen)
    acc = hits[pick].sum(1) / counts[pick].sum(1)
    return float(torch.quantile(acc, 0.025)), float(torch.quantile(acc, 0.975))


def standardise(train: torch.Tensor, test: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    mean, std = train.mean(0), train.std(0).clamp_min(1e-6)
    return (train - mean) / std, (test - mean) / std


def linear_probe(x_train: torch.Tensor, y_train: torch.Tensor, x_test: torch.Tensor, n_classes: int,
                 steps: int = 500, seed: int = 0) -> torch.Tensor:
    """Predicted classes of ``x_test`` by softmax regression fitted on standardised ``x_train``."""
    torch.manual_seed(seed)
    x_train, x_test = standardise(x_train, x_test)
    probe = torch.nn.Linear(x_train.shape[1], n_classes)
    opt = torch.optim.Adam(probe.parameters(), lr=1e-2, weight_decay=1e-4)
    for _ in range(steps):
        opt.zero_grad()
        F.cross_entropy(probe(x_train), y_train).backward()
        opt.step()
    with torch.no_grad():
        return probe(x_test).argmax(1)


def ridge(x_train: torch.Tensor, y_train: torch.Tensor, x_test: torch.Tensor, lam: float = 1.0) -> torch.Tensor:
    """Ridge regression on standardised features (closed form, float64)."""
    x_train, x_test = standardise(x_train.double(), x_test.double())
    x_train = torch.cat([x_train, torch.ones(len(x_train), 1, dtype=torch.float64)], 1)
    x_test = torch.cat([x_test, torch.ones(len(x_test), 1, dtype=torch.float64)], 1)
    eye = torch.eye(x_train.shape[1], dtype=torch.float64)
    eye[-1, -1] = 0.0
    w = torch.linalg.solve(x_train.T @ x_train + lam * eye, x_train.T @ y_train.double())
    return (x_test @ w).float()


def pose_errors(position: torch.Tensor, yaw_cs: torch.Tensor, peak: torch.Tensor, corpus: Corpus,
                held: torch.Tensor) -> dict[str, float]:
    """Mean errors on held-out samples: tangential position (mm, in the pad plane), normal position (mm),
    symmetry-aware yaw (deg, shapes that have a yaw), peak contact depth (mm)."""
    true = corpus.position[held]
    normal_axis = 2  # the pad frame's z is the gel normal (checked in tests on generated episodes)
    tangential = (position[:, :2] - true[:, :2]).norm(dim=1)
    yaw = yaw_error_deg(yaw_cs, corpus.yaw[held], corpus.order[held])
    return {"position_tangential_mm": float(tangential.mean()),
            "position_normal_mm": float((position[:, normal_axis] - true[:, normal_axis]).abs().mean()),
            "yaw_deg": float(torch.nanmean(yaw)), "peak_depth_mm": float((peak - corpus.peak[held]).abs().mean())}


def probe_report(feats: torch.Tensor, corpus: Corpus, train: torch.Tensor, held: torch.Tensor, seed: int) \
        -> dict[str, Any]:
    """Shape accuracy (with intervals and a confusion matrix) and pose / depth errors of linear probes."""
    n_classes = len(corpus.shapes)
    pred = linear_probe(feats[train], corpus.label[train], feats[held], n_classes, seed=seed)
    truth = corpus.label[held]
    correct = pred == truth
    k, n = int(correct.sum()), int(held.sum())
    episode = corpus.episode[held]
    votes = {}
    for e in torch.unique(episode).tolist():
        sel = episode == e
        votes[e] = bool(torch.bincount(pred[sel], minlength=n_classes).argmax() == truth[sel][0])
    confusion = torch.zeros(n_classes, n_classes, dtype=torch.int64)
    confusion.index_put_((truth, pred), torch.ones_like(truth), accumulate=True)
    per_shape = {s: float(correct[truth == c].float().mean()) for c, s in enumerate(corpus.shapes)
                 if (truth == c).any()}
    # pose and depth probes: ridge regressions on the same frozen features
    position = ridge(feats[train], corpus.position[train], feats[held])
    yaw_rows = train & (corpus.order > 0)
    yaw_cs_train, _ = yaw_target(corpus.yaw[yaw_rows], corpus.order[yaw_rows])
    yaw_cs = ridge(feats[yaw_rows], yaw_cs_train, feats[held])
    peak = ridge(feats[train], corpus.peak[train][:, None], feats[held])[:, 0]
    return {"accuracy": k / n, "correct": k, "samples": n, "wilson95": wilson(k, n),
            "episode_bootstrap95": episode_bootstrap(correct, episode, seed=seed),
            "episode_vote_accuracy": sum(votes.values()) / len(votes), "episodes": len(votes),
            "per_shape": per_shape, "confusion": confusion.tolist(),
            "errors": pose_errors(position, yaw_cs, peak, corpus, held)}


def baselines(corpus: Corpus, train: torch.Tensor, held: torch.Tensor) -> dict[str, Any]:
    """What knowing nothing scores: chance, the majority class, and predicting the training mean."""
    counts = torch.bincount(corpus.label[held], minlength=len(corpus.shapes))
    n = int(held.sum())
    mean_pos = corpus.position[train].mean(0).expand(n, 3)
    mean_peak = corpus.peak[train].mean().expand(n)
    zero_yaw = torch.tensor([[1.0, 0.0]]).expand(n, 2)
    return {"chance": 1.0 / len(corpus.shapes), "majority": float(counts.max()) / n,
            "errors_of_the_mean": pose_errors(mean_pos, zero_yaw, mean_peak, corpus, held)}


# ----------------------------------------------------------------------------------------------- chart

def save_chart(result: dict[str, Any], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    trained, rand = result["probe"]["trained"], result["probe"]["random_init"]
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2), gridspec_kw={"width_ratios": [1.0, 1.3, 1.6]})
    ax = axes[0]
    labels = ["trained", "random init"]
    accs = [trained["accuracy"], rand["accuracy"]]
    lows = [a - r["episode_bootstrap95"][0] for a, r in zip(accs, (trained, rand))]
    highs = [r["episode_bootstrap95"][1] - a for a, r in zip(accs, (trained, rand))]
    ax.bar(labels, [100 * a for a in accs], yerr=[[100 * v for v in lows], [100 * v for v in highs]],
           color=["tab:blue", "tab:gray"], capsize=6)
    ax.axhline(95, color="tab:green", ls="--", lw=1, label="goal 95 %")
    ax.axhline(100 * result["baselines"]["chance"], color="k", ls=":", lw=1, label="chance")
    for i, a in enumerate(accs):
        ax.text(i, 100 * a + 2, f"{100 * a:.1f} %", ha="center", fontsize=9)
    ax.set_ylim(0, 105)
    ax.set_ylabel("14-shape linear probe, held-out frames (%)")
    ax.legend(fontsize=8, loc="lower right")
    ax.set_title("shape (bars: 95 % episode bootstrap)", fontsize=9)
    ax = axes[1]
    keys = [("position_tangential_mm", "position, in plane (mm)"), ("position_normal_mm", "position, normal (mm)"),
            ("peak_depth_mm", "peak depth (mm)"), ("yaw_deg", "yaw / 10 (deg, mod symmetry)")]
    x = np.arange(len(keys))
    scale = [1, 1, 1, 0.1]
    mean_only = {"errors": result["baselines"]["errors_of_the_mean"]}
    for j, (name, res, colour) in enumerate((("trained", trained, "tab:blue"), ("random init", rand, "tab:gray"),
                                              ("predict the mean", mean_only, "tab:orange"))):
        ax.bar(x + (j - 1) * 0.27, [res["errors"][k] * s for (k, _), s in zip(keys, scale)], 0.27, label=name,
               color=colour)
    ax.set_xticks(x, [lab for _, lab in keys], fontsize=8, rotation=15)
    ax.set_ylabel("mean error on held-out frames (linear probe)")
    ax.legend(fontsize=8)
    ax.set_title("contact and pose", fontsize=9)
    ax = axes[2]
    conf = np.asarray(trained["confusion"], float)
    conf = conf / conf.sum(1, keepdims=True).clip(min=1)
    ax.imshow(conf, cmap="Blues", vmin=0, vmax=1)
    shapes = result["shapes"]
    ax.set_xticks(range(len(shapes)), shapes, rotation=90, fontsize=7)
    ax.set_yticks(range(len(shapes)), shapes, fontsize=7)
    ax.set_xlabel("predicted")
    ax.set_title("trained encoder's probe: confusion (row-normalised)", fontsize=9)
    fig.suptitle(f"Encoder recipe on {result['sensor']}: {result['train_episodes']} training / "
                 f"{result['held_out_episodes']} held-out episodes, {result['steps']} steps", fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


# ----------------------------------------------------------------------------------------------- main

def cpu_model() -> str:
    """The CPU's model name (from /proc/cpuinfo where there is one)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine() -> str:
    return f"{cpu_model()}, {os.cpu_count()} cores, Python {platform.python_version()}, torch {torch.__version__}"


def markdown_table(result: dict[str, Any]) -> str:
    """The README's results table, from a result JSON."""
    rows = [("14-shape linear probe, held-out frames", "accuracy"), ("  95 % interval (bootstrap over episodes)", "ci"),
            ("  95 % Wilson interval over frames (too narrow: frames of an episode correlate)", "wilson"),
            ("  majority vote per held-out episode", "vote"),
            ("position in the pad plane, mean error (mm)", "position_tangential_mm"),
            ("position along the normal, mean error (mm)", "position_normal_mm"),
            ("yaw modulo the shape's symmetry, mean error (deg)", "yaw_deg"),
            ("peak contact depth, mean error (mm)", "peak_depth_mm")]
    base = result["baselines"]

    def cell(r: dict[str, Any] | None, key: str) -> str:
        if r is None:
            if key == "accuracy":
                return f"{100 * base['chance']:.1f} % (chance)"
            if key in base["errors_of_the_mean"]:
                return f"{base['errors_of_the_mean'][key]:.3g}"
            return ""
        if key == "accuracy":
            return f"{100 * r['accuracy']:.1f} %"
        if key == "ci":
            lo, hi = r["episode_bootstrap95"]
            return f"{100 * lo:.1f}-{100 * hi:.1f} %"
        if key == "wilson":
            lo, hi = r["wilson95"]
            return f"{100 * lo:.1f}-{100 * hi:.1f} % ({r['samples']} frames)"
        if key == "vote":
            return f"{100 * r['episode_vote_accuracy']:.1f} % of {r['episodes']}"
        return f"{r['errors'][key]:.3g}"

    lines = ["| held-out episodes (linear probes on frozen features) | trained encoder | random-init encoder | "
             "no encoder (predict the training mean) |", "|---|---|---|---|"]
    for label, key in rows:
        lines.append(f"| {label} | " + " | ".join(cell(r, key) for r in (result["probe"]["trained"],
                                                                          result["probe"]["random_init"], None))
                     + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    args = parse_args(argv)
    if args.table:
        result = json.loads(args.table.read_text())
        print(markdown_table(result))
        return result
    torch.set_num_threads(args.threads)
    size = tuple(args.image_size)
    generation_s = None
    if args.generate is not None:
        data, generation_s = generate_corpus(args.out_dir / "corpus", args.sensor, args.generate, args.frames,
                                             args.shapes, args.gen_workers, args.contact)
    else:
        data = args.data
    t0 = time.perf_counter()
    target = tuple(args.target_size or size)
    cache = args.out_dir / (f"cache-{args.sensor}-{size[0]}x{size[1]}-{target[0]}x{target[1]}-"
                            f"{Path(data).resolve().name}.pt")
    try:
        corpus = load_corpus(Path(data), args.sensor, size, args.contact_mm, cache, target_size=target)
    except DatasetError as error:
        raise SystemExit(f"pretrain_encoder: {error}") from None
    train_mask, held_mask, train_ids, held_ids = split_masks(corpus, args.held_out, args.train_episodes,
                                                             args.split_seed)
    read_s = time.perf_counter() - t0
    print(f"{len(corpus.label)} samples in contact from {len(corpus.episode_ids)} episodes, {len(corpus.shapes)} "
          f"shapes; {len(train_ids)} training / {len(held_ids)} held-out episodes ({read_s:.0f} s to read)", flush=True)
    arch = {"widths": tuple(args.widths), "pool": args.pool, "space_to_depth": args.space_to_depth}
    model = make_model(corpus, train_mask, size, args.seed, **arch)
    random_model = make_model(corpus, train_mask, size, args.seed + 1, **arch)  # same architecture, never trained
    weights = RecipeWeights(consistency=args.consistency_weight, temperature=args.temperature)
    augment = Augment(rotate_deg=args.rotate_deg)
    t1 = time.perf_counter()
    history = train(model, corpus, train_mask, args.steps, args.batch_size, args.lr, args.seed, args.log_every,
                    augment=augment, weights=weights, max_minutes=args.max_minutes)
    train_s = time.perf_counter() - t1
    checkpoint = args.out_dir / "encoder.pt"
    save_checkpoint(model, checkpoint, corpus.shapes)
    t2 = time.perf_counter()
    probe: dict[str, Any] = {}
    own_heads: dict[str, float] = {}
    for label, m in (("trained", model), ("random_init", random_model)):
        feats, heads = encode_all(m, corpus)
        probe[label] = probe_report(feats, corpus, train_mask, held_mask, args.seed)
        if label == "trained":
            own_heads = pose_errors(heads["position_mm"][held_mask], heads["yaw_cs"][held_mask],
                                    heads["peak_depth_mm"][held_mask], corpus, held_mask)
    window = max(1, min(100, len(history) // 5))
    result = {
        "recipe": "examples/pretrain_encoder.py", "command": "python examples/pretrain_encoder.py "
        + " ".join(sys.argv[1:] if argv is None else argv),
        "machine": machine(), "threads": args.threads, "sensor": args.sensor, "data": str(data),
        "image_size": list(size), "target_size": list(target), "contact_mm": args.contact_mm,
        "steps": len(history), "max_steps": args.steps,
        "max_minutes": args.max_minutes, "batch_size": args.batch_size,
        "encoder": model.config.to_dict(), "augment": asdict(augment), "weights": asdict(weights),
        "shapes": corpus.shapes, "symmetry_order": {s: rotational_symmetry(s) for s in corpus.shapes},
        "train_episodes": len(train_ids), "train_episodes_per_shape_cap": args.train_episodes,
        "split_seed": args.split_seed,
        "held_out_episodes": len(held_ids),
        "train_samples": int(train_mask.sum()), "held_out_samples": int(held_mask.sum()),
        "held_out_episode_ids": held_ids,
        "loss_first": {k: float(np.mean([h[k] for h in history[:window]])) for k in history[0]},
        "loss_last": {k: float(np.mean([h[k] for h in history[-window:]])) for k in history[0]},
        "probe": probe, "trained_heads_errors": own_heads,
        "baselines": baselines(corpus, train_mask, held_mask),
        "seconds": {"generate": generation_s, "read": read_s, "train": train_s, "probe": time.perf_counter() - t2},
        "checkpoint": str(checkpoint), "goal_accuracy": 0.95,
        "goal_met": probe["trained"]["accuracy"] >= 0.95,
    }
    for label in ("trained", "random_init"):
        r = probe[label]
        lo, hi = r["episode_bootstrap95"]
        print(f"{label:12s} probe {100 * r['accuracy']:.1f} % (episodes bootstrap {100 * lo:.1f}"
              f"-{100 * hi:.1f}; vote per episode {100 * r['episode_vote_accuracy']:.1f} %)  "
              + "  ".join(f"{k} {v:.3f}" for k, v in r["errors"].items()))
    print("trained heads: " + "  ".join(f"{k} {v:.3f}" for k, v in own_heads.items()))
    if args.out_json:
        args.out_json.parent.mkdir(parents=True, exist_ok=True)
        args.out_json.write_text(json.dumps(result, indent=1) + "\n")
    if args.figure:
        save_chart(result, args.figure)
    return result


if __name__ == "__main__":
    main()
