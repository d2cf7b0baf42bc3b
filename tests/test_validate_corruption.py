"""Damaged data never crashes the validator: every corruption is a failing finding for the right episode,
and the other episodes are still checked (and pass)."""

from __future__ import annotations

import shutil
import tempfile
from functools import lru_cache
from pathlib import Path

import numpy as np
from factories import make_episode
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_validate_support import (
    STORAGES,
    episode_files,
    failing,
    refresh_safety,
    replace_array,
    write_dataset,
)

from univtac_data.schema.fields import field_for_path
from univtac_data.storage import DatasetWriter
from univtac_data.validators import Report, validate

N_FRAMES = 3
SETTINGS = settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
_TEMPLATES = Path(tempfile.mkdtemp(prefix="univtac-validate-templates-"))


@lru_cache(maxsize=None)
def template(storage: str, n_episodes: int) -> Path:
    """A clean dataset of ``n_episodes`` small episodes (ep0, ep1, ...), built once per test session."""
    root = _TEMPLATES / f"{storage}-{n_episodes}"
    write_dataset(root, [make_episode("gelsight_mini", N_FRAMES, f"ep{k}", seed=k) for k in range(n_episodes)],
                  storage)
    return root


def fresh_copy(storage: str, n_episodes: int, into: str) -> Path:
    root = Path(into) / "ds"
    shutil.copytree(template(storage, n_episodes), root)
    return root


def assert_only(report: Report, bad: str, others: tuple[str, ...] = ("ep0", "ep1")) -> None:
    """``bad`` fails with at least one finding; every other episode passes."""
    assert report.failed_episodes() == [bad]
    failed = report.episodes[bad].failed_checks()
    assert failed and all(c.findings for c in failed)
    for eid in others:
        if eid != bad:
            assert report.episodes[eid].ok, report.episodes[eid].failed_checks()


FLOAT_PATHS = sorted(p for p, a in make_episode("gelsight_mini", N_FRAMES, "ep1").arrays.items()
                     if np.issubdtype(a.dtype, np.floating))
ALL_PATHS = sorted(make_episode("gelsight_mini", N_FRAMES, "ep1").arrays)
OTHER_DTYPES = ("float64", "float32", "int32", "uint8", "int16")


@SETTINGS
@given(storage=st.sampled_from(STORAGES), target=st.sampled_from(["ep0", "ep1"]), pick=st.integers(0, 10_000),
       offset=st.integers(0, 2 ** 24), xor=st.integers(1, 255))
def test_byte_flips_are_reported(storage, target, pick, offset, xor):
    with tempfile.TemporaryDirectory() as tmp:
        root = fresh_copy(storage, 2, tmp)
        files = episode_files(root, storage, target)
        path = files[pick % len(files)]
        data = bytearray(path.read_bytes())
        data[offset % len(data)] ^= xor
        path.write_bytes(bytes(data))
        report = validate(root)
        assert_only(report, target)
        assert "schema.checksums" in failing(report, target)


@SETTINGS
@given(storage=st.sampled_from(STORAGES), target=st.sampled_from(["ep0", "ep1"]), pick=st.integers(0, 10_000),
       fraction=st.floats(0.0, 0.999))
def test_truncations_are_reported(storage, target, pick, fraction):
    with tempfile.TemporaryDirectory() as tmp:
        root = fresh_copy(storage, 2, tmp)
        files = episode_files(root, storage, target)
        path = files[pick % len(files)]
        data = path.read_bytes()
        path.write_bytes(data[: int(len(data) * fraction)])
        report = validate(root)
        assert_only(report, target)
        assert "schema.checksums" in failing(report, target)


@SETTINGS
@given(storage=st.sampled_from(STORAGES), field=st.sampled_from(FLOAT_PATHS), where=st.integers(0, 10 ** 6),
       value=st.sampled_from([np.nan, np.inf, -np.inf]))
def test_injected_non_finite_values_are_reported(storage, field, where, value):
    episode = make_episode("gelsight_mini", N_FRAMES, "ep1", seed=1)
    array = episode.arrays[field]
    array.reshape(-1)[where % array.size] = value
    refresh_safety(episode)
    with tempfile.TemporaryDirectory() as tmp:
        root = fresh_copy(storage, 1, tmp)
        DatasetWriter.open(root, storage=storage).add(episode)
        report = validate(root)
        assert_only(report, "ep1")
        check = report.episodes["ep1"].check("physics.finite")
        assert check.status == "fail" and any(f.field == field for f in check.findings)


@SETTINGS
@given(storage=st.sampled_from(STORAGES), target=st.sampled_from(["ep0", "ep1"]), field=st.sampled_from(ALL_PATHS),
       dtype=st.sampled_from(OTHER_DTYPES))
def test_dtype_changes_are_reported(storage, target, field, dtype):
    spec = field_for_path(field)
    assert spec is not None
    stored = "uint8" if spec.dtype == "bool" else spec.dtype
    new_dtype = dtype if dtype != stored else "float64" if stored != "float64" else "int16"
    episode = make_episode("gelsight_mini", N_FRAMES, target, seed=int(target[-1]))
    with tempfile.TemporaryDirectory() as tmp:
        root = fresh_copy(storage, 2, tmp)
        replace_array(root, storage, target, field, episode.arrays[field].astype(new_dtype))
        report = validate(root)
        assert_only(report, target)
        dtype_check = report.episodes[target].check("schema.dtype")
        assert dtype_check.status == "fail" and dtype_check.findings[0].field == field
