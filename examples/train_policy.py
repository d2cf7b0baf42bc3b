"""Policy baselines: does touch help? Train a small ACT-style policy (``examples/act_policy.py``) on task
demonstrations, evaluate it with ``univtac-data evaluate``, and report.

Three variants, one recipe: ``vision`` (head + wrist cameras + agent_pos), ``vision_tactile`` (plus both
pads' marked tactile images through a small CNN trained end to end) and ``vision_encoder`` (plus both pads'
images through the pretrained tactile encoder, frozen; ``--encoder PATH`` is a checkpoint of
``examples/pretrain_encoder.py``).

Demonstrations come from ``univtac_data.loaders.PolicyChunkDataset`` (``TASK_OBS_KEYS``: what the task
environments observe). The policy runs at ``--rate-hz`` (25 Hz by default: the scripted experts' closed
loops hold at 25 Hz, not at 10, and two camera renders a step make 50 Hz rollouts twice as dear);
demonstrations recorded at that rate (``generate task --rate 25``) are used as they are, faster ones
subsampled: actions are absolute end-effector targets, so the target 1 / rate s ahead is simply the
recorded action that many frames on. Every recorded frame still starts a training sample (``--stride``).

    # demonstrations (cameras small), then per variant: train, evaluate, report
    univtac-data generate task pull_out_key --episodes 50 --rate 25 --camera-size 128x72 --workers 1 --out data/key
    python examples/train_policy.py train --data data/key --task pull_out_key --variant vision --out runs/key/vision
    python examples/train_policy.py train ... --variant vision_encoder --encoder encoder.pt --out runs/key/vision_encoder
    python examples/train_policy.py evaluate --run runs/key/vision --episodes 100
    python examples/train_policy.py report --runs runs/*/* --json benchmarks/results/policy_baselines.json \\
        --chart docs/figures/policy_baselines.png

``evaluate`` runs ``univtac-data evaluate TASK --policy act_policy:from_env --rate-hz R --camera-size WxH``
(plus ``--tactile-extras`` for a tactile variant trained with ``--history``) with ``examples/`` on
``PYTHONPATH`` and ``UNIVTAC_POLICY_CHECKPOINT`` naming the run's ``policy.pt``.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import platform
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from act_policy import (CHECKPOINT_ENV, ENSEMBLE_K_ENV, PADS, TARGET_FRAMES, VARIANTS,  # noqa: E402
                        ChunkPolicyNet, Normalization, PolicyConfig, chunk_targets, masked_l1, parameter_count,
                        past_agent_input, resize_uint8, save_checkpoint, touch_input)

EXAMPLES = Path(__file__).resolve().parent


# ------------------------------------------------------------------------------------------------- data

class DemoCache:
    """Every training sample in memory: images as uint8 at the policy's sizes, agent_pos (N, 8),
    actions (N, C, 8) at the policy's rate and ``is_pad`` (N, C), both pads' touch signals ``touch``
    (N, 2, 4) (``act_policy.TOUCH_SIGNALS``); for ``vision_encoder`` the frozen encoder's features (N, F) per
    pad instead of the images (computed once)."""

    def __init__(self, tensors: dict[str, torch.Tensor], episodes: int, demo_rate_hz: float, subsample: int,
                 stride: int = 1) -> None:
        self.tensors = tensors
        self.episodes = episodes
        self.demo_rate_hz = demo_rate_hz
        self.subsample = subsample
        self.stride = stride  # every stride-th recorded frame is a sample

    def __len__(self) -> int:
        return len(self.tensors["agent_pos"])


def demo_rate(dataset: Any) -> float:
    """The recording rate (Hz) of a ``PolicyChunkDataset``'s episodes, from the datasets' indexes."""
    rates = {float(dataset.datasets[ref.dataset].index[ref.episode_id].nominal_rate_hz) for ref in dataset.episodes}
    if len(rates) != 1:
        raise SystemExit(f"demonstrations recorded at several rates {sorted(rates)}: use one rate per run")
    return rates.pop()


def load_demos(path: str | Path, task: str, config: PolicyConfig, stride: int = 1, max_episodes: int | None = None,
               log: Any = print) -> DemoCache:
    """Read the demonstrations of ``task`` at ``path`` through ``PolicyChunkDataset`` into memory."""
    from univtac_data.generators.allocator import fix_mmap_threshold
    from univtac_data.loaders import TASK_OBS_KEYS, PolicyChunkDataset

    # reading a sample decodes ~2 MB of float images freed at once beside the small resized copies kept: with
    # glibc's adaptive threshold, reading Pull-out Key's 6,384 samples grew to 7.6 GB, 0.48 GB with it fixed
    fix_mmap_threshold(128 * 1024)

    keys = tuple(k for k in TASK_OBS_KEYS if not k.startswith("scene/cameras/")
                 or k.split("/")[2] in config.cameras)
    keys += tuple(f"tactile/{pad}/{name}" for pad in PADS for name in ("depth_um", "normal_force_n", "shear_force_n"))
    probe = PolicyChunkDataset(path, obs_keys=keys, names=task, chunk=1)
    rate = demo_rate(probe)
    subsample = round(rate / config.rate_hz)
    if subsample < 1 or abs(rate / subsample - config.rate_hz) > 1e-6:
        raise SystemExit(f"demonstrations at {rate} Hz cannot be subsampled to {config.rate_hz} Hz")
    episodes = [ref.episode_id for ref in probe.episodes][:max_episodes]
    # a chunk of C actions at the policy's rate spans C * subsample recorded actions; keep every
    # subsample-th, the target reached 1 / rate s after the previous one
    data = PolicyChunkDataset(path, obs_keys=keys, names=task, episodes=episodes, chunk=config.chunk * subsample,
                              history=1, normalize="none", action_pad="repeat")
    rows = np.flatnonzero(data.table.step % stride == 0)
    pick = torch.arange(subsample - 1, config.chunk * subsample, subsample)
    out: dict[str, list[torch.Tensor]] = {"agent_pos": [], "action": [], "action_is_pad": [], "episode": []}
    for name in config.cameras:
        out[name] = []
    for pad in PADS:  # read for every variant, so one cache serves all three
        out[f"tactile_{pad}"] = []
    out["touch"] = []
    start = time.perf_counter()
    for n, row in enumerate(rows):
        sample = data[int(row)]
        obs = sample["obs"]
        out["agent_pos"].append(obs["agent_pos"][-1])
        out["action"].append(sample["action"][pick])
        out["action_is_pad"].append(sample["action_is_pad"][pick])
        out["episode"].append(torch.tensor(int(data.table.episode[row])))
        for name in config.cameras:
            image = (obs[f"scene/cameras/{name}/rgb"][-1:] * 255).round().to(torch.uint8)
            out[name].append(resize_uint8(image, config.camera_hw)[0])
        for pad in PADS:
            image = (obs[f"tactile/{pad}/marked_rgb"][-1:] * 255).round().to(torch.uint8)
            out[f"tactile_{pad}"].append(resize_uint8(image, config.tactile_hw)[0])
        out["touch"].append(recorded_touch(obs))
        if n % 2000 == 0:
            log(f"  read {n}/{len(rows)} samples ({time.perf_counter() - start:.0f} s)")
    tensors = {k: torch.stack(v) for k, v in out.items()}
    return DemoCache(tensors, len(episodes), rate, subsample, stride)


def demonstrations_sha256(path: str | Path, task: str, max_episodes: int | None = None) -> tuple[str, int]:
    """A fingerprint of ``task``'s demonstrations at ``path``: SHA-256 over each episode's seed and recorded
    actions (as little-endian float64), in seed order, and the number of episodes (the first
    ``max_episodes`` only, as ``train --max-episodes`` reads them). It does not depend on the
    storage backend, the compression or the camera images, so demonstrations regenerated elsewhere with the
    same code and seeds give the same fingerprint, and a policy run says which demonstrations it learnt from."""
    import hashlib

    from univtac_data import CorruptFileError, DatasetError

    dataset, rows = task_rows(path, task)
    rows = rows[:max_episodes]
    if not rows:
        raise SystemExit(f"{path}: no episode of task {task!r}")
    try:
        digest = hashlib.sha256()
        for row in rows:
            with dataset.open_episode(row.episode_id) as handle:
                action = np.ascontiguousarray(handle.read("robot/action"), dtype="<f8")
            digest.update(f"{row.seed} {action.shape}\n".encode())
            digest.update(action.tobytes())
    except (DatasetError, CorruptFileError) as err:  # each names the file and the problem
        raise SystemExit(str(err)) from None
    return digest.hexdigest(), len(rows)


def recorded_touch(obs: dict[str, torch.Tensor]) -> torch.Tensor:
    """(2, 4) ``TOUCH_SIGNALS`` of both pads from a recorded frame (``PolicyChunkDataset`` observations), the
    same numbers ``act_policy.touch_signals`` reads from the environment at rollout."""
    rows = []
    for pad in PADS:
        depth_mm = float(obs[f"tactile/{pad}/depth_mm"][-1].max())  # the loader serves depth_um in mm
        shear = obs[f"tactile/{pad}/shear_force_n"][-1].reshape(2)
        rows.append([depth_mm, float(obs[f"tactile/{pad}/normal_force_n"][-1]), float(shear[0]), float(shear[1])])
    return torch.tensor(rows, dtype=torch.float32)


def history_rows(episode: torch.Tensor, history: int, step_rows: int) -> torch.Tensor:
    """(N, history) rows of each sample's past, oldest first: ``step_rows`` rows make one policy step, and a
    row before its episode's first is that first row (the rollout pads its first steps the same way)."""
    n = len(episode)
    rows = torch.arange(n)
    starts = torch.ones(n, dtype=torch.bool)
    starts[1:] = episode[1:] != episode[:-1]
    first = torch.cummax(torch.where(starts, rows, torch.zeros_like(rows)), 0).values
    back = step_rows * torch.arange(history, 0, -1)
    return torch.maximum(rows[:, None] - back[None], first[:, None])


def task_rows(path: str | Path, task: str) -> tuple[Any, list[Any]]:
    """The dataset at ``path`` and the index rows of ``task``'s episodes, in seed order (no episode is read)."""
    from univtac_data import CorruptFileError, Dataset, DatasetError

    try:
        dataset = Dataset.open(path)
    except (DatasetError, CorruptFileError) as err:  # each names the file and the problem
        raise SystemExit(str(err)) from None
    return dataset, sorted((row for row in dataset.index.values() if row.name == task), key=lambda row: row.seed)


def episode_digests(path: str | Path, task: str) -> list[list[str]]:
    """[episode_id, sha256] of ``task``'s episodes at ``path``, from the dataset's index: the episode digest
    covers every byte of the episode's files, so demonstrations regenerated into the same directory give
    other digests."""
    return [[row.episode_id, row.sha256] for row in task_rows(path, task)[1]]


def cached_demos(cache_path: str | None, data: str, task: str, config: PolicyConfig, stride: int,
                 max_episodes: int | None, log: Any = print) -> DemoCache:
    """``load_demos``, saved to ``cache_path`` the first time (the three variants read the same samples;
    the file records what it was made from, the episodes' digests included, and is rebuilt when that
    differs)."""
    key = {"data": str(Path(data).resolve()), "episodes": episode_digests(data, task), "task": task,
           "rate_hz": config.rate_hz, "chunk": config.chunk,
           "cameras": list(config.cameras), "camera_hw": list(config.camera_hw),
           "tactile_hw": list(config.tactile_hw), "stride": stride, "max_episodes": max_episodes}
    if cache_path and Path(cache_path).exists():
        try:
            saved = torch.load(cache_path, weights_only=False)
        except (OSError, RuntimeError, EOFError, pickle.UnpicklingError) as err:  # a cache is only ever a copy
            log(f"  the cache {cache_path} is unreadable ({err}): read again")
            saved = {"key": None}
        if saved["key"] == key and "touch" in saved["tensors"]:  # caches from before touch signals: rebuilt
            log(f"  samples from the cache {cache_path}")
            return DemoCache(saved["tensors"], saved["episodes"], saved["demo_rate_hz"], saved["subsample"], stride)
        if saved["key"] is not None:
            log(f"  the cache {cache_path} was made from other demonstrations or settings: read again")
    cache = load_demos(data, task, config, stride=stride, max_episodes=max_episodes, log=log)
    if cache_path:
        tmp = str(cache_path) + ".part"
        torch.save({"key": key, "tensors": cache.tensors, "episodes": cache.episodes,
                    "demo_rate_hz": cache.demo_rate_hz, "subsample": cache.subsample}, tmp)
        os.replace(tmp, cache_path)
    return cache


def add_encoder_features(cache: DemoCache, net: ChunkPolicyNet, batch: int = 256) -> None:
    """Replace each pad's images by the frozen encoder's features (they never change in training)."""
    for pad in PADS:
        images = cache.tensors.pop(f"tactile_{pad}")
        feats = [net.encoder_features(images[s:s + batch].float() / 255.0) for s in range(0, len(images), batch)]
        cache.tensors[f"feat_{pad}"] = torch.cat(feats)


# ------------------------------------------------------------------------------------------------ train

def random_shift(images: torch.Tensor, pad: int, generator: torch.Generator) -> torch.Tensor:
    """Shift each image by up to ``pad`` px (replicate padding, then a random crop): the camera augmentation
    that keeps a small CNN from memorising 50 demonstrations' pixels."""
    if pad == 0:
        return images
    b, c, h, w = images.shape
    padded = torch.nn.functional.pad(images, (pad, pad, pad, pad), mode="replicate")
    dx = torch.randint(0, 2 * pad + 1, (b,), generator=generator)
    dy = torch.randint(0, 2 * pad + 1, (b,), generator=generator)
    rows = (dy[:, None] + torch.arange(h)[None])[:, None, :, None].expand(b, c, h, w + 2 * pad)
    cols = (dx[:, None] + torch.arange(w)[None])[:, None, None, :].expand(b, c, h, w)
    return padded.gather(2, rows).gather(3, cols)


def make_batch(cache: DemoCache, targets: torch.Tensor, index: torch.Tensor, norm: Normalization,
               config: PolicyConfig, shift_px: int,
               generator: torch.Generator | None) -> tuple[dict[str, torch.Tensor], torch.Tensor, torch.Tensor]:
    """``targets``: the (N, C, 8) chunks the network learns (``chunk_targets`` of the cache's actions)."""
    t = cache.tensors
    obs = {"agent_pos": (t["agent_pos"][index] - norm.agent_mean) / norm.agent_std}
    for name in config.cameras:
        images = t[name][index].float() / 255.0
        obs[name] = random_shift(images, shift_px, generator) if generator is not None else images
    for pad in PADS if config.uses_tactile else ():
        if f"feat_{pad}" in t:
            obs[f"feat_{pad}"] = t[f"feat_{pad}"][index]
        else:
            obs[f"tactile_{pad}"] = t[f"tactile_{pad}"][index].float() / 255.0
    if config.history:
        past = t["history_rows"][index]
        obs["past_agent"] = past_agent_input(t["agent_pos"][past], t["agent_pos"][index], norm)
        if config.reads_touch:
            obs["touch"] = touch_input(t["touch"][torch.cat([past, index[:, None]], 1)])
    actions = (targets[index] - norm.action_mean) / norm.action_std
    return obs, actions, t["action_is_pad"][index]


def train(cache: DemoCache, config: PolicyConfig, *, steps: int, batch_size: int, lr: float, seed: int,
          shift_px: int = 4, encoder_path: str | None = None, log: Any = print,
          net: ChunkPolicyNet | None = None) -> tuple[ChunkPolicyNet, Normalization, list[float]]:
    """AdamW on the masked L1 loss; returns the network (eval mode), its normalisation and the loss per step."""
    torch.manual_seed(seed)
    if net is None:
        net = ChunkPolicyNet(config)
        if config.variant == "vision_encoder":
            if encoder_path is None:
                raise ValueError("the vision_encoder variant needs the pretrained encoder's checkpoint")
            load_encoder_weights(net, encoder_path)
    if config.variant == "vision_encoder" and "feat_left" not in cache.tensors:
        add_encoder_features(cache, net)
    t = cache.tensors
    if config.history:
        # consecutive rows are consecutive recorded frames only when every frame starts a sample
        if cache.stride != 1:
            raise ValueError(f"--history needs every recorded frame read (--stride 1, got {cache.stride})")
        t["history_rows"] = history_rows(t["episode"], config.history, cache.subsample)
    targets = chunk_targets(t["agent_pos"], t["action"], config)
    norm = Normalization.fit(t["agent_pos"], targets, t["action_is_pad"])
    params = [p for p in net.parameters() if p.requires_grad]
    optimiser = torch.optim.AdamW(params, lr=lr, weight_decay=1e-4)
    schedule = torch.optim.lr_scheduler.LambdaLR(optimiser, lambda s: min(1.0, (s + 1) / 100))  # short warm-up
    generator = torch.Generator().manual_seed(seed)
    losses: list[float] = []
    net.train()
    start = time.perf_counter()
    for step in range(steps):
        index = torch.randint(0, len(cache), (batch_size,), generator=generator)
        obs, actions, is_pad = make_batch(cache, targets, index, norm, config, shift_px, generator)
        loss = masked_l1(net(obs), actions, is_pad)
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(params, 10.0)
        optimiser.step()
        schedule.step()
        losses.append(loss.item())
        if step % 200 == 0 or step == steps - 1:
            recent = np.mean(losses[-200:])
            log(f"  step {step}/{steps}: loss {recent:.4f} ({time.perf_counter() - start:.0f} s)")
    return net.eval(), norm, losses


def load_encoder_weights(net: ChunkPolicyNet, path: str) -> None:
    from pretrain_encoder import load_checkpoint as load_encoder

    assert net.encoder is not None
    net.encoder.load_state_dict(load_encoder(Path(path)).state_dict())
    net.encoder.requires_grad_(False)


def encoder_config(path: str) -> dict[str, Any]:
    data = torch.load(path, weights_only=False, map_location="cpu")
    return dict(data["config"])


def cmd_train(args: argparse.Namespace) -> int:
    torch.set_num_threads(args.threads)
    if args.variant == "vision_encoder" and not args.encoder:
        raise SystemExit("--variant vision_encoder needs --encoder PATH (a checkpoint of examples/pretrain_encoder.py)")
    if args.history < 0:
        raise SystemExit(f"--history must be >= 0 policy steps (got {args.history})")
    if args.history and args.stride != 1:
        raise SystemExit(f"--history {args.history} reads the past from every recorded frame: use --stride 1 "
                         f"(got {args.stride}) or --history 0")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    width, height = (int(v) for v in args.camera_input.lower().split("x"))
    cameras = () if args.cameras == "none" else tuple(args.cameras.split(","))
    encoder = encoder_config(args.encoder) if args.variant == "vision_encoder" else None
    tactile = {"tactile_hw": (int(encoder["height"]), int(encoder["width"]))} if encoder else {}
    config = PolicyConfig(variant=args.variant, cameras=cameras, camera_hw=(height, width), chunk=args.chunk,
                          rate_hz=args.rate_hz, d_model=args.d_model, encoder=encoder, pose=args.pose,
                          opening=args.opening, history=args.history, ensemble_k=args.ensemble_k, **tactile)
    log_file = open(out / "train.log", "a")

    def log(message: str) -> None:
        print(message, flush=True)
        print(message, file=log_file, flush=True)

    log(f"train {args.task} {args.variant}: {args}")
    t0 = time.perf_counter()
    cache = cached_demos(args.cache, args.data, args.task, config, args.stride, args.max_episodes, log=log)
    if not config.uses_tactile:
        for pad in PADS:
            cache.tensors.pop(f"tactile_{pad}")
    demos_sha256, _ = demonstrations_sha256(args.data, args.task, args.max_episodes)
    t_read = time.perf_counter() - t0
    log(f"  {len(cache)} samples from {cache.episodes} episodes at {cache.demo_rate_hz:g} Hz "
        f"(one action in {cache.subsample}: {config.rate_hz:g} Hz) in {t_read:.0f} s")
    t1 = time.perf_counter()
    net, norm, losses = train(cache, config, steps=args.steps, batch_size=args.batch_size, lr=args.lr, seed=args.seed,
                              shift_px=args.shift_px, encoder_path=args.encoder, log=log)
    t_train = time.perf_counter() - t1
    summary = {
        "task": args.task, "variant": args.variant, "data": str(args.data), "demos": cache.episodes,
        "demonstrations_sha256": demos_sha256,
        "samples": len(cache), "demo_rate_hz": cache.demo_rate_hz, "rate_hz": config.rate_hz, "chunk": config.chunk,
        "steps": args.steps, "batch_size": args.batch_size, "epochs": args.steps * args.batch_size / len(cache),
        "lr": args.lr, "seed": args.seed, "pose": config.pose, "opening": config.opening, "history": config.history,
        "ensemble_k": config.ensemble_k,
        "camera_size": args.camera_size, "cameras": list(cameras),
        "trainable_parameters": parameter_count(net), "encoder": args.encoder,
        "read_s": t_read, "train_s": t_train, "threads": args.threads,
        "loss_first_100": float(np.mean(losses[:100])), "loss_last_100": float(np.mean(losses[-100:])),
    }
    save_checkpoint(out / "policy.pt", net, norm, extra=summary)
    (out / "train.json").write_text(json.dumps(summary, indent=1))
    log(f"  trained in {t_train:.0f} s; loss {summary['loss_first_100']:.3f} -> {summary['loss_last_100']:.3f}; "
        f"wrote {out / 'policy.pt'}")
    return 0


# --------------------------------------------------------------------------------------------- evaluate

def evaluate_command(task: str, episodes: int, rate_hz: float, camera_size: str | None, json_path: Path,
                     seed: int = 0, touch: bool = False) -> list[str]:
    """``touch``: the policy reads the pads' touch signals (a tactile variant with history)."""
    cmd = ["univtac-data", "evaluate", task, "--policy", "act_policy:from_env", "--episodes", str(episodes),
           "--seed", str(seed), "--rate-hz", f"{rate_hz:g}", "--json", str(json_path)]
    cmd += ["--no-cameras"] if camera_size is None else ["--camera-size", camera_size]
    return cmd + (["--tactile-extras"] if touch else [])


def policy_env(checkpoint: Path, threads: int = 1, ensemble_k: float | None = None) -> dict[str, str]:
    env = dict(os.environ)
    env[CHECKPOINT_ENV] = str(checkpoint)
    env.pop(ENSEMBLE_K_ENV, None)
    if ensemble_k is not None:
        env[ENSEMBLE_K_ENV] = repr(ensemble_k)
    env["UNIVTAC_POLICY_THREADS"] = str(threads)
    env["PYTHONPATH"] = os.pathsep.join([str(EXAMPLES), *filter(None, [env.get("PYTHONPATH")])])
    env.setdefault("MUJOCO_GL", "egl")
    return env


def cmd_evaluate(args: argparse.Namespace) -> int:
    run = Path(args.run)
    summary = json.loads((run / "train.json").read_text())
    camera_size = summary["camera_size"] if summary["cameras"] else None
    json_path = run / ("eval.json" if args.seed == 0 else f"eval-{args.seed}.json")
    touch = summary.get("history", 0) > 0 and summary["variant"] != "vision"  # PolicyConfig.reads_touch
    cmd = evaluate_command(summary["task"], args.episodes, summary["rate_hz"], camera_size, json_path, args.seed, touch)
    print(" ".join(cmd), flush=True)
    start = time.perf_counter()
    subprocess.run(cmd, env=policy_env(run / "policy.pt", args.threads, args.ensemble_k), check=True)
    elapsed = time.perf_counter() - start
    result = json.loads(json_path.read_text())
    result["wall_s"] = elapsed
    result["ensemble_k"] = summary.get("ensemble_k", PolicyConfig().ensemble_k) if args.ensemble_k is None else args.ensemble_k
    prefix = "" if args.ensemble_k is None else f"{ENSEMBLE_K_ENV}={args.ensemble_k!r} "
    result["command"] = prefix + " ".join(cmd)
    json_path.write_text(json.dumps(result, indent=1))
    print(f"evaluated in {elapsed:.0f} s", flush=True)
    return 0


# ----------------------------------------------------------------------------------------------- report

def machine() -> dict[str, Any]:
    from pretrain_encoder import cpu_model

    return {"cpu": cpu_model(), "cores": os.cpu_count(), "python": platform.python_version(), "torch": torch.__version__,
            "threads_per_process": 1, "gpu": None}


def merged_evaluation(run: Path) -> dict[str, Any] | None:
    """``eval.json`` and any ``eval-*.json`` of a run (evaluations on disjoint seed ranges, ``--seed``), as one."""
    files = sorted(run.glob("eval.json")) + sorted(run.glob("eval-*.json"))
    if not files:
        return None
    evals = [json.loads(f.read_text()) for f in files]
    rollouts = [r for ev in evals for r in ev["per_rollout"]]
    seeds = [r["seed"] for r in rollouts]
    if len(set(seeds)) != len(seeds):
        raise SystemExit(f"{run}: evaluations overlap in seeds; give each a disjoint --seed range")
    ks = {ev.get("ensemble_k", PolicyConfig().ensemble_k) for ev in evals}
    if len(ks) != 1:
        raise SystemExit(f"{run}: evaluations with different --ensemble-k {sorted(ks)}; evaluate each k in its own run directory")
    from univtac_data.envs.evaluate import wilson_interval

    n, k = len(rollouts), sum(r["success"] for r in rollouts)
    return {"rollouts": n, "successes": k, "success_rate": k / n, "wilson95": list(wilson_interval(k, n)),
            "unsafe_rate": sum(r["unsafe"] for r in rollouts) / n,
            "errors": sum(r["reason"].startswith("error") for r in rollouts),
            "mean_steps": sum(r["steps"] for r in rollouts) / n,
            "wall_s": sum(ev.get("wall_s", ev.get("elapsed_s", 0.0)) for ev in evals),
            "commands": [ev.get("command") for ev in evals], "per_rollout": rollouts,
            "ensemble_k": evals[0].get("ensemble_k", PolicyConfig().ensemble_k)}


def collect_rows(runs: list[Path]) -> list[dict[str, Any]]:
    rows = []
    for run in runs:
        ev = merged_evaluation(run)
        if not (run / "train.json").exists() or ev is None:
            continue
        train_s = json.loads((run / "train.json").read_text())
        rows.append({
            "task": train_s["task"], "variant": train_s["variant"], "demos": train_s["demos"],
            "rollouts": ev["rollouts"], "successes": ev["successes"], "success_rate": ev["success_rate"],
            "wilson95": ev["wilson95"], "unsafe_rate": ev["unsafe_rate"], "errors": ev["errors"],
            "mean_steps": ev["mean_steps"], "rate_hz": train_s["rate_hz"], "demo_rate_hz": train_s["demo_rate_hz"],
            "chunk": train_s["chunk"], "train_steps": train_s["steps"], "epochs": round(train_s["epochs"], 2),
            "batch_size": train_s["batch_size"], "samples": train_s["samples"],
            "trainable_parameters": train_s["trainable_parameters"], "read_s": round(train_s["read_s"], 1),
            "train_s": round(train_s["train_s"], 1), "eval_s": round(ev["wall_s"], 1),
            "loss_first_100": train_s["loss_first_100"], "loss_last_100": train_s["loss_last_100"],
            "failure_reasons": failure_reasons(ev["per_rollout"]), "eval_commands": ev["commands"],
            "camera_size": train_s["camera_size"], "ensemble_k": ev["ensemble_k"],
            "seed": train_s.get("seed", 0), "pose": train_s.get("pose", "absolute"),
            "opening": train_s.get("opening", "absolute"), "history": train_s.get("history", 0),
            "demonstrations_sha256": train_s.get("demonstrations_sha256"),
        })
    return sorted(rows, key=row_order)


def row_order(row: dict[str, Any]) -> tuple[str, int, int]:
    """Rows sort by task, then variant in ``VARIANTS`` order, then training seed."""
    return row["task"], VARIANTS.index(row["variant"]), int(row.get("seed", 0))


def recipe(row: dict[str, Any]) -> tuple[str, str, int, float, str | None]:
    """The targets a run was trained on (pose, opening), the policy steps of past it read, the temporal
    ensembling weight k it was evaluated with, and the demonstrations it learnt from
    (``demonstrations_sha256``); runs from before those options are absolute, read the present only, were
    evaluated with ACT's k = 0.01 and did not record their demonstrations (None)."""
    return (row.get("pose", "absolute"), row.get("opening", "absolute"), int(row.get("history", 0)),
            float(row.get("ensemble_k", 0.01)), row.get("demonstrations_sha256"))


def pooled_rows(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per task, variant and recipe: the rollouts of every training seed together, with each seed's
    own rate beside them (the binomial interval of the pool does not hold the spread between training runs;
    the per-seed rates show it). Runs trained on other targets or other demonstrations are never pooled
    together."""
    from univtac_data.envs.evaluate import wilson_interval

    out = []
    for key in dict.fromkeys((r["task"], r["variant"], recipe(r)) for r in rows):
        group = [r for r in rows if (r["task"], r["variant"], recipe(r)) == key]
        n, k = sum(r["rollouts"] for r in group), sum(r["successes"] for r in group)
        out.append({"task": key[0], "variant": key[1], "pose": key[2][0], "opening": key[2][1], "history": key[2][2], "ensemble_k": key[2][3],
                    "demonstrations_sha256": key[2][4], "training_seeds": [r["seed"] for r in group],
                    "rollouts": n, "successes": k, "success_rate": k / n, "wilson95": list(wilson_interval(k, n)),
                    "per_seed_success_rate": [r["success_rate"] for r in group],
                    "unsafe_rate": sum(r["unsafe_rate"] * r["rollouts"] for r in group) / n,
                    "train_s": sum(r["train_s"] for r in group), "eval_s": sum(r["eval_s"] for r in group)})
    return out


def difference_interval(k1: int, n1: int, k2: int, n2: int) -> tuple[float, float, float]:
    """p1 - p2 and its 95 % interval by Newcombe's hybrid score method (his method 10: from the two Wilson
    intervals), which keeps its coverage near 0 and 1, where the policies' rates sit."""
    from univtac_data.envs.evaluate import wilson_interval

    p1, p2 = k1 / n1, k2 / n2
    (l1, u1), (l2, u2) = wilson_interval(k1, n1), wilson_interval(k2, n2)
    d = p1 - p2
    return d, d - ((p1 - l1) ** 2 + (u2 - p2) ** 2) ** 0.5, d + ((u1 - p1) ** 2 + (p2 - l2) ** 2) ** 0.5


def touch_effects(pooled: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per task and recipe, each tactile variant's success minus vision's (points) with its 95 % interval: only
    between policies trained on the same demonstrations (``recipe``)."""
    out = []
    for base in (r for r in pooled if r["variant"] == "vision"):
        for row in (r for r in pooled if r["task"] == base["task"] and r["variant"] != "vision"
                    and recipe(r) == recipe(base)):
            d, lo, hi = difference_interval(row["successes"], row["rollouts"], base["successes"], base["rollouts"])
            out.append({"task": base["task"], "variant": row["variant"], "pose": base["pose"],
                        "opening": base["opening"], "history": base["history"], "ensemble_k": base["ensemble_k"],
                        "demonstrations_sha256": base.get("demonstrations_sha256"), "points": 100 * d,
                        "interval95_points": [100 * lo, 100 * hi], "goal_points": 15.0,
                        "goal_met": 100 * d >= 15.0})
    return out


def failure_reasons(rollouts: list[dict[str, Any]]) -> dict[str, int]:
    """How rollouts ended: success, step_limit, unsafe by rule (indentation, in-hand slip), error."""
    counts: dict[str, int] = {}
    for r in rollouts:
        reason = r["reason"]
        if reason.startswith("unsafe:"):
            reason = "unsafe: " + reason.split(":", 1)[1].strip().split(" ")[0]
            reason = {"unsafe: in-hand": "unsafe: in-hand slip"}.get(reason, reason)
        elif reason.startswith("error"):
            reason = "error"
        counts[reason] = counts.get(reason, 0) + 1
    return dict(sorted(counts.items()))


def chart(pooled: list[dict[str, Any]], path: Path) -> None:
    """Success per task and variant from ``pooled_rows``: the training seeds' rollouts pooled (bar, 95 % Wilson
    interval), each seed's own rate as a dot."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    # one group of bars per task and recipe (a task's recipes differ in history or ensembling k)
    # (runs that did not record their demonstrations sort first)
    groups = sorted({(r["task"], recipe(r)) for r in pooled}, key=lambda g: (g[0], g[1][:4], g[1][4] or ""))
    several = {task for task, _ in groups if sum(t == task for t, _ in groups) > 1}

    def label(task: str, rec: tuple[str, str, int, float, str | None]) -> str:
        if task not in several:
            return task
        demos = {r[4] for t, r in groups if t == task}
        return (task + f"\nhistory {rec[2]}, k = {rec[3]:g}"
                + (f", demos {(rec[4] or 'unrecorded')[:8]}" if len(demos) > 1 else ""))

    labels = [label(task, rec) for task, rec in groups]
    colours = {"vision": "#7f7f7f", "vision_tactile": "#1f77b4", "vision_encoder": "#d62728"}
    per_row = 5  # groups a panel: more tasks wrap onto further panels instead of one unreadably wide chart
    panels = [list(range(i, min(i + per_row, len(groups)))) for i in range(0, len(groups), per_row)]
    fig, axes = plt.subplots(len(panels), 1, figsize=(2.6 + 2.4 * min(per_row, len(groups)), 3.8 * len(panels)),
                             squeeze=False)
    width = 0.26
    present = [v for v in VARIANTS if any(r["variant"] == v for r in pooled)]  # bars centred on their task
    for ax, panel in zip(axes[:, 0], panels):
        for v, variant in enumerate(present):
            for slot, t in enumerate(panel):
                task, rec = groups[t]
                row = next((r for r in pooled if r["task"] == task and r["variant"] == variant and recipe(r) == rec),
                           None)
                if row is None:
                    continue
                x = slot + (v - (len(present) - 1) / 2) * width
                p, (lo, hi) = row["success_rate"], row["wilson95"]
                ax.bar(x, 100 * p, width * 0.9, color=colours[variant],
                       label=variant if variant not in ax.get_legend_handles_labels()[1] else None)
                ax.errorbar(x, 100 * p, yerr=[[100 * (p - lo)], [100 * (hi - p)]], color="black", capsize=3, lw=1)
                if len(row["per_seed_success_rate"]) > 1:
                    seeds = row["per_seed_success_rate"]
                    ax.plot([x] * len(seeds), [100 * q for q in seeds], "o", ms=3, mfc="white", mec="black", zorder=3)
                ax.text(x, 100 * hi + 1.5, f"{row['successes']}/{row['rollouts']}", ha="center", fontsize=7)
        ax.set_xticks(range(len(panel)), [labels[t] for t in panel], fontsize=8)
        ax.set_xlim(-0.5, per_row - 0.5 if len(panels) > 1 else len(panel) - 0.5)
        ax.set_ylabel("success, % (95 % Wilson interval)")
        ax.set_ylim(0, 108)
    # one legend for every panel, above them, where no bar can be under it
    handles = {label: h for ax in axes[:, 0] for h, label in zip(*ax.get_legend_handles_labels())}
    fig.suptitle("ACT-style policy, 50 demonstrations: vision vs touch (dots: training seeds)", fontsize=9)
    fig.legend(list(handles.values()), list(handles), fontsize=8, ncol=len(handles), loc="upper center",
               bbox_to_anchor=(0.5, 1 - 0.3 / (3.8 * len(panels))), frameon=False)
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.55 / (3.8 * len(panels))))
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def run_key(row: dict[str, Any]) -> tuple[str, str, int, tuple[str, str, int, float, str | None]]:
    """What makes two rows the same run: task, variant, training seed and recipe (a run on other
    demonstrations is another run, not a rerun)."""
    return row["task"], row["variant"], int(row.get("seed", 0)), recipe(row)


def merged_rows(earlier: list[dict[str, Any]], new: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """An earlier report's rows with ``new`` added; a new row replaces an earlier one of the same run
    (``run_key``), so re-evaluating a run does not count it twice."""
    keys = {run_key(r) for r in new}
    return sorted([r for r in earlier if run_key(r) not in keys] + new, key=row_order)


def read_json_arg(flag: str, path: str) -> dict[str, Any]:
    try:
        value = json.loads(Path(path).read_text())
    except (OSError, ValueError) as err:
        raise SystemExit(f"{flag} {path}: not a readable JSON file ({err})") from None
    if not isinstance(value, dict):
        raise SystemExit(f"{flag} {path}: not a JSON object")
    return value


def cmd_fingerprint(args: argparse.Namespace) -> int:
    sha, episodes = demonstrations_sha256(args.data, args.task)
    print(f"{sha}  {args.task}, {episodes} demonstrations in {args.data}")
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    rows = collect_rows([Path(r) for r in args.runs])
    if not rows:
        raise SystemExit("no run has both train.json and eval.json")
    # --merge: runs whose directories are gone stay in the report, as the earlier report measured them
    earlier = read_json_arg("--merge", args.merge) if args.merge else {}
    if earlier and not isinstance(earlier.get("rows"), list):
        raise SystemExit(f"--merge {args.merge}: not a report of this script (no 'rows' list)")
    report: dict[str, Any] = {"machine": machine(), "note": args.note or earlier.get("note", "")}
    if "machine" in earlier and earlier["machine"] != report["machine"]:
        report["earlier_machine"] = earlier["machine"]
    if args.setup:  # what the runs started from (generation times, reference rates), measured elsewhere
        report["setup"] = read_json_arg("--setup", args.setup)
    elif "setup" in earlier:
        report["setup"] = earlier["setup"]
    report["rows"] = merged_rows(earlier.get("rows", []), rows)
    report["pooled"] = pooled_rows(report["rows"])
    report["touch_effects"] = touch_effects(report["pooled"])
    if "ablations" in earlier and not args.ablation_runs:
        report["ablations"] = earlier["ablations"]
    notes = args.ablation_note or []
    for k, runs in enumerate(args.ablation_runs or []):
        ablation = collect_rows([Path(r) for r in runs])
        pooled = pooled_rows(ablation)
        report.setdefault("ablations", []).append({"note": notes[k] if k < len(notes) else "", "rows": ablation,
                                                   "pooled": pooled, "touch_effects": touch_effects(pooled)})
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    partial = out.with_name(out.name + ".tmp")  # --merge may name the file it writes: never leave it half-written
    partial.write_text(json.dumps(report, indent=1) + "\n")
    os.replace(partial, out)
    if args.chart:
        chart(report["pooled"], Path(args.chart))
    for r in report["pooled"]:
        lo, hi = r["wilson95"]
        seeds = ", ".join(f"{100 * q:.0f}" for q in r["per_seed_success_rate"])
        print(f"| {r['task']} | {r['variant']} | history {r['history']}, k {r['ensemble_k']:g} "
              f"| {r['successes']}/{r['rollouts']} = {100 * r['success_rate']:.0f} % "
              f"({100 * lo:.0f}-{100 * hi:.0f}) | {seeds} | {100 * r['unsafe_rate']:.0f} % | {r['train_s'] / 60:.1f} min "
              f"| {r['eval_s'] / 60:.1f} min |")
    for e in report["touch_effects"]:
        lo, hi = e["interval95_points"]
        print(f"{e['task']} (history {e['history']}, k {e['ensemble_k']:g}): {e['variant']} - vision = "
              f"{e['points']:+.1f} points ({lo:+.1f} to {hi:+.1f})")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    tr = sub.add_parser("train", help="train one variant on one task's demonstrations")
    tr.add_argument("--data", required=True, help="dataset of demonstrations (univtac-data generate task)")
    tr.add_argument("--task", required=True)
    tr.add_argument("--variant", choices=VARIANTS, required=True)
    tr.add_argument("--encoder", default=None, help="pretrained encoder checkpoint (vision_encoder)")
    tr.add_argument("--out", required=True, help="run directory: policy.pt, train.json, train.log")
    tr.add_argument("--rate-hz", type=float, default=25.0, help="policy rate, Hz (default 25)")
    tr.add_argument("--chunk", type=int, default=20, help="actions per chunk (default 20: 0.8 s at 25 Hz)")
    tr.add_argument("--cameras", default="head,wrist", help="comma-separated cameras, or 'none'")
    tr.add_argument("--camera-size", default="128x72", help="camera WxH recorded and evaluated at (default 128x72)")
    tr.add_argument("--camera-input", default="64x36", help="camera WxH the policy's CNN reads, area-resized (default 64x36)")
    tr.add_argument("--pose", choices=TARGET_FRAMES, default="relative",
                    help="the pose the policy predicts: relative to the measured one (default) or absolute")
    tr.add_argument("--opening", choices=TARGET_FRAMES, default="relative",
                    help="the opening the policy predicts: relative to the measured one (default) or absolute")
    tr.add_argument("--history", type=int, default=25,
                    help="policy steps of the past the network reads: agent_pos, and for the tactile variants the "
                         "pads' touch signals (default 25: 1 s at 25 Hz; 0: the present only)")
    tr.add_argument("--ensemble-k", type=float, default=PolicyConfig().ensemble_k,
                    help="temporal-ensembling weight k the checkpoint rolls out with: exp(-k i), i = 0 the oldest "
                         f"prediction (default {PolicyConfig().ensemble_k:g}, ACT's; negative weighs the newest most: "
                         "-0.5 suits Pull-out Key, see docs/policies.md)")
    tr.add_argument("--d-model", type=int, default=128)
    tr.add_argument("--steps", type=int, default=3000)
    tr.add_argument("--batch-size", type=int, default=32)
    tr.add_argument("--lr", type=float, default=3e-4)
    tr.add_argument("--shift-px", type=int, default=4, help="random-shift augmentation of the cameras, px")
    tr.add_argument("--stride", type=int, default=1, help="every n-th recorded frame starts a sample")
    tr.add_argument("--max-episodes", type=int, default=None)
    tr.add_argument("--cache", default=None, help="file caching the read samples (shared by the variants)")
    tr.add_argument("--seed", type=int, default=0)
    tr.add_argument("--threads", type=int, default=1)
    ev = sub.add_parser("evaluate", help="univtac-data evaluate a trained run")
    ev.add_argument("--run", required=True)
    ev.add_argument("--episodes", type=int, default=100)
    ev.add_argument("--seed", type=int, default=0)
    ev.add_argument("--threads", type=int, default=1)
    ev.add_argument("--ensemble-k", type=float, default=None,
                    help="override the temporal-ensembling weight k (negative: the newest prediction weighs most)")
    rp = sub.add_parser("report", help="JSON, chart and table rows from evaluated runs")
    rp.add_argument("--runs", nargs="+", required=True)
    rp.add_argument("--json", required=True)
    rp.add_argument("--chart", default=None)
    rp.add_argument("--note", default="")
    rp.add_argument("--ablation-runs", nargs="+", action="append", default=None,
                    help="a group of runs reported apart (e.g. another rollout setting or rate); repeat for more")
    rp.add_argument("--ablation-note", action="append", default=None, help="a note per --ablation-runs group")
    rp.add_argument("--setup", default=None, help="JSON file stored as the report's 'setup' (e.g. generation times)")
    rp.add_argument("--merge", default=None, metavar="JSON",
                    help="an earlier report whose rows, setup, note and ablations are kept: the runs given add "
                         "to its rows and replace those of the same task, variant, seed and recipe")
    fp = sub.add_parser("fingerprint", help="the SHA-256 of a task's demonstrations (seeds and actions), to check "
                                            "that regenerated demonstrations are those a report's runs learnt from")
    fp.add_argument("--data", required=True)
    fp.add_argument("--task", required=True)
    args = parser.parse_args(argv)
    commands = {"train": cmd_train, "evaluate": cmd_evaluate, "report": cmd_report, "fingerprint": cmd_fingerprint}
    return commands[args.command](args)


if __name__ == "__main__":
    raise SystemExit(main())
