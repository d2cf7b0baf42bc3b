"""The entry point: ``validate(path)`` runs the selected rule groups on every episode and returns a ``Report``.

Episodes are independent: with ``workers > 1`` a process pool checks them in parallel. Each worker opens
the dataset itself (no h5py or zarr handle crosses a process boundary) and is started from a fresh
forkserver, not forked from a parent that may hold library threads.
"""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed

import numpy as np

from univtac_data.progress import Progress
from univtac_data.schema.sensors import SensorProfile
from univtac_data.storage.dataset import Dataset, episode_relpath
from univtac_data.storage.errors import DatasetError, FormatVersionError
from univtac_data.validators.config import ValidationConfig
from univtac_data.validators.context import DatasetView, EpisodeContext, EpisodeSource, load_context, one_line
from univtac_data.validators.registry import GROUPS, RULES, Rule, Skip, rules_in
from univtac_data.validators.report import CheckResult, EpisodeReport, Finding, Report
from univtac_data.validators.rules_schema import checksum_findings, index_row_findings
from univtac_data.version import __version__

ALWAYS_REPORTED = "schema.readable"  # read failures are findings whatever groups are selected


def parse_groups(groups: Iterable[str] | str | None) -> tuple[str, ...]:
    """Normalise a group selection (None: all; a comma-separated string or names); ValueError if unknown."""
    if groups is None:
        return GROUPS
    names = [g.strip() for g in (groups.split(",") if isinstance(groups, str) else groups) if g.strip()]
    unknown = [g for g in names if g not in GROUPS]
    if unknown or not names:
        raise ValueError(f"groups must be among {', '.join(GROUPS)} (got {', '.join(names) or 'none'})")
    return tuple(g for g in GROUPS if g in names)


def _threshold(rule: Rule, ctx: EpisodeContext | None, config: ValidationConfig) -> float | None:
    if rule.threshold is None:
        return None
    if rule.threshold.startswith("profile."):
        if ctx is None or ctx.profile is None:
            return None
        return float(getattr(ctx.profile, rule.threshold.split(".", 1)[1]))
    return float(getattr(config, rule.threshold))


def run_rule(rule: Rule, target: EpisodeContext | DatasetView, config: ValidationConfig) -> CheckResult:
    """One rule on one episode context (or dataset view); an unanticipated exception becomes a failure."""
    ctx = target if isinstance(target, EpisodeContext) else None
    common = dict(rule=rule.name, group=rule.group, threshold_name=rule.threshold,
                  threshold=_threshold(rule, ctx, config))
    try:
        with np.errstate(all="ignore"):
            findings = rule.func(target)
    except Skip as reason:
        return CheckResult(status="skip", note=str(reason), **common)  # type: ignore[arg-type]
    except Exception as error:  # bad data must never crash a run; say which rule tripped and how
        message = f"rule {rule.name} could not evaluate the data ({type(error).__name__}: {one_line(error)})"
        return CheckResult(status="fail", findings=[Finding(message=message)], **common)  # type: ignore[arg-type]
    return CheckResult(status="fail" if findings else "pass", findings=findings, **common)  # type: ignore[arg-type]


def _result(name: str, findings: list[Finding]) -> CheckResult:
    rule = RULES[name]
    return CheckResult(rule=name, group=rule.group, status="fail" if findings else "pass", findings=findings,
                       threshold_name=rule.threshold)


def _unopened(rules: list[Rule], failing: str, findings: list[Finding], why: str, config: ValidationConfig,
              source: EpisodeSource | None = None) -> list[CheckResult]:
    """Results when the episode could not be opened or read: ``failing`` fails; with a ``source`` the
    checksums still say whether the files changed since they were written; every other rule is skipped."""
    out = [CheckResult(rule=failing, group=RULES[failing].group, status="fail", findings=findings,
                       threshold_name=RULES[failing].threshold)]
    for rule in rules:
        if rule.name == failing:
            continue
        if rule.name == "schema.checksums" and source is not None:
            try:
                out.append(_result(rule.name, checksum_findings(source)))
            except Exception as error:  # an unreadable file system entry is a finding too
                out.append(_result(rule.name, [Finding(message=f"checksums cannot be computed "
                                                               f"({type(error).__name__}: {one_line(error)})")]))
            continue
        out.append(CheckResult(rule=rule.name, group=rule.group, status="skip", note=why,
                               threshold_name=rule.threshold, threshold=_threshold(rule, None, config)))
    return out


def validate_episode(dataset: Dataset, view: DatasetView, episode_id: str, groups: Sequence[str],
                     config: ValidationConfig) -> EpisodeReport:
    """Every rule of ``groups`` on one episode. Never raises on bad data."""
    rules = rules_in(groups)
    row = dataset.index.get(episode_id)
    relpath = row.path if row is not None else episode_relpath(episode_id, dataset.store)
    source = EpisodeSource(loc=dataset.loc, episode_id=episode_id, row=row, relpath=relpath,
                           manifest=view.manifest, manifest_error=view.manifest_error)
    n_frames = row.n_frames if row is not None else None

    def report(checks: list[CheckResult], frames: int | None = n_frames) -> EpisodeReport:
        return EpisodeReport(episode_id=episode_id, path=relpath, n_frames=frames, checks=checks)

    missing = index_row_findings(source, None)
    if missing:
        return report(_unopened(rules, "schema.index_row", missing, "the episode is not on disk", config))
    try:
        handle = dataset.store.open(dataset.loc, relpath)
    except FormatVersionError as error:
        findings = [Finding(message=str(error), field=dataset.loc.url_of(relpath))]
        return report(_unopened(rules, "schema.format_version", findings,
                                "the episode cannot be read in this format version", config, source))
    except Exception as error:  # DatasetError from the stores, or anything a damaged file provokes
        text = str(error) if isinstance(error, DatasetError) else \
            f"{dataset.loc.url_of(relpath)}: cannot open ({type(error).__name__}: {one_line(error)})"
        return report(_unopened(rules, ALWAYS_REPORTED, [Finding(message=text, field=dataset.loc.url_of(relpath))],
                                "the episode cannot be opened", config, source))
    try:
        with handle, np.errstate(all="ignore"):
            ctx = load_context(handle, source, _profile(dataset, handle.meta.sensor), dataset.info, config)
    except Exception as error:
        findings = [Finding(message=f"{handle.where}: reading failed ({type(error).__name__}: {one_line(error)})",
                            field=handle.where)]
        return report(_unopened(rules, ALWAYS_REPORTED, findings, "the episode could not be read", config, source))
    if all(r.name != ALWAYS_REPORTED for r in rules):
        rules = [RULES[ALWAYS_REPORTED], *rules]
    return report([run_rule(r, ctx, config) for r in rules], ctx.n_frames)


def _profile(dataset: Dataset, sensor: str) -> SensorProfile | None:
    try:
        return dataset.sensor(sensor)
    except KeyError:
        return None


def dataset_view(dataset: Dataset) -> DatasetView:
    try:
        manifest, error = dataset.manifest(), None
    except DatasetError as failure:
        manifest, error = None, str(failure)
    return DatasetView(loc=dataset.loc, info=dataset.info, index=dataset.index, manifest=manifest,
                       manifest_error=error)


# --- worker processes ----------------------------------------------------------------------------------------

_WORKER: tuple[Dataset, DatasetView, tuple[str, ...], ValidationConfig] | None = None


def _init_worker(path: str, groups: tuple[str, ...], config: ValidationConfig) -> None:
    global _WORKER
    dataset = Dataset.open(path)
    _WORKER = (dataset, dataset_view(dataset), groups, config)


def _worker_validate(episode_id: str) -> EpisodeReport:
    assert _WORKER is not None, "worker used before _init_worker"
    dataset, view, groups, config = _WORKER
    return validate_episode(dataset, view, episode_id, groups, config)


def _pool_context() -> multiprocessing.context.BaseContext:
    if "forkserver" in multiprocessing.get_all_start_methods():
        context = multiprocessing.get_context("forkserver")
        context.set_forkserver_preload(["univtac_data.validators.runner"])
        return context
    return multiprocessing.get_context("spawn")


def _progress(total: int, enabled: bool) -> Progress:
    # a bar on a terminal, plain lines every few seconds in a log
    return Progress(total, desc="validate", enabled=enabled)


def validate(path: str | os.PathLike[str], *, groups: Iterable[str] | str | None = None,
             episodes: Iterable[str] | None = None, workers: int = 1, config: ValidationConfig | None = None,
             progress: bool = False) -> Report:
    """Validate the dataset at ``path``.

    groups: rule groups to run ('schema', 'safety', 'physics'); None runs all. Read failures are always
    reported (rule ``schema.readable``). episodes: ids to check (default: every indexed episode; an id not
    in the index is reported as failing). workers: processes checking episodes in parallel. progress: a
    tqdm bar on stderr when it is a terminal, plain periodic lines when it is not.

    Raises ``DatasetError`` (one line naming the file) when the dataset itself is unusable: missing path,
    not a dataset, unreadable info.json or index, another major format version. Bad episodes never raise.
    """
    selected = parse_groups(groups)
    if workers < 1:
        raise ValueError(f"workers must be >= 1 (got {workers})")
    config = config or ValidationConfig()
    dataset = Dataset.open(path)
    view = dataset_view(dataset)
    dataset_checks = [run_rule(r, view, config) for r in rules_in(selected, scope="dataset")]
    ids = sorted(dataset.index) if episodes is None else list(dict.fromkeys(episodes))
    results: dict[str, EpisodeReport] = {}
    with _progress(len(ids), progress) as bar:
        if workers == 1 or len(ids) < 2:
            for episode_id in ids:
                results[episode_id] = validate_episode(dataset, view, episode_id, selected, config)
                bar.update(1)
        else:
            with ProcessPoolExecutor(max_workers=min(workers, len(ids)), mp_context=_pool_context(),
                                     initializer=_init_worker, initargs=(os.fspath(path), selected, config)) as pool:
                futures = {pool.submit(_worker_validate, eid): eid for eid in ids}
                for future in as_completed(futures):
                    results[futures[future]] = future.result()
                    bar.update(1)
    return Report(dataset=dataset.loc.url, storage=dataset.info.storage, format_version=dataset.info.format_version,
                  validator_version=__version__, groups=list(selected), config=config, dataset_checks=dataset_checks,
                  episodes={eid: results[eid] for eid in ids})
