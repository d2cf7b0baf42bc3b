"""Gap field from a MuJoCo scene: the signed distance along the pad normal from the undeformed gel surface
to the objects, on a sensor grid, mm (negative = overlap). Called every frame; separate from the contact solve.

The pad frame comes from a site (or geom) placed at the gel-pad-centre frame of
``univtac_data.schema.sensors`` (+z out of the gel toward the object). For every grid cell the vertical line
(x, y, t) in that frame is intersected with each listed geom; the gap is the lowest entry height over the geoms.

Why analytic + rasterised (measured by ``benchmarks/tactile_speed_vs_accuracy.py``, numbers in
docs/tactile.md): closed-form entries for primitives and scan-converting mesh triangles are exact at every
pixel, include the positive gap near contact and the overlap of deep presses, handle non-convex meshes, and
cost well under a millisecond to a few ms at 320 x 240. ``mujoco.mj_multiRay`` casts one fan of rays from a
single point (so the rays are not parallel to the pad normal unless cast from far away), needs one ray per
pixel through MuJoCo's generic ray code, and returns nothing for rays that start inside an overlapping object.
MuJoCo's ``tactile`` sensor reports only the penetration depth (no positive gap), at the vertices of a plate
mesh that must be added to the model, requires SDF octrees for every mesh that may touch it, and only updates
when MuJoCo itself registers a contact.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numba
import numpy as np

from .contact import GAP_FAR_MM
from .gap_primitives import (
    BOX,
    CYLINDER,
    ELLIPSOID,
    SLACK_MM,
    Extent,
    box_extent,
    cylinder_extent,
    ellipsoid_extent,
    lower_to_entry,
    mesh_triangles,
    rasterise_lowest,
)
from .sensor_model import SensorGrid

__all__ = ["GapFieldBuffer", "PadPose", "gap_field", "pad_pose"]

M_TO_MM = 1000.0
BEHIND_GEL_MM = 10.0  # geoms wholly this far behind the undeformed gel surface are not seen by the pad, mm


@dataclass(frozen=True)
class PadPose:
    """World pose of the gel-pad-centre frame: ``rotation`` (3, 3) pad-to-world, ``origin_mm`` (3,) mm."""

    rotation: np.ndarray
    origin_mm: np.ndarray


class GapFieldBuffer:
    """One pad's gap field (ny, nx) mm, kept from frame to frame: ``gap_field(..., out=buffer)`` resets to
    ``GAP_FAR_MM`` only the cells the previous call wrote, not the whole grid, and records in ``box`` the
    (rows, cols) outside which the new field reads ``GAP_FAR_MM`` (an empty box: no object below the cutoff),
    so that its readers need not scan the rest. Each call overwrites the field: use it before the next."""

    def __init__(self, shape: tuple[int, int]) -> None:
        self.gap_mm = np.full(shape, GAP_FAR_MM)
        self.box: tuple[slice, slice] = (slice(0, 0), slice(0, 0))


def pad_pose(model: mujoco.MjModel, data: mujoco.MjData, name: str, kind: str = "site") -> PadPose:
    """Pad frame from the current pose of a ``site`` (default) or ``geom`` named ``name`` (after mj_forward)."""
    if kind == "site":
        sid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, name)
        if sid < 0:
            raise KeyError(f"no site named {name!r} in the model")
        return PadPose(data.site_xmat[sid].reshape(3, 3).copy(), data.site_xpos[sid] * M_TO_MM)
    if kind == "geom":
        gid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, name)
        if gid < 0:
            raise KeyError(f"no geom named {name!r} in the model")
        return PadPose(data.geom_xmat[gid].reshape(3, 3).copy(), data.geom_xpos[gid] * M_TO_MM)
    raise ValueError(f"kind must be 'site' or 'geom' (got {kind!r})")


def _geom_id(model: mujoco.MjModel, geom: int | str) -> int:
    if isinstance(geom, str):
        gid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, geom)
        if gid < 0:
            raise KeyError(f"no geom named {geom!r} in the model")
        return int(gid)
    return int(geom)


def gap_field(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    pad: PadPose,
    geoms: Sequence[int | str],
    grid: SensorGrid,
    cutoff_mm: float = 10.0,
    out: GapFieldBuffer | None = None,
) -> np.ndarray:
    """Gap (ny, nx) mm on ``grid`` from the pad to the listed geoms at the current ``data`` pose.

    Supported geom types: sphere, capsule, cylinder, box, ellipsoid, mesh (convex or not). Gaps above
    ``cutoff_mm`` (and cells with no object) read ``GAP_FAR_MM``. ``out``: the buffer to write the field into
    (and its ``box``); default: a new array.
    """
    if out is None:
        gap = np.full(grid.shape, GAP_FAR_MM)
    else:
        if out.gap_mm.shape != grid.shape:
            raise ValueError(f"GapFieldBuffer of shape {out.gap_mm.shape} for a grid of {grid.shape}")
        gap = out.gap_mm
        gap[out.box] = GAP_FAR_MM
    # the object's part above the cutoff reads GAP_FAR_MM whatever its height, so each geom is cut there
    # (with rounding slack) and evaluated only on the cells under what is left
    z_max = cutoff_mm + SLACK_MM
    triangles = []
    written: list[tuple[slice, slice]] = []  # the boxes of cells that may hold a gap below GAP_FAR_MM
    for geom in geoms:
        gid = _geom_id(model, geom)
        gtype = int(model.geom_type[gid])
        pos = pad.rotation.T @ (data.geom_xpos[gid] * M_TO_MM - pad.origin_mm)
        rbound = float(model.geom_rbound[gid]) * M_TO_MM
        if rbound > 0.0 and pos[2] - rbound > cutoff_mm:  # the bounding sphere is wholly above: skip early
            continue
        if rbound > 0.0 and pos[2] + rbound < -BEHIND_GEL_MM:
            # wholly behind the gel surface, farther than any press: behind the finger, not in the gel (an
            # object there would otherwise read as pressed through the pad by its whole distance)
            continue
        rot = pad.rotation.T @ data.geom_xmat[gid].reshape(3, 3)
        if gtype == mujoco.mjtGeom.mjGEOM_MESH:
            triangles.append(mesh_triangles(rot, pos, *_mesh_mm(model, gid)))
            continue
        for extent, kind, part_pos, part_size in _convex_parts(gid, gtype, rot, pos, model.geom_size[gid] * M_TO_MM,
                                                               z_max):
            win = _window(grid, extent)
            if win is not None:
                lower_to_entry(gap, grid.x_mm, grid.y_mm, kind, rot, part_pos, part_size, window=win)
                written.append(win)
    if triangles:  # all mesh geoms in one scan: the per-call set-up costs more than a small mesh's cells
        box = rasterise_lowest(gap, grid.x_mm, grid.y_mm, np.concatenate(triangles), cutoff=cutoff_mm)
        if box is not None:
            written.append(box)
    box = _union(written) if written else (slice(0, 0), slice(0, 0))
    _cut_off(gap, box[0].start, box[0].stop, box[1].start, box[1].stop, cutoff_mm, GAP_FAR_MM)
    if out is not None:
        out.box = box
    return gap


@numba.njit(cache=True, nogil=True)
def _cut_off(gap: np.ndarray, r0: int, r1: int, c0: int, c1: int, cutoff: float,
             far: float) -> None:  # pragma: no cover (compiled)
    # gaps above ``cutoff`` in rows r0:r1, cols c0:c1 read ``far``: one pass, where array code made a boolean
    # window and a masked write
    for i in range(r0, r1):
        row = gap[i]
        for j in range(c0, c1):
            row[j] = far if row[j] > cutoff else row[j]


def _union(boxes: list[tuple[slice, slice]]) -> tuple[slice, slice]:
    """The smallest (rows, cols) box holding every one of ``boxes`` (non-empty, slices with start and stop)."""
    return (slice(min(b[0].start for b in boxes), max(b[0].stop for b in boxes)),
            slice(min(b[1].start for b in boxes), max(b[1].stop for b in boxes)))


ConvexPart = tuple[Extent, int, np.ndarray, np.ndarray]  # xy box, kind, centre (3,) mm, size (3,) mm


def _mesh_mm(model: mujoco.MjModel, gid: int) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) mm in the geom frame and faces (F, 3) of mesh geom ``gid``."""
    mid = int(model.geom_dataid[gid])
    va, vn = model.mesh_vertadr[mid], model.mesh_vertnum[mid]
    fa, fn = model.mesh_faceadr[mid], model.mesh_facenum[mid]
    return model.mesh_vert[va : va + vn].astype(np.float64) * M_TO_MM, model.mesh_face[fa : fa + fn]


def _convex_parts(
    gid: int, gtype: int, rot: np.ndarray, pos: np.ndarray, size: np.ndarray, z_max: float,
) -> list[ConvexPart]:
    """Convex pieces of primitive geom ``gid`` (pose ``rot``, ``pos`` and MJCF ``size`` in mm, pad frame) that
    reach below ``z_max`` mm: each piece's xy box there, its kind for ``lower_to_entry`` (same ``rot``), centre
    and size. A capsule is its cylinder and two caps, so each is evaluated under its own box only."""
    if gtype == mujoco.mjtGeom.mjGEOM_SPHERE or gtype == mujoco.mjtGeom.mjGEOM_ELLIPSOID:
        radii = np.full(3, size[0]) if gtype == mujoco.mjtGeom.mjGEOM_SPHERE else np.asarray(size, dtype=np.float64)
        pieces = [_ellipsoid_piece(rot, pos, radii, z_max)]
    elif gtype == mujoco.mjtGeom.mjGEOM_BOX:
        extent = box_extent(rot, pos, size, z_max)
        pieces = [None if extent is None else (extent, BOX, pos, np.asarray(size, dtype=np.float64))]
    elif gtype == mujoco.mjtGeom.mjGEOM_CYLINDER or gtype == mujoco.mjtGeom.mjGEOM_CAPSULE:
        radius, half = float(size[0]), float(size[1])
        extent = cylinder_extent(rot, pos, radius, half, z_max)
        pieces = [None if extent is None else (extent, CYLINDER, pos, np.array([radius, half, 0.0]))]
        if gtype == mujoco.mjtGeom.mjGEOM_CAPSULE:
            pieces += [_ellipsoid_piece(rot, pos + rot[:, 2] * s * half, np.full(3, radius), z_max) for s in (-1.0, 1.0)]
    else:
        raise ValueError(f"geom {gid} has type {mujoco.mjtGeom(gtype).name}, not supported by the gap field")
    return [p for p in pieces if p is not None]


def _ellipsoid_piece(rot: np.ndarray, pos: np.ndarray, radii: np.ndarray, z_max: float) -> ConvexPart | None:
    extent = ellipsoid_extent(rot, pos, radii, z_max)
    return None if extent is None else (extent, ELLIPSOID, pos, radii)


def _window(grid: SensorGrid, extent: Extent) -> tuple[slice, slice] | None:
    """(rows, cols) slices of the cells whose centres lie in the xy box ``extent`` mm; None when there are none."""
    x_lo, x_hi, y_lo, y_hi = extent
    cols = np.flatnonzero((grid.x_mm >= x_lo) & (grid.x_mm <= x_hi))
    rows = np.flatnonzero((grid.y_mm >= y_lo) & (grid.y_mm <= y_hi))
    if cols.size == 0 or rows.size == 0:
        return None
    return (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
