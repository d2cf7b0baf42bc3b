"""Evaluate a policy on a task: rollouts on evaluation seeds, success with a Wilson interval, safety.

Rollout k runs on seed ``EVAL_SEED_BASE + seed + k`` (generation never uses a seed that high, so a policy
is never scored on a layout a demonstration was recorded on); ``replay:`` policies are the exception: they
replay each recorded episode on its own seed. A rollout ends when the task succeeds (success), a tactile
safety rule is broken (unsafe, a failure), the policy raises or returns a bad action (error, a failure,
reported; the evaluation goes on), or at the task's step limit (step_limit).
"""

from __future__ import annotations

import math
import os
import sys
import time
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from tqdm import tqdm

from univtac_data.envs.policies import ExpertPolicy, Policy, RandomPolicy, ReplayPolicy, ZeroPolicy, load_replay, user_policy
from univtac_data.envs.task_env import TaskEnv
from univtac_data.generators.tasks.base import EVAL_SEED_BASE


def wilson_interval(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95 % (z = 1.96) Wilson score interval of a success rate; (0, 1) for n = 0."""
    if n == 0:
        return 0.0, 1.0
    p = successes / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    # the closed form gives exactly 0 at no success and 1 at all; rounding would put the end on the wrong side of p
    lo = 0.0 if successes == 0 else max(0.0, centre - half)
    hi = 1.0 if successes == n else min(1.0, centre + half)
    return lo, hi


@dataclass
class Rollout:
    seed: int
    success: bool
    unsafe: bool
    reason: str  # success | unsafe: ... | error: ... | step_limit
    steps: int


@dataclass
class EvaluationReport:
    task: str
    policy: str
    rollouts: list[Rollout] = field(default_factory=list)
    elapsed_s: float = 0.0

    @property
    def n(self) -> int:
        return len(self.rollouts)

    @property
    def successes(self) -> int:
        return sum(r.success for r in self.rollouts)

    def summary(self) -> dict[str, Any]:
        lo, hi = wilson_interval(self.successes, self.n)
        steps = sum(r.steps for r in self.rollouts)
        return {
            "task": self.task, "policy": self.policy, "rollouts": self.n,
            "success_rate": self.successes / self.n if self.n else 0.0, "wilson95": [lo, hi],
            "unsafe_rate": sum(r.unsafe for r in self.rollouts) / self.n if self.n else 0.0,
            "errors": sum(r.reason.startswith("error") for r in self.rollouts),
            "mean_steps": steps / self.n if self.n else 0.0,
            "steps_per_s": steps / self.elapsed_s if self.elapsed_s > 0 else 0.0,
        }

    def as_json(self) -> dict[str, Any]:
        return {**self.summary(), "per_rollout": [asdict(r) for r in self.rollouts]}


def make_policy(spec: str, env: TaskEnv, task: str, seed: int) -> Policy:
    if spec == "expert":
        return ExpertPolicy(env)
    if spec == "zero":
        return ZeroPolicy()
    if spec == "random":
        return RandomPolicy(seed)
    if spec.startswith("replay:"):
        return load_replay(spec[len("replay:"):], task)
    if ":" in spec:
        return user_policy(spec)
    from univtac_data.storage.errors import DatasetError

    raise DatasetError(f"--policy must be expert, zero, random, replay:DATASET or module:factory (got {spec!r})")


def _checked_action(action: Any) -> np.ndarray:
    array = np.asarray(action, dtype=np.float64)
    if array.shape != (8,):
        raise ValueError(f"the policy returned an action of shape {array.shape}; expected (8,) "
                         f"(x, y, z m; qw, qx, qy, qz; width m)")
    return array


def step_limit(env: TaskEnv) -> int:
    """The task's step limit as a time limit: ``max_steps`` is counted at the tasks' 50 Hz, so a rollout at
    ``rate_hz`` gets ``max_steps * rate_hz / 50`` steps (the same seconds; ``Task.step_limit``, which
    ``generate`` keeps its demonstrations within too)."""
    return env.task.step_limit


def rollout(env: TaskEnv, policy: Policy, seed: int, video: Any | None = None) -> Rollout:
    obs, info = env.reset(seed=seed)
    limit = step_limit(env)
    steps = 0
    try:
        policy.reset()
        if video is not None:
            video(obs)
        for steps in range(1, limit + 1):
            obs, _, terminated, _, info = env.step(_checked_action(policy.act(obs)))
            if video is not None:
                video(obs)
            if terminated:
                break
    except Exception as error:  # a policy (or its action) failed: this rollout fails, the evaluation goes on
        return Rollout(seed, False, False, f"error: {type(error).__name__}: {error}", steps)
    if info["is_success"]:
        return Rollout(seed, True, False, "success", steps)
    if not info["safety"]["ok"]:
        return Rollout(seed, False, True, f"unsafe: {info['safety']['reason']}", steps)
    return Rollout(seed, False, False, "step_limit", steps)


def _video_frame(obs: dict[str, Any]) -> np.ndarray:
    """The head camera (if any) beside both pads' tactile images, all at one height (even sizes)."""
    from PIL import Image

    pixels = obs["pixels"]
    tiles = [pixels[k] for k in ("head", "tactile_left", "tactile_right") if k in pixels]
    height = max(t.shape[0] for t in tiles)
    height += height % 2
    scaled = []
    for tile in tiles:
        width = max(2, round(tile.shape[1] * height / tile.shape[0]))
        scaled.append(np.asarray(Image.fromarray(tile).resize((width + width % 2, height))))
    return np.concatenate(scaled, axis=1)


def evaluate(task: str, policy_spec: str, *, episodes: int = 100, seed: int = 0, env_kwargs: dict[str, Any] | None = None,
             video_dir: str | None = None, videos: int = 3, progress: bool = True) -> EvaluationReport:
    env = TaskEnv(task, **(env_kwargs or {}))
    report = EvaluationReport(task, policy_spec)
    try:
        policy = make_policy(policy_spec, env, task, seed)
        if isinstance(policy, ReplayPolicy):
            seeds = list(policy.episodes)[:episodes]
        else:
            seeds = [EVAL_SEED_BASE + seed + k for k in range(episodes)]
        start = time.perf_counter()
        for k, rollout_seed in enumerate(tqdm(seeds, desc=f"evaluate {task}", unit="rollout", disable=not progress,
                                             file=sys.stderr)):
            if isinstance(policy, ReplayPolicy):
                policy.start(rollout_seed)
            writer = None
            if video_dir is not None and k < videos:
                writer = _VideoRecorder(os.path.join(video_dir, f"{task}-{rollout_seed}.mp4"), int(env.config.rate_hz))
            try:
                report.rollouts.append(rollout(env, policy, rollout_seed, writer))
            finally:
                if writer is not None:
                    writer.close()
        report.elapsed_s = time.perf_counter() - start
    finally:
        env.close()
    return report


class _VideoRecorder:
    """Writes each observation as a video frame; the file appears under its name only once complete."""

    def __init__(self, path: str, fps: int) -> None:
        self.path, self.fps = path, fps
        self.tmp = path + ".part.mp4"
        self._writer: Any = None

    def __call__(self, obs: dict[str, Any]) -> None:
        frame = _video_frame(obs)
        if self._writer is None:
            from univtac_data.export.video import Mp4Writer

            os.makedirs(os.path.dirname(self.path) or ".", exist_ok=True)
            self._writer = Mp4Writer(self.tmp, frame.shape[1], frame.shape[0], self.fps)
        self._writer.write(frame)

    def close(self) -> None:
        if self._writer is not None:
            self._writer.close()
            os.replace(self.tmp, self.path)


__all__ = ["EvaluationReport", "Rollout", "evaluate", "rollout", "step_limit", "wilson_interval"]
