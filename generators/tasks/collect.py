"""Expert demonstrations: run a task's expert on seed after seed, keep the successful, safe episodes.

Seeds are tried in order from the base seed (``base_seed + k``, all below ``EVAL_SEED_BASE``). Workers run
seeds in parallel and write each episode under a temporary name; the driver decides in seed order, so the
dataset is the first N successes whatever the worker count, and a rerun after a kill resumes after the last
kept seed (every earlier seed has been decided) and ends with the dataset an uninterrupted run makes.
With ``keep_failures`` failed or unsafe episodes are kept too, flagged (``success`` false,
``extra.task.kept_failure``), and do not count towards N.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from univtac_data.episode import Episode
from univtac_data.generators.allocator import keep_freed_memory
from univtac_data.generators.runner import check_executor, run_specs
from univtac_data.generators.scene.recording import build_episode
from univtac_data.generators.scene.threads import one_blas_thread
from univtac_data.generators.tasks.base import EVAL_SEED_BASE, TaskConfig
from univtac_data.generators.tasks.expert_rollout import expert_rollout
from univtac_data.generators.tasks.registry import make_task
from univtac_data.progress import Progress
from univtac_data.generators.tasks.session import TaskSession
from univtac_data.schema.models import GeneratorInfo
from univtac_data.storage import DatasetWriter, Location, WrittenEpisode, discard_staged, publish_staged, write_episode_file
from univtac_data.storage.errors import DatasetError
from univtac_data.version import __version__

GENERATOR_NAME = "univtac_data.generators.tasks"


@dataclass(frozen=True)
class TaskEpisodeSpec:
    """Everything that determines one task episode (same spec, same arrays)."""

    task: str
    seed: int
    config: TaskConfig = field(default_factory=TaskConfig)

    @property
    def episode_id(self) -> str:
        return f"{self.task}-{self.config.sensor}-{self.seed:06d}"

    @property
    def sensor(self) -> str:
        return self.config.sensor


@dataclass
class ExpertOutcome:
    """One expert rollout: its result and, when recorded, its episode."""

    seed: int
    success: bool
    safe: bool
    steps: int
    violation: str | None
    memory: dict[str, Any]
    episode: Episode | None = None
    max_in_hand_slip_mm: float = 0.0  # the held object's largest move in the gripper frame, mm (a safety rule)


def run_expert(spec: TaskEpisodeSpec, *, record: bool = True, corrections: bool = True) -> ExpertOutcome:
    """Run the task's expert from ``spec.seed`` until its script ends or the step limit (a time limit, the
    same as ``evaluate``'s: ``Task.step_limit``); record it if asked.
    ``corrections=False`` runs the expert with its corrections switched off (to measure what they are worth)."""
    task = make_task(spec.task, spec.config)
    with expert_rollout(task, spec.seed, record=record, corrections=corrections) as run:
        state = run.run()
        session = run.session
        outcome = ExpertOutcome(spec.seed, bool(task.success(state)), session.safe, session.steps,
                                session.first_violation(), _jsonable(run.ctx.memory),
                                max_in_hand_slip_mm=float(session.max_in_hand_slip_mm))
        if record:
            with one_blas_thread():
                outcome.episode = _episode(spec, session, outcome)
        return outcome


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return value


def _episode(spec: TaskEpisodeSpec, session: TaskSession, outcome: ExpertOutcome) -> Episode:
    sim = session.sim
    assert sim is not None
    actions = np.array(session.actions + [session.last_action], dtype=np.float32)
    settings = {"task": spec.task, "seed": spec.seed, **asdict(spec.config)}
    extra = {"task": {"layout": _jsonable(session.layout), "steps": session.steps, "safe": outcome.safe,
                      "violation": outcome.violation, "max_indentation_mm": session.max_indentation_mm,
                      "max_in_hand_slip_mm": session.max_in_hand_slip_mm, "memory": outcome.memory,
                      "max_steps": session.task.step_limit}}
    return build_episode(
        sim.frames, sim.pixel_arrays(), episode_id=spec.episode_id, kind="task", name=spec.task,
        sensor=spec.config.sensor, seed=spec.seed, generator=GeneratorInfo(name=GENERATOR_NAME, version=__version__,
                                                                          settings=_jsonable(settings)),
        success=outcome.success and outcome.safe, rate_hz=spec.config.rate_hz,
        primitive_names=session.task.primitive_names, reference_rgb=sim.reference_rgb(),
        cameras=[c.info(sim.model) for c in sim.camera_specs], actions=actions, extra=extra)


@dataclass
class SeedResult:
    """What a worker hands back for one seed."""

    seed: int
    kept: bool  # success and safe
    written: WrittenEpisode | None  # staged, when kept (or when failures are kept)
    frames: int
    violation: str | None


def produce_task_episode(spec: TaskEpisodeSpec, url: str, storage: str, level: int, keep_failures: bool) -> SeedResult:
    """Run and record one seed; write its file under a temporary name when it may be kept (worker side)."""
    keep_freed_memory()
    outcome = run_expert(spec)
    kept = outcome.success and outcome.safe
    written = None
    assert outcome.episode is not None
    if kept or keep_failures:
        if not kept:
            outcome.episode.meta.extra["task"]["kept_failure"] = True
        written = write_episode_file(Location.parse(url), storage, outcome.episode, compression_level=level,
                                     publish=False)
    return SeedResult(spec.seed, kept, written, outcome.episode.meta.n_frames, outcome.violation)


@dataclass
class CollectSummary:
    """What a collection run did."""

    task: str
    wanted: int
    already: int  # successful episodes there before this run
    tried: int = 0  # seeds run by this run
    kept: int = 0
    failed_seeds: list[int] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    frames: int = 0
    elapsed_s: float = 0.0
    stopped: str = ""  # why the run ended short of ``wanted``: the seed range or --max-seeds ran out

    @property
    def success_rate(self) -> float:
        return self.kept / self.tried if self.tried else 0.0


def collect(url: str, task: str, episodes: int, *, config: TaskConfig, base_seed: int = 0, storage: str = "hdf5",
            workers: int = 1, executor: str = "local", ray_address: str | None = None, keep_failures: bool = False,
            compression_level: int = 1, max_seeds: int | None = None, progress: bool = True) -> CollectSummary:
    """Add successful expert episodes of ``task`` to the dataset at ``url`` until it holds ``episodes``."""
    make_task(task, config)  # unknown task or bad settings fail before anything is written
    if not 0 <= base_seed < EVAL_SEED_BASE:
        raise DatasetError(f"--seed must be in [0, {EVAL_SEED_BASE}) (evaluation seeds start at {EVAL_SEED_BASE})")
    check_executor(executor, ray_address)
    with DatasetWriter.open(url, storage=storage, sensors=[config.sensor]) as writer:  # one writer per dataset
        summary = _collect_into(writer, url, task, episodes, config, base_seed, storage, workers, executor,
                                ray_address, keep_failures, compression_level, max_seeds, progress)
        writer.recover()  # temporaries of seeds still running when the run had enough
    return summary


def _check_same_settings(writer: DatasetWriter, rows: list[Any], task: str, config: TaskConfig) -> None:
    """Refuse to add episodes made with other settings to this task's episodes: every row's rate from the
    index (cheap), and one episode's stored settings (all of a task's episodes in a dataset share them)."""
    for row in rows:
        if abs(row.nominal_rate_hz - config.rate_hz) > 1e-9:
            raise DatasetError(f"{writer.loc.url_of(row.path)}: recorded at {row.nominal_rate_hz} Hz, this run asks "
                               f"for {config.rate_hz} Hz; rerun with the same options or choose a new --out")
    if not rows:
        return
    with writer.store.open(writer.loc, rows[0].path) as handle:
        stored = handle.meta.generator.settings
    wanted = _jsonable({"task": task, **asdict(config)})
    for key, value in wanted.items():
        if key in stored and stored[key] != value:
            raise DatasetError(f"{writer.loc.url_of(rows[0].path)}: made with {key}={stored[key]!r}, this run asks "
                               f"for {key}={value!r}; rerun with the same options or choose a new --out")


def _collect_into(writer: DatasetWriter, url: str, task: str, episodes: int, config: TaskConfig, base_seed: int,
                  storage: str, workers: int, executor: str, ray_address: str | None, keep_failures: bool,
                  compression_level: int, max_seeds: int | None, progress: bool) -> CollectSummary:
    mine = [row for row in writer.index.values() if row.kind == "task" and row.name == task and row.sensor == config.sensor]
    _check_same_settings(writer, mine, task, config)
    done = sum(1 for row in mine if row.success)
    summary = CollectSummary(task, episodes, done)
    if done >= episodes:
        return summary
    start_seed = max([row.seed + 1 for row in mine] + [base_seed])
    limit = max_seeds if max_seeds is not None else 20 * episodes
    last_seed = min(start_seed + limit, EVAL_SEED_BASE)
    specs = (TaskEpisodeSpec(task, seed, config) for seed in range(start_seed, last_seed))
    loc = Location.parse(url)
    bar = Progress(episodes, initial=done, desc=f"generate {task}", enabled=progress)
    t0 = time.perf_counter()
    waiting: dict[int, SeedResult | BaseException] = {}
    next_seed = start_seed
    stream: Iterator[Any] = run_specs(produce_task_episode, specs, (url, storage, compression_level, keep_failures),
                                      workers=workers, executor=executor, ray_address=ray_address)
    try:
        for spec, result in stream:
            waiting[spec.seed] = result
            while next_seed in waiting and done < episodes:
                result = waiting.pop(next_seed)
                summary.tried += 1
                if isinstance(result, BaseException):
                    summary.errors.append(f"seed {next_seed}: {type(result).__name__}: {result}")
                    summary.failed_seeds.append(next_seed)
                else:
                    if not result.kept:
                        summary.failed_seeds.append(next_seed)
                    if result.written is not None:
                        writer.commit([publish_staged(loc, result.written)])
                        summary.frames += result.frames
                    if result.kept:
                        summary.kept += 1
                        done += 1
                        bar.update(1, tried=summary.tried, success=f"{summary.success_rate:.0%}")
                next_seed += 1
            if done >= episodes:
                break
    finally:
        close = getattr(stream, "close", None)
        if close is not None:
            close()
        for leftover in waiting.values():
            if isinstance(leftover, SeedResult) and leftover.written is not None:
                discard_staged(loc, leftover.written)
        bar.close()
        summary.elapsed_s = time.perf_counter() - t0
    if done < episodes and next_seed >= last_seed:
        if last_seed == EVAL_SEED_BASE:
            summary.stopped = (f"no demonstration seed left: seeds {start_seed} to {EVAL_SEED_BASE - 1} are all "
                               f"tried (evaluation seeds start at {EVAL_SEED_BASE}); use a lower --seed or a new --out")
        else:
            summary.stopped = (f"gave up after seeds {start_seed} to {last_seed - 1} (--max-seeds {limit}; "
                               f"the default is 20 a wanted episode)")
    return summary
