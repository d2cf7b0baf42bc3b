"""Run a corpus: episodes in parallel (a local process pool or Ray), committed as they finish, resumable.

Each worker simulates one episode and writes its file with ``write_episode_file`` (atomic, checksummed);
the driver alone commits index and manifest. Episodes already in the dataset are skipped, so rerunning the
same command after a kill finishes the job, and because every episode is a pure function of its spec the
result is the same dataset an uninterrupted run makes.
"""

from __future__ import annotations

import ctypes
import logging
import os
import signal
import socket
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import MISSING, asdict, dataclass, field, fields
from multiprocessing import get_context
from typing import Any, TypeVar

from univtac_data.generators.allocator import keep_freed_memory
from univtac_data.generators.indenters.corpus import IndenterEpisodeSpec, run_indenter_episode
from univtac_data.generators.reaper import start_reaper, stop_reaper
from univtac_data.progress import Progress
from univtac_data.storage import DatasetWriter, Location, WrittenEpisode, write_episode_file
from univtac_data.storage.encoding import ZSTD_LEVELS
from univtac_data.storage.errors import DatasetError

S = TypeVar("S")
R = TypeVar("R")
_END: Any = object()  # marks the end of a spec iterator


@dataclass
class RunSummary:
    """What a run did."""

    planned: int
    skipped_existing: int
    written: int = 0
    frames: int = 0
    failed: list[str] = field(default_factory=list)  # one line each: episode id and error
    elapsed_s: float = 0.0

    @property
    def frames_per_s(self) -> float:
        return self.frames / self.elapsed_s if self.elapsed_s > 0 else 0.0


# Blosc level per contact model when a run does not choose one. Elastic residual images are wide and low,
# where level 3 saves the most (about 15 %: GF225 elastic frames go from 290 to 246 KiB, inside the size
# budget), and it costs about an eighth of their rate, which the elastic rows can spare above their target
# (25 frames/s/core); geometric frames are small at level 1 already, and their rate has little to spare.
AUTO_COMPRESSION_LEVEL = {"geometric": 1, "elastic": 3}
# ... except the GF225's geometric frames (480 x 480, 2.25 times the Mini's pixels), which the half-space's
# sink-in took past the 265 KiB budget at level 1 (277.5 KiB a frame over the 14 shapes,
# benchmarks/results/generate_throughput_fidelity.json); level 2 makes them 262.8 KiB (generate_throughput.json).
AUTO_COMPRESSION_LEVEL_BY_SENSOR = {("gf225", "geometric"): 2}


def compression_level_for(spec: IndenterEpisodeSpec, level: int | None = None) -> int:
    """The Blosc level ``spec``'s episode is written at: ``level``, or by its sensor and contact model when None."""
    if level is not None:
        return level
    return AUTO_COMPRESSION_LEVEL_BY_SENSOR.get((spec.sensor, spec.contact_method),
                                                AUTO_COMPRESSION_LEVEL[spec.contact_method])


def produce_indenter_episode(spec: IndenterEpisodeSpec, url: str, storage: str,
                             compression_level: int | None = None) -> WrittenEpisode:
    """Simulate one episode and write its file (runs in a worker, which keeps its freed memory)."""
    keep_freed_memory()
    episode = run_indenter_episode(spec)
    return write_episode_file(Location.parse(url), storage, episode,
                              compression_level=compression_level_for(spec, compression_level))


def _check_same_settings(writer: DatasetWriter, specs: list[IndenterEpisodeSpec]) -> None:
    """Refuse to resume into episodes made with other settings: the dataset would silently mix them. Every
    finished episode is checked from its index row (seed, frames, rate, sensor, shape: no file opened), and one
    episode's stored settings are compared in full (contact model, gel, time step are in the file only)."""
    done = [s for s in specs if writer.has(s.episode_id)]
    if not done:
        return
    for spec in done:
        row = writer.index[spec.episode_id]
        for key, made_with, wanted in (("seed", row.seed, spec.seed), ("frames", row.n_frames, spec.frames),
                                       ("record_rate_hz", row.nominal_rate_hz, spec.record_rate_hz),
                                       ("sensor", row.sensor, spec.sensor), ("shape", row.name, spec.shape)):
            if made_with != wanted:
                hint = " (derived from --seed)" if key == "seed" else ""
                raise DatasetError(f"{writer.loc.url_of(row.path)}: made with {key}={made_with!r}, this run asks for "
                                   f"{key}={wanted!r}{hint}; rerun with the same options or choose a new --out")
    row = writer.index[done[0].episode_id]
    with writer.store.open(writer.loc, row.path) as handle:
        stored = handle.meta.generator.settings
    # a setting added since the dataset was made (e.g. ``gel``) had its default value then
    defaults = {f.name: f.default for f in fields(IndenterEpisodeSpec) if f.default is not MISSING}
    for key, wanted in asdict(done[0]).items():
        made_with = stored.get(key, defaults.get(key))
        if made_with != wanted:
            raise DatasetError(f"{writer.loc.url_of(row.path)}: made with {key}={made_with!r}, "
                               f"this run asks for {key}={wanted!r}; rerun with the same options or choose a new --out")


PR_SET_PDEATHSIG = 1  # <linux/prctl.h>
WATCHDOG_PERIOD_S = 1.0


def _die_with_parent(parent_pid: int) -> None:
    """Pool worker initializer: end this worker when the process that started it dies, even by SIGKILL
    (whose pool cannot tell its workers anything). On Linux the kernel sends SIGKILL (prctl
    PR_SET_PDEATHSIG); everywhere a daemon thread also watches the parent's pid, for a worker busy in Python.
    (Linux signals on the exit of the *thread* that started the worker: iterate ``run_specs`` from one thread
    that lives as long as the run, as ``run_corpus`` does.)"""
    if os.uname().sysname == "Linux":
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent_pid:  # the parent died before prctl took effect
        os._exit(1)

    def watch() -> None:
        while True:
            time.sleep(WATCHDOG_PERIOD_S)
            if os.getppid() != parent_pid:
                os._exit(1)

    threading.Thread(target=watch, name="parent-watchdog", daemon=True).start()


def _local(produce: Callable[..., R], specs: Iterable[S], args: tuple[Any, ...], workers: int) \
        -> Iterator[tuple[S, R | BaseException]]:
    """``produce(spec, *args)`` for every spec, in a process pool of ``workers`` (inline for 1), yielding each
    spec with its result or its exception as they finish (in any order). Specs are drawn lazily, at most
    ``2 * workers`` ahead of the results taken, so ``specs`` may be endless and closing the stream stops it."""
    if workers <= 1:
        for spec in specs:
            try:
                yield spec, produce(spec, *args)
            except Exception as error:  # one bad episode must not end the run; it is reported
                yield spec, error
        return
    # spawn: no inherited locks or file handles from the driver (h5py and threads do not survive fork)
    with ProcessPoolExecutor(max_workers=workers, mp_context=get_context("spawn"), initializer=_die_with_parent,
                             initargs=(os.getpid(),)) as pool:
        pending: dict[Future[R], S] = {}
        queue = iter(specs)
        exhausted = False
        try:
            while not exhausted or pending:
                while not exhausted and len(pending) < 2 * workers:
                    spec = next(queue, _END)
                    if spec is _END:
                        exhausted = True
                        break
                    pending[pool.submit(produce, spec, *args)] = spec
                done, _ = wait(pending, return_when=FIRST_COMPLETED)
                for future in done:
                    spec = pending.pop(future)
                    failure = future.exception()
                    yield spec, failure if failure is not None else future.result()
        except BaseException:
            for future in pending:
                future.cancel()
            raise


def _ray(produce: Callable[..., R], specs: Iterable[S], args: tuple[Any, ...], workers: int, address: str | None) \
        -> Iterator[tuple[S, R | BaseException]]:
    """As ``_local``, as Ray tasks (a local Ray with ``workers`` CPUs, or the cluster at ``address``)."""
    check_executor("ray", address)
    import ray

    started_here = not ray.is_initialized()
    reaper = None
    if started_here:
        kwargs: dict[str, Any] = {"address": address} if address else {"num_cpus": workers}
        if not address:  # a local Ray: its processes must not outlive this driver, even SIGKILLed
            reaper = start_reaper()
        ray.init(include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR, **kwargs)
    try:
        remote = ray.remote(num_cpus=1)(produce)
        queue, futures = iter(specs), {}
        while True:
            while len(futures) < 2 * workers:
                spec = next(queue, _END)
                if spec is _END:
                    break
                futures[remote.remote(spec, *args)] = spec
            if not futures:
                break
            done, _ = ray.wait(list(futures), num_returns=1)
            spec = futures.pop(done[0])
            try:
                yield spec, ray.get(done[0])
            except Exception as error:  # ray wraps the worker's exception; report it per episode
                yield spec, error
    finally:
        if started_here:
            ray.shutdown()
        stop_reaper(reaper)


RAY_CONNECT_TIMEOUT_S = 5.0


def check_executor(executor: str, ray_address: str | None = None) -> None:
    """Fail early, in one line, when the executor cannot run: no Ray installed, or a Ray address that does not
    answer (``ray.init`` would retry for minutes). Call it before creating any output."""
    if executor not in ("local", "ray"):
        raise DatasetError(f"unknown executor {executor!r}; choose local or ray")
    if executor != "ray":
        return
    try:
        import ray  # noqa: F401
    except ImportError:
        raise DatasetError("--executor ray needs Ray: pip install 'univtac-data[ray]'") from None
    if not ray_address or ray_address == "auto":
        return
    target = ray_address.split("://", 1)[-1].rstrip("/")
    host, _, port = target.rpartition(":")
    if not host or not port.isdigit():
        raise DatasetError(f"--ray-address {ray_address}: expected HOST:PORT or ray://HOST:PORT")
    try:
        socket.create_connection((host, int(port)), timeout=RAY_CONNECT_TIMEOUT_S).close()
    except OSError as error:
        raise DatasetError(f"--ray-address {ray_address}: no Ray cluster answers there "
                           f"({error.strerror or error or 'timed out'})") from None


def run_specs(produce: Callable[..., R], specs: Iterable[S], args: tuple[Any, ...], *, workers: int = 1,
              executor: str = "local", ray_address: str | None = None) -> Iterator[tuple[S, R | BaseException]]:
    """``produce(spec, *args)`` for every spec on the chosen executor, yielding (spec, result or exception)
    as each finishes. ``produce`` must be a module-level function (it is pickled to the workers)."""
    if executor == "ray":
        return _ray(produce, specs, args, workers, ray_address)
    return _local(produce, specs, args, workers)


def run_corpus(url: str, specs: list[IndenterEpisodeSpec], *, storage: str = "hdf5", workers: int = 1,
               executor: str = "local", ray_address: str | None = None, progress: bool = True,
               compression_level: int | None = None) -> RunSummary:
    """Make every episode of ``specs`` that the dataset at ``url`` lacks. ``compression_level``: Blosc level
    1 to 9 of the episode files (None: ``compression_level_for``, by sensor and contact model)."""
    if compression_level is not None and compression_level not in ZSTD_LEVELS:
        raise DatasetError(f"--compression-level must be {ZSTD_LEVELS.start} to {ZSTD_LEVELS.stop - 1} "
                           f"(got {compression_level})")
    if workers < 1:
        raise DatasetError(f"--workers must be at least 1 (got {workers})")
    check_executor(executor, ray_address)  # before any file is created
    sensors = sorted({s.sensor for s in specs})
    with DatasetWriter.open(url, storage=storage, sensors=sensors) as writer:  # the dataset's writer lock
        _check_same_settings(writer, specs)
        todo = [s for s in specs if not writer.has(s.episode_id)]
        summary = RunSummary(planned=len(specs), skipped_existing=len(specs) - len(todo))
        if not todo:
            return summary
        start = time.perf_counter()
        bar = Progress(len(specs), initial=summary.skipped_existing, desc="generate", enabled=progress)
        stream = run_specs(produce_indenter_episode, todo, (url, storage, compression_level), workers=workers,
                           executor=executor, ray_address=ray_address)
        try:
            for spec, result in stream:
                if isinstance(result, BaseException):
                    summary.failed.append(f"{spec.episode_id}: {type(result).__name__}: {result}")
                else:
                    writer.commit([result])
                    summary.written += 1
                    summary.frames += result.row.n_frames
                summary.elapsed_s = time.perf_counter() - start
                bar.update(1, frames_per_s=f"{summary.frames_per_s:.0f}", failed=len(summary.failed))
        finally:
            bar.close()
            summary.elapsed_s = time.perf_counter() - start
    return summary


def default_workers() -> int:
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1))
