"""Schema rules: the episode is readable, in a supported version, complete, typed and shaped as the field
table says, checksummed as the manifest says, and indexed as its metadata says."""

from __future__ import annotations

import numpy as np

from univtac_data.schema.fields import FIELDS
from univtac_data.storage.dataset import episode_digest
from univtac_data.validators.context import DatasetView, EpisodeContext, EpisodeSource
from univtac_data.validators.registry import Skip, collect, frame_finding, rule
from univtac_data.validators.report import Finding
from univtac_data.version import FORMAT_VERSION, READABLE_MAJORS, parse_format_version


@rule("schema.readable", "schema")
def readable(ctx: EpisodeContext) -> list[Finding]:
    """The episode opens and every array decodes (chunk checksums hold); damaged chunks are listed by frame."""
    out = list(ctx.read_problems)
    if ctx.structure_problem:
        out.insert(0, Finding(message=ctx.structure_problem, field=ctx.where))
    return out


@rule("schema.format_version", "schema")
def format_version(ctx: EpisodeContext) -> list[Finding]:
    """The episode's format version has this reader's major version (a newer minor is read, extras ignored),
    and the file's own format_version attribute is present and says the same as its metadata."""
    # Opening an episode of another major version fails before a context exists, and the runner reports
    # that under this rule; this covers a context built some other way.
    major = parse_format_version(ctx.meta.format_version)[0]
    if major not in READABLE_MAJORS:
        readable = " and ".join(f"{m}.x" for m in sorted(READABLE_MAJORS))
        return [Finding(message=f"{ctx.where}: written in format {ctx.meta.format_version}; this reader reads "
                                f"format {readable} only", field="format_version")]
    if ctx.version_attr is None:
        return [Finding(message=f"{ctx.where}: the file has no format_version attribute (its metadata says "
                                f"{ctx.meta.format_version})", field="format_version")]
    if str(ctx.version_attr) != ctx.meta.format_version:
        return [Finding(message=f"{ctx.where}: the file's format_version attribute is {ctx.version_attr!r}, its "
                                f"metadata says {ctx.meta.format_version!r}", field="format_version")]
    return []


@rule("schema.episode_meta", "schema")
def episode_meta(ctx: EpisodeContext) -> list[Finding]:
    """The metadata's episode id matches its index entry and info.json has a profile for its sensor."""
    out = []
    if ctx.meta.episode_id != ctx.episode_id:
        out.append(Finding(message=f"{ctx.where}: metadata says episode {ctx.meta.episode_id!r}, the index and "
                                   f"file name say {ctx.episode_id!r}", field="episode_id"))
    if ctx.meta.sensor not in ctx.info.sensors:
        out.append(Finding(message=f"{ctx.where}: sensor {ctx.meta.sensor!r} has no profile in info.json "
                                   f"(profiles: {', '.join(sorted(ctx.info.sensors)) or 'none'})", field="sensor"))
    return out


def checksum_findings(source: EpisodeSource) -> list[Finding]:
    """Files of the episode whose SHA-256 or size differs from the manifest, missing, or not listed."""
    if source.manifest is None:
        return [Finding(message=f"manifest unreadable: {source.manifest_error}", field="meta/manifest.json")]
    loc = source.loc
    listed = {rel: e for rel, e in source.manifest.files.items() if e.episode_id == source.episode_id}
    out = []
    if not listed:
        out.append(Finding(message=f"{loc.url_of(source.relpath)}: episode has no entry in meta/manifest.json",
                           field=source.relpath))
    for rel, entry in sorted(listed.items()):
        if not loc.exists(rel):
            out.append(Finding(message=f"{loc.url_of(rel)}: file is missing (listed in the manifest)", field=rel))
            continue
        size = loc.size(rel)
        if size != entry.bytes:
            out.append(Finding(message=f"{loc.url_of(rel)}: {size} bytes, the manifest says {entry.bytes} "
                                       "(truncated or rewritten)", field=rel, values=[size], limits=[entry.bytes]))
        elif loc.sha256(rel) != entry.sha256:
            out.append(Finding(message=f"{loc.url_of(rel)}: SHA-256 differs from the manifest (file changed or "
                                       "damaged)", field=rel))
    if loc.exists(source.relpath):
        for rel in loc.files_under(source.relpath):
            if rel not in listed:
                out.append(Finding(message=f"{loc.url_of(rel)}: file is not in the manifest", field=rel))
    return out


@rule("schema.checksums", "schema")
def checksums(ctx: EpisodeContext) -> list[Finding]:
    """Every file of the episode exists with the size and SHA-256 that meta/manifest.json records, and no
    file is unlisted."""
    if ctx.source is None:
        raise Skip("no dataset context")
    return checksum_findings(ctx.source)


def index_row_findings(source: EpisodeSource, ctx: EpisodeContext | None) -> list[Finding]:
    """The index row against the disk, and (when the episode opened) against its metadata and manifest."""
    loc, row = source.loc, source.row
    if row is None:
        return [Finding(message=f"{loc.url}: episode {source.episode_id!r} is not in the index", field="index")]
    if not loc.exists(row.path):
        return [Finding(message=f"{loc.url_of(row.path)}: episode {row.episode_id} is in the index but missing "
                                "on disk", field=row.path)]
    if ctx is None:
        return []
    meta = ctx.meta
    expected: dict[str, object] = {
        "format_version": meta.format_version, "kind": meta.kind, "name": meta.name, "sensor": meta.sensor,
        "seed": meta.seed, "n_frames": meta.n_frames, "nominal_rate_hz": meta.nominal_rate_hz,
        "success": meta.success, "max_indentation_mm": meta.safety.max_indentation_mm,
        "max_slip_mm": meta.safety.max_slip_mm,
    }
    stamps = ctx.arrays.get("timestamps_ns")
    if stamps is not None and len(stamps):
        expected["duration_ns"] = int(stamps[-1]) - int(stamps[0])
    if source.manifest is not None:
        entries = {r: e for r, e in source.manifest.files.items() if e.episode_id == row.episode_id}
        if entries:
            expected["bytes"] = sum(e.bytes for e in entries.values())
            expected["sha256"] = episode_digest(entries)
    return [Finding(message=f"index row of {row.episode_id}: {key} is {getattr(row, key)!r}, the episode says "
                            f"{value!r}", field=f"index.{key}")
            for key, value in expected.items() if not _same(getattr(row, key), value)]


def _same(a: object, b: object) -> bool:
    if isinstance(a, float) or isinstance(b, float):
        return isinstance(a, (int, float)) and isinstance(b, (int, float)) and \
            abs(float(a) - float(b)) <= 1e-9 * max(1.0, abs(float(b)))
    return a == b


@rule("schema.index_row", "schema")
def index_row(ctx: EpisodeContext) -> list[Finding]:
    """The episode's index row names a file that exists and agrees with its metadata, timestamps and manifest."""
    if ctx.source is None:
        raise Skip("no dataset context")
    return index_row_findings(ctx.source, ctx)


@rule("schema.fields_present", "schema")
def fields_present(ctx: EpisodeContext) -> list[Finding]:
    """Every required field is stored, and every stored array is a field the metadata declares."""
    out = []
    for path, state in ctx.fields.items():
        if state.problem == "missing":
            out.append(Finding(message=f"{ctx.where}: required field {path} is missing", field=path))
        elif state.problem == "unknown" and not ctx.newer_minor:
            why = "not declared in the episode's metadata" if state.spec else "not a field of the format"
            out.append(Finding(message=f"{ctx.where}: array {path} is {why}", field=path))
    return out


@rule("schema.dtype", "schema")
def dtype(ctx: EpisodeContext) -> list[Finding]:
    """Each array is stored in its field-table dtype (bool masks as uint8 0/1)."""
    return [Finding(message=f"{path} must be {s.spec.dtype if s.spec else '?'} (got {s.stored_dtype})", field=path)
            for path, s in ctx.fields.items() if s.problem == "dtype"]


@rule("schema.shape", "schema")
def shape(ctx: EpisodeContext) -> list[Finding]:
    """Each array has its field-table shape resolved for the sensor, cameras and meta.n_frames."""
    ctx.require_profile()
    return [Finding(message=f"{path} must have shape {s.expected_shape} (got {s.stored_shape})", field=path)
            for path, s in ctx.fields.items() if s.problem == "shape"]


def _position_fields(ctx: EpisodeContext) -> list[tuple[str, np.ndarray]]:
    out = []
    for pattern in ("robot/ee_pose", "scene/objects/{object}/pose", "tactile/{pad}/pad_pose",
                    "tactile/{pad}/object_pose", "robot/action"):
        for path in ctx.paths_like(pattern):
            out.append((path, ctx.arrays[path][:, :3].astype(np.float64)))
    return out


@rule("schema.units", "schema", threshold="max_position_m")
def units(ctx: EpisodeContext) -> list[Finding]:
    """Values are plausible in their table units: positions within max_position_m (m, not mm), gripper widths
    and finger positions within [-gripper_negative_tolerance_m, max_gripper_width_m]."""
    cfg, out = ctx.config, []
    for path, xyz in _position_fields(ctx):
        worst = np.abs(xyz).max(axis=1)
        out.append(frame_finding(f"{path}[:, :3]", worst > cfg.max_position_m, worst,
                                 f"have a position beyond {cfg.max_position_m} m (stored in mm?)",
                                 cfg.max_listed_frames, unit="m"))
    widths = [(p, ctx.arrays[p].reshape(ctx.n_frames, -1).astype(np.float64))
              for p in ("robot/gripper_width_m", "robot/finger_pos_m") if p in ctx.arrays]
    if "robot/action" in ctx.arrays:
        widths.append(("robot/action[:, 7]", ctx.arrays["robot/action"][:, 7:8].astype(np.float64)))
    for path, value in widths:
        high, low = value.max(axis=1), value.min(axis=1)
        bad = (high > cfg.max_gripper_width_m) | (low < -cfg.gripper_negative_tolerance_m)
        worst = np.where(high > cfg.max_gripper_width_m, high, low)
        out.append(frame_finding(path, bad, worst, f"outside [-{cfg.gripper_negative_tolerance_m}, "
                                 f"{cfg.max_gripper_width_m}] m", cfg.max_listed_frames, unit="m"))
    return collect(out)


@rule("schema.primitive_index", "schema")
def primitive_index(ctx: EpisodeContext) -> list[Finding]:
    """scene/primitive is -1 or an index into meta.primitive_names."""
    values = ctx.array("scene/primitive").astype(np.int64)
    bad = (values < -1) | (values >= len(ctx.meta.primitive_names))
    return collect([frame_finding("scene/primitive", bad, values,
                                  f"outside [-1, {len(ctx.meta.primitive_names) - 1}]", ctx.config.max_listed_frames)])


# --- dataset scope: run once by the runner on a DatasetView -------------------------------------------------


@rule("schema.field_table", "schema", scope="dataset")
def field_table(view: DatasetView) -> list[Finding]:
    """info.json's field table agrees with this reader's: dtype, shape, unit and frame of every path."""
    theirs = {f.path: f for f in view.info.fields}
    version = parse_format_version(view.info.format_version)
    out = []
    for ours in FIELDS:
        if parse_format_version(ours.since) > version:
            continue  # added after the dataset's version
        spec = theirs.get(ours.path)
        if spec is None:
            out.append(Finding(message=f"info.json: field {ours.path} is missing from the field table",
                               field=ours.path))
            continue
        for key in ("dtype", "shape", "unit", "frame", "sampling"):
            if getattr(spec, key) != getattr(ours, key):
                out.append(Finding(message=f"info.json: field {ours.path} has {key} {getattr(spec, key)!r}, "
                                           f"format {FORMAT_VERSION} says {getattr(ours, key)!r}", field=ours.path))
    return out


@rule("schema.manifest", "schema", scope="dataset")
def manifest(view: DatasetView) -> list[Finding]:
    """meta/manifest.json parses, and every entry belongs to an indexed episode."""
    if view.manifest is None:
        return [Finding(message=str(view.manifest_error), field="meta/manifest.json")]
    stray = sorted({e.episode_id for e in view.manifest.files.values()} - set(view.index))
    return [Finding(message=f"meta/manifest.json lists files of episode {eid!r}, which is not in the index",
                    field="meta/manifest.json") for eid in stray]


@rule("schema.orphan_files", "schema", scope="dataset")
def orphan_files(view: DatasetView) -> list[Finding]:
    """Every entry of episodes/ is an indexed episode (leftover writer temporaries '.tmp-*' excepted)."""
    from univtac_data.storage.fs import TMP_PREFIX

    loc = view.loc
    indexed = {row.path for row in view.index.values()}
    out = []
    for name in loc.listdir("episodes"):
        rel = f"episodes/{name}"
        if name.startswith(TMP_PREFIX) or rel in indexed:
            continue
        out.append(Finding(message=f"{loc.url_of(rel)}: on disk but not in the index (run 'univtac-data "
                                   "reindex' to add it, or remove it)", field=rel))
    return out
