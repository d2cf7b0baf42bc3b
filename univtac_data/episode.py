"""An episode in memory: its metadata and its arrays by path, checked against the field table."""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field

import numpy as np

from univtac_data.schema.fields import FIELDS, FieldSpec, expand_paths, field_for_path
from univtac_data.schema.models import EpisodeMeta
from univtac_data.schema.sensors import SensorProfile
from univtac_data.version import FORMAT_VERSION


class EpisodeError(ValueError):
    """An episode whose arrays do not match the spec (a programming or data error, not I/O)."""


@dataclass
class Episode:
    """One episode: ``meta`` plus ``arrays`` keyed by concrete path (``tactile/left/depth_um``, ...).

    Arrays carry their logical dtype (``bool`` for masks); storage encodings are the backends' business.
    """

    meta: EpisodeMeta
    arrays: dict[str, np.ndarray] = field(default_factory=dict)

    def __getitem__(self, path: str) -> np.ndarray:
        return self.arrays[path]

    def in_current_format(self) -> Episode:
        """This episode as this package writes it: metadata stamped with ``FORMAT_VERSION`` (an episode read
        from an older format keeps its arrays; the writer chooses the encoding)."""
        if self.meta.format_version == FORMAT_VERSION:
            return self
        return Episode(meta=self.meta.model_copy(update={"format_version": FORMAT_VERSION}), arrays=self.arrays)

    def expected_paths(self) -> dict[str, FieldSpec]:
        """Concrete path -> spec for every field this episode may hold (required and optional)."""
        cameras = [c.name for c in self.meta.cameras]
        out: dict[str, FieldSpec] = {}
        for spec in FIELDS:
            for path in expand_paths(spec, self.meta.pads, cameras, self.meta.objects):
                if spec.path == "scene/cameras/{camera}/depth_m":
                    camera = path.split("/")[2]
                    if not next(c for c in self.meta.cameras if c.name == camera).depth:
                        continue
                out[path] = spec
        return out

    def required_paths(self) -> list[str]:
        """Paths that must be present: required fields, every camera's rgb (and depth when declared),
        every object's pose."""
        declared = ("{camera}", "{object}")
        return [p for p, s in self.expected_paths().items() if s.required or any(d in s.path for d in declared)]


def resolve_shape(spec: FieldSpec, path: str, meta: EpisodeMeta, profile: SensorProfile) -> tuple[int, ...]:
    """Concrete shape of ``path`` for this episode and sensor."""
    dims: dict[str, int] = {
        "T": meta.n_frames, "H": profile.image_height_px, "W": profile.image_width_px, "N": profile.n_markers,
    }
    if "{camera}" in spec.path:
        camera = next(c for c in meta.cameras if c.name == path.split("/")[2])
        dims.update(h=camera.height_px, w=camera.width_px)
    return tuple(d if isinstance(d, int) else dims[d] for d in spec.shape)


def check_episode(episode: Episode, profile: SensorProfile) -> None:
    """Raise ``EpisodeError`` naming the first field that is missing, unknown, or of the wrong dtype/shape."""
    meta = episode.meta
    if meta.sensor != profile.name:
        raise EpisodeError(f"episode {meta.episode_id}: sensor {meta.sensor!r} but profile {profile.name!r} given")
    expected = episode.expected_paths()
    for path in episode.required_paths():
        if path not in episode.arrays:
            raise EpisodeError(f"episode {meta.episode_id}: required field {path} is missing")
    for path, array in episode.arrays.items():
        spec = expected.get(path)
        if spec is None:
            known = field_for_path(path)
            why = "not declared in the episode's metadata" if known else "not a field of the format"
            raise EpisodeError(f"episode {meta.episode_id}: field {path} is {why}")
        if array.dtype != np.dtype(spec.dtype):
            raise EpisodeError(f"episode {meta.episode_id}: field {path} must be {spec.dtype} (got {array.dtype})")
        shape = resolve_shape(spec, path, meta, profile)
        if array.shape != shape:
            raise EpisodeError(f"episode {meta.episode_id}: field {path} must have shape {shape} (got {array.shape})")


def meta_json(meta: EpisodeMeta) -> str:
    """Canonical JSON of the metadata (sorted keys): what is stored and what is hashed."""
    return json.dumps(meta.model_dump(mode="json"), sort_keys=True, separators=(",", ":"))


def content_hash(episode: Episode) -> str:
    """SHA-256 of the episode's logical content (metadata and every array's path, dtype, shape and bytes),
    independent of the backend that stored it."""
    digest = hashlib.sha256(meta_json(episode.meta).encode())
    for path in sorted(episode.arrays):
        array = np.ascontiguousarray(episode.arrays[path])
        digest.update(f"\n{path} {array.dtype.str} {array.shape}\n".encode())
        digest.update(array.tobytes())
    return digest.hexdigest()
