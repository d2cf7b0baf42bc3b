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
import numpy as np

from .contact import GAP_FAR_MM
from .gap_primitives import box_entry, capsule_entry, cylinder_entry, ellipsoid_entry, mesh_entry
from .sensor_model import SensorGrid

__all__ = ["PadPose", "gap_field", "pad_pose"]

M_TO_MM = 1000.0


@dataclass(frozen=True)
class PadPose:
    """World pose of the gel-pad-centre frame: ``rotation`` (3, 3) pad-to-world, ``origin_mm`` (3,) mm."""

    rotation: np.ndarray
    origin_mm: np.ndarray


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
) -> np.ndarray:
    """Gap (ny, nx) mm on ``grid`` from the pad to the listed geoms at the current ``data`` pose.

    Supported geom types: sphere, capsule, cylinder, box, ellipsoid, mesh (convex or not). Gaps above
    ``cutoff_mm`` (and cells with no object) read ``GAP_FAR_MM``.
    """
    gap = np.full(grid.shape, np.inf)
    for geom in geoms:
        gid = _geom_id(model, geom)
        rot = pad.rotation.T @ data.geom_xmat[gid].reshape(3, 3)
        pos = pad.rotation.T @ (data.geom_xpos[gid] * M_TO_MM - pad.origin_mm)
        size = model.geom_size[gid] * M_TO_MM
        gtype = int(model.geom_type[gid])
        # only the cells under the geom's bounding sphere can see it
        rbound = float(model.geom_rbound[gid]) * M_TO_MM
        if rbound > 0.0:
            if pos[2] - rbound > cutoff_mm:
                continue
            cols = np.flatnonzero(np.abs(grid.x_mm - pos[0]) <= rbound)
            rows = np.flatnonzero(np.abs(grid.y_mm - pos[1]) <= rbound)
            if cols.size == 0 or rows.size == 0:
                continue
            win = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
        else:
            win = (slice(None), slice(None))
        x, y = grid.x_mm[win[1]], grid.y_mm[win[0]]
        if gtype == mujoco.mjtGeom.mjGEOM_SPHERE:
            entry = ellipsoid_entry(x, y, rot, pos, np.full(3, size[0]))
        elif gtype == mujoco.mjtGeom.mjGEOM_ELLIPSOID:
            entry = ellipsoid_entry(x, y, rot, pos, size)
        elif gtype == mujoco.mjtGeom.mjGEOM_BOX:
            entry = box_entry(x, y, rot, pos, size)
        elif gtype == mujoco.mjtGeom.mjGEOM_CYLINDER:
            entry = cylinder_entry(x, y, rot, pos, size[0], size[1])
        elif gtype == mujoco.mjtGeom.mjGEOM_CAPSULE:
            entry = capsule_entry(x, y, rot, pos, size[0], size[1])
        elif gtype == mujoco.mjtGeom.mjGEOM_MESH:
            mid = int(model.geom_dataid[gid])
            va, vn = model.mesh_vertadr[mid], model.mesh_vertnum[mid]
            fa, fn = model.mesh_faceadr[mid], model.mesh_facenum[mid]
            verts = model.mesh_vert[va : va + vn].astype(np.float64) * M_TO_MM
            entry = mesh_entry(x, y, rot, pos, verts, model.mesh_face[fa : fa + fn], cutoff=cutoff_mm)
        else:
            raise ValueError(f"geom {gid} has type {mujoco.mjtGeom(gtype).name}, not supported by the gap field")
        np.minimum(gap[win], entry, out=gap[win])
    return np.where(gap > cutoff_mm, GAP_FAR_MM, gap)
