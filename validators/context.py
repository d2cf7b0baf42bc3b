"""What the rules see of one episode: field states, small arrays read whole, per-frame summaries of the
large ones, and every read problem met on the way.

``load_context`` reads each array once. Small arrays (poses, forces, markers, timestamps) are kept whole;
image and depth arrays are streamed in blocks of ``read_block_frames`` frames and reduced to per-frame
summaries (``frames.py``), so memory stays bounded whatever the episode length.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from univtac_data.episode import Episode, resolve_shape
from univtac_data.schema.fields import FieldSpec, field_for_path
from univtac_data.schema.models import DatasetInfo, EpisodeMeta, IndexRow, Manifest
from univtac_data.schema.sensors import SensorProfile
from univtac_data.storage.backend import EpisodeHandle
from univtac_data.storage.errors import CorruptFileError, DatasetError
from univtac_data.storage.fs import Location
from univtac_data.validators.config import ValidationConfig
from univtac_data.validators.registry import Skip
from univtac_data.validators.report import Finding
from univtac_data.version import is_newer_minor

STREAMED_CODECS = ("image", "depth")


@dataclass
class FieldState:
    """One array path: what the table expects and what is stored. ``problem`` None means usable."""

    path: str
    spec: FieldSpec | None
    required: bool
    expected_shape: tuple[int, ...] | None = None
    stored_shape: tuple[int, ...] | None = None
    stored_dtype: str | None = None
    problem: str | None = None  # "missing", "unknown", "dtype", "shape", "unreadable"


@dataclass
class DatasetView:
    """What the dataset-scope rules see: the root, info.json, the index and the manifest."""

    loc: Location
    info: DatasetInfo
    index: dict[str, IndexRow]
    manifest: Manifest | None
    manifest_error: str | None = None


@dataclass
class EpisodeSource:
    """The dataset side of an episode: its location, index row and the manifest (or why it is unreadable)."""

    loc: Location
    episode_id: str
    row: IndexRow | None
    relpath: str
    manifest: Manifest | None
    manifest_error: str | None = None


@dataclass
class EpisodeContext:
    """One opened episode as the rules see it. Owns no file handle once ``load_context`` returns."""

    episode_id: str
    where: str
    meta: EpisodeMeta
    profile: SensorProfile | None
    info: DatasetInfo
    config: ValidationConfig
    fields: dict[str, FieldState] = field(default_factory=dict)
    arrays: dict[str, np.ndarray] = field(default_factory=dict)
    summaries: dict[str, np.ndarray] = field(default_factory=dict)
    read_problems: list[Finding] = field(default_factory=list)
    structure_problem: str | None = None  # the array listing itself failed
    source: EpisodeSource | None = None  # where the episode sits in the dataset (index row, manifest)
    version_attr: object = None  # the file's own format_version attribute (None: absent)

    @property
    def n_frames(self) -> int:
        return self.meta.n_frames

    @property
    def newer_minor(self) -> bool:
        """Written by a newer minor version of the format: unknown fields are allowed and ignored."""
        return is_newer_minor(self.meta.format_version)

    def require_profile(self) -> SensorProfile:
        if self.profile is None:
            raise Skip(f"sensor {self.meta.sensor!r} has no profile (see schema.episode_meta)")
        return self.profile

    def array(self, path: str) -> np.ndarray:
        """The whole array at ``path``; ``Skip`` naming the reason when it is absent or unusable."""
        if path in self.arrays:
            return self.arrays[path]
        state = self.fields.get(path)
        if state is None:
            raise Skip(f"{path} is not stored")
        raise Skip(f"{path} is unusable ({state.problem or 'streamed, not kept whole'}; see the schema rules)")

    def summary(self, key: str) -> np.ndarray:
        """Per-frame summary ``key`` (NaN at unreadable frames); ``Skip`` when its inputs were unusable."""
        if key not in self.summaries:
            raise Skip(f"summary {key} unavailable: its input arrays are absent or unusable")
        return self.summaries[key]

    def paths_like(self, pattern: str) -> list[str]:
        """Usable whole arrays whose table path is ``pattern`` (e.g. 'scene/objects/{object}/pose')."""
        return sorted(p for p, s in self.fields.items()
                      if s.spec is not None and s.spec.path == pattern and p in self.arrays)

    def intervals_s(self) -> np.ndarray:
        """Duration of each of the T-1 frame intervals, s: from the timestamps where they increase, else
        the nominal 1 / rate."""
        nominal = 1.0 / self.meta.nominal_rate_hz
        out = np.full(max(self.n_frames - 1, 0), nominal)
        stamps = self.arrays.get("timestamps_ns")
        if stamps is not None and stamps.shape == (self.n_frames,):
            diffs = np.diff(stamps.astype(np.int64)).astype(np.float64) * 1e-9
            good = diffs > 0
            out[good] = diffs[good]
        return out


def _expected(meta: EpisodeMeta) -> tuple[dict[str, FieldSpec], set[str]]:
    skeleton = Episode(meta=meta)
    return skeleton.expected_paths(), set(skeleton.required_paths())


def _storage_dtypes(spec: FieldSpec) -> tuple[str, ...]:
    return ("uint8", "bool") if spec.dtype == "bool" else (spec.dtype,)


def _inspect_fields(ctx: EpisodeContext, handle: EpisodeHandle) -> None:
    expected, required = _expected(ctx.meta)
    try:
        stored = set(handle.paths())
    except DatasetError as error:
        ctx.structure_problem = one_line(error)
        stored = set(expected)  # look each expected array up by path instead
    for path in sorted(set(expected) | stored):
        spec = expected.get(path)
        state = FieldState(path=path, spec=spec, required=path in required)
        ctx.fields[path] = state
        if path not in stored:
            state.problem = "missing" if state.required else None
            if not state.required:
                del ctx.fields[path]
            continue
        if spec is None:
            state.spec = field_for_path(path)
            state.problem = "unknown"
            continue
        try:
            shape, dtype = handle.layout(path)
        except KeyError:
            state.problem = "missing" if state.required else None
            if not state.required:
                del ctx.fields[path]
            continue
        except DatasetError as error:
            state.problem = "unreadable"
            ctx.read_problems.append(Finding(
                message=f"{path}: array metadata cannot be read ({one_line(error)})",
                field=path))
            continue
        state.stored_shape, state.stored_dtype = shape, str(dtype)
        if ctx.profile is not None:
            state.expected_shape = resolve_shape(spec, path, ctx.meta, ctx.profile)
        if state.stored_dtype not in _storage_dtypes(spec):
            state.problem = "dtype"
        elif state.expected_shape is not None and shape != state.expected_shape:
            state.problem = "shape"
        elif state.expected_shape is None and spec.sampling == "per_frame" and shape[:1] != (ctx.n_frames,):
            state.problem = "shape"


def one_line(error: BaseException) -> str:
    text = str(error).strip()
    return text.splitlines()[0] if text else type(error).__name__


def read_whole(ctx: EpisodeContext, handle: EpisodeHandle, path: str) -> None:
    """Read a small array into ``ctx.arrays``; a read failure marks the field unreadable."""
    try:
        ctx.arrays[path] = handle.read(path)
    except CorruptFileError as error:
        ctx.fields[path].problem = "unreadable"
        frames = list(range(ctx.n_frames)) if ctx.fields[path].spec and \
            ctx.fields[path].spec.sampling == "per_frame" else []  # type: ignore[union-attr]
        ctx.read_problems.append(Finding(
            message=f"{path}: cannot be read ({one_line(error)})", field=path,
            frames=frames[:ctx.config.max_listed_frames], n_frames=len(frames)))


def load_context(handle: EpisodeHandle, source: EpisodeSource, profile: SensorProfile | None, info: DatasetInfo,
                 config: ValidationConfig) -> EpisodeContext:
    """Inspect and read every array of the open episode ``handle`` once; never raises on bad data."""
    from univtac_data.validators.frames import scan_streamed

    ctx = EpisodeContext(episode_id=source.episode_id, where=handle.where, meta=handle.meta, profile=profile,
                         info=info, config=config, source=source, version_attr=handle.version_attr)
    _inspect_fields(ctx, handle)
    streamed = []
    for path, state in ctx.fields.items():
        if state.problem is not None or state.spec is None:
            continue
        if state.spec.codec in STREAMED_CODECS and state.spec.sampling == "per_frame":
            streamed.append(path)
        else:
            read_whole(ctx, handle, path)
    scan_streamed(ctx, handle, streamed)
    return ctx
