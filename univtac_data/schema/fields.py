"""The field table: every array an episode holds, with dtype, shape, unit, frame and encoding.

This table is the single source of truth for the spec's field list (``spec/fields.md`` is generated
from it), for the writer's and reader's checks, and for ``info.json``'s ``fields``. Paths are relative
to the episode root; ``{pad}``, ``{camera}`` and ``{object}`` are placeholders filled from the episode's
metadata. Shape symbols: ``T`` frames, ``H``/``W`` the sensor image, ``N`` markers, ``h``/``w`` a camera.
"""

from __future__ import annotations

import re
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

Sampling = Literal["per_frame", "per_episode"]
Codec = Literal["image", "depth", "dense", "small"]


class FieldSpec(BaseModel):
    """One array of an episode."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    path: str = Field(description="path inside the episode; {pad}/{camera}/{object} are placeholders")
    symbol: str = Field(description="the paper's symbol, if any")
    dtype: Literal["uint8", "uint16", "int16", "int64", "float32", "float64", "bool"]
    shape: tuple[str | int, ...] = Field(description="symbolic shape; T frames, H/W image, N markers, h/w camera")
    unit: str
    frame: str = Field(description="coordinate frame the values are expressed in, or 'image' / '-'")
    sampling: Sampling
    required: bool
    codec: Codec = Field(description="storage class; see the spec's 'Encoding' section")
    since: str = Field(default="1.0", description="format version that added the field")
    residual_of: str | None = Field(
        default=None, description="field whose values the 2.0 writer subtracts (modulo 256) before compressing, "
                                  "when the episode holds it; same placeholders as path")
    description: str


def _f(path: str, dtype: str, shape: tuple[str | int, ...], unit: str, frame: str, description: str, *,
       symbol: str = "", sampling: Sampling = "per_frame", required: bool = True, codec: Codec = "small",
       residual_of: str | None = None, since: str = "1.0") -> FieldSpec:
    return FieldSpec(path=path, symbol=symbol, dtype=dtype, shape=shape, unit=unit, frame=frame,  # type: ignore[arg-type]
                     sampling=sampling, required=required, codec=codec, residual_of=residual_of, since=since,
                     description=description)


FIELDS: tuple[FieldSpec, ...] = (
    _f("timestamps_ns", "int64", ("T",), "ns", "-",
       "time of each recorded frame since the episode's start; strictly increasing, nominally k * 1e9 / rate"),
    # --- tactile, per pad -------------------------------------------------------------------------
    _f("tactile/{pad}/marked_rgb", "uint8", ("T", "H", "W", 3), "-", "image", "tactile image with markers, RGB",
       symbol="I_marked", codec="image", residual_of="tactile/{pad}/pure_rgb"),
    _f("tactile/{pad}/pure_rgb", "uint8", ("T", "H", "W", 3), "-", "image", "marker-free tactile image, RGB",
       symbol="I_pure", codec="image", residual_of="tactile/{pad}/pure_ref_rgb"),
    _f("tactile/{pad}/pure_ref_rgb", "uint8", ("H", "W", 3), "-", "image",
       "marker-free image of the undeformed gel (no contact): the sensor's background frame, RGB; "
       "I_pure - pure_ref_rgb is the usual difference image", sampling="per_episode", required=False,
       codec="image", since="2.0"),
    _f("tactile/{pad}/depth_um", "uint16", ("T", "H", "W"), "um", "gel pad centre (-z)",
       "indentation depth of the gel surface at each pixel, >= 0, integer micrometres (mm = value / 1000)",
       symbol="D", codec="depth"),
    _f("tactile/{pad}/contact_mask", "bool", ("T", "H", "W"), "-", "image",
       "pixels where the gel touches the object (pressure > 0)", codec="depth"),
    _f("tactile/{pad}/markers_ref_px", "float32", ("N", 2), "px", "image",
       "marker centres (u, v) on the undeformed gel, column then row, pixel centres at integers",
       symbol="M_ref", sampling="per_episode"),
    _f("tactile/{pad}/markers_px", "float32", ("T", "N", 2), "px", "image",
       "current marker centres (u, v), same order as markers_ref_px", symbol="M", codec="dense"),
    _f("tactile/{pad}/object_pose", "float64", ("T", 7), "m, -", "gel pad centre",
       "pose of the tactile object (meta.tactile_object) in the pad frame: x, y, z (m), quaternion w, x, y, z",
       symbol="p"),
    _f("tactile/{pad}/normal_force_n", "float32", ("T",), "N", "gel pad centre (-z)",
       "total normal force the object presses into the gel, >= 0"),
    _f("tactile/{pad}/shear_force_n", "float32", ("T", 2), "N", "gel pad centre",
       "total tangential force on the gel surface along x, y"),
    _f("tactile/{pad}/slip_mm", "float32", ("T",), "mm", "gel pad centre",
       "tangential sliding of the object over the gel accumulated since contact onset; 0 while stuck"),
    _f("tactile/{pad}/pad_pose", "float64", ("T", 7), "m, -", "world",
       "pose of the gel-pad-centre frame in the world: x, y, z (m), quaternion w, x, y, z", required=False),
    # --- robot ------------------------------------------------------------------------------------
    _f("robot/ee_pose", "float64", ("T", 7), "m, -", "world",
       "end-effector (gripper base) pose: x, y, z (m), quaternion w, x, y, z"),
    _f("robot/gripper_width_m", "float32", ("T",), "m", "gripper", "distance between the two gel surfaces"),
    _f("robot/finger_pos_m", "float32", ("T", 2), "m", "gripper",
       "left and right finger slide-joint positions, 0 = fully open, positive closing"),
    _f("robot/action", "float32", ("T", 8), "m, -, m", "world",
       "commanded target sent at frame t and held until frame t+1 (not the next state): "
       "ee x, y, z (m), ee quaternion w, x, y, z, gripper width (m); names in meta.action_names"),
    # --- scene ------------------------------------------------------------------------------------
    _f("scene/cameras/{camera}/rgb", "uint8", ("T", "h", "w", 3), "-", "image", "camera image, RGB",
       required=False, codec="image"),
    _f("scene/cameras/{camera}/depth_m", "float32", ("T", "h", "w"), "m", "camera (+z forward)",
       "camera depth along the optical axis; present when meta.cameras[*].depth is true",
       required=False, codec="image"),
    _f("scene/objects/{object}/pose", "float64", ("T", 7), "m, -", "world",
       "object pose: x, y, z (m), quaternion w, x, y, z; one per name in meta.objects", required=False),
    _f("scene/primitive", "int16", ("T",), "-", "-",
       "index into meta.primitive_names of the primitive running at each frame; -1 for none"),
)

FIELDS_BY_PATH: dict[str, FieldSpec] = {f.path: f for f in FIELDS}

NAME_PATTERN = r"^[A-Za-z0-9_.\-]{1,128}$"
_NAME = re.compile(NAME_PATTERN)


def _path_regex(path: str) -> re.Pattern[str]:
    escaped = re.escape(path)
    for name in ("pad", "camera", "object"):
        escaped = escaped.replace(re.escape("{" + name + "}"), "[^/]+")
    return re.compile("^" + escaped + "$")


_PATH_REGEXES = tuple((_path_regex(f.path), f) for f in FIELDS)


def field_for_path(path: str) -> FieldSpec | None:
    """The spec of a concrete path such as ``tactile/left/depth_um``; None when no field matches."""
    for regex, spec in _PATH_REGEXES:
        if regex.match(path):
            return spec
    return None


def expand_paths(spec: FieldSpec, pads: list[str], cameras: list[str], objects: list[str]) -> list[str]:
    """Concrete paths of a field for an episode's pads, cameras and objects."""
    if "{pad}" in spec.path:
        return [spec.path.replace("{pad}", p) for p in pads]
    if "{camera}" in spec.path:
        return [spec.path.replace("{camera}", c) for c in cameras]
    if "{object}" in spec.path:
        return [spec.path.replace("{object}", o) for o in objects]
    return [spec.path]


def is_valid_name(name: str) -> bool:
    """Pads, cameras, objects and episode ids are path components: letters, digits, ``_ . -``."""
    return bool(_NAME.match(name))
