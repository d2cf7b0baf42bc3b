"""Pure geometry: where vertical lines through the gel grid first enter an object, in the pad frame (mm).

Every function takes the grid's cell centres ``x`` (nx,), ``y`` (ny,) (mm, pad frame) and the object's pose
in the pad frame (rotation ``rot`` (3, 3) object-to-pad, centre ``pos`` (3,) mm), and returns the height z
(ny, nx) mm at which the line {(x, y, t), t from -inf} enters the object (+inf where it misses). Convex
primitives are solved in closed form (quadratic or slab intersection); a triangle mesh, convex or not, is
rasterised: each triangle's projection onto the gel plane is scanned and the lowest interpolated height kept.
"""

from __future__ import annotations

import numpy as np

__all__ = ["box_entry", "capsule_entry", "cylinder_entry", "ellipsoid_entry", "mesh_entry"]


def _local_rays(x: np.ndarray, y: np.ndarray, rot: np.ndarray, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Line origins (ny, nx, 3) on the gel plane and the common direction (3,) in the object's frame."""
    # rot.T @ (x - px, y - py, -pz) for every cell, as broadcast sums of rot's rows: no (ny, nx, 3) temporaries
    # from meshgrid and stack, which cost more than the arithmetic on these small windows
    origin = ((x - pos[0])[None, :, None] * rot[0] + (y - pos[1])[:, None, None] * rot[1]) - pos[2] * rot[2]
    return origin, rot[2].copy()


def _quadratic_entry(a: float | np.ndarray, b: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Roots (t_in, t_out) of a t^2 + b t + c = 0 (a > 0), +inf/-inf where there is none."""
    disc = b * b - 4.0 * a * c
    ok = disc >= 0.0
    sq = np.sqrt(np.where(ok, disc, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        t_in = np.where(ok, (-b - sq) / (2.0 * a), np.inf)
        t_out = np.where(ok, (-b + sq) / (2.0 * a), -np.inf)
    return t_in, t_out


def ellipsoid_entry(x: np.ndarray, y: np.ndarray, rot: np.ndarray, pos: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Ellipsoid with semi-axes ``radii`` (3,) mm (a sphere when equal)."""
    o, d = _local_rays(x, y, rot, pos)
    o = o / radii
    d = d / radii
    t_in, _ = _quadratic_entry(float(d @ d), 2.0 * (o @ d), np.einsum("ijk,ijk->ij", o, o) - 1.0)
    return t_in


def _slab(o: np.ndarray, d: float, lo: float, hi: float) -> tuple[np.ndarray, np.ndarray]:
    if abs(d) < 1e-12:
        inside = (o >= lo) & (o <= hi)
        return np.where(inside, -np.inf, np.inf), np.where(inside, np.inf, -np.inf)
    t1, t2 = (lo - o) / d, (hi - o) / d
    return np.minimum(t1, t2), np.maximum(t1, t2)


def box_entry(x: np.ndarray, y: np.ndarray, rot: np.ndarray, pos: np.ndarray, half: np.ndarray) -> np.ndarray:
    """Box with half-sizes ``half`` (3,) mm."""
    o, d = _local_rays(x, y, rot, pos)
    t_in = np.full(o.shape[:2], -np.inf)
    t_out = np.full(o.shape[:2], np.inf)
    for k in range(3):
        a, b = _slab(o[..., k], float(d[k]), -half[k], half[k])
        t_in, t_out = np.maximum(t_in, a), np.minimum(t_out, b)
    return np.where(t_in <= t_out, t_in, np.inf)


def _tube(o: np.ndarray, d: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Infinite cylinder about the local z axis."""
    a = float(d[0] ** 2 + d[1] ** 2)
    c = o[..., 0] ** 2 + o[..., 1] ** 2 - radius * radius
    if a < 1e-12:
        inside = c <= 0.0
        return np.where(inside, -np.inf, np.inf), np.where(inside, np.inf, -np.inf)
    return _quadratic_entry(a, 2.0 * (o[..., 0] * d[0] + o[..., 1] * d[1]), c)


def cylinder_entry(
    x: np.ndarray, y: np.ndarray, rot: np.ndarray, pos: np.ndarray, radius: float, half_height: float
) -> np.ndarray:
    """Solid cylinder along the local z axis (MuJoCo's convention)."""
    o, d = _local_rays(x, y, rot, pos)
    a_in, a_out = _tube(o, d, radius)
    b_in, b_out = _slab(o[..., 2], float(d[2]), -half_height, half_height)
    t_in, t_out = np.maximum(a_in, b_in), np.minimum(a_out, b_out)
    return np.where(t_in <= t_out, t_in, np.inf)


def capsule_entry(
    x: np.ndarray, y: np.ndarray, rot: np.ndarray, pos: np.ndarray, radius: float, half_length: float
) -> np.ndarray:
    """Capsule: cylinder of ``half_length`` along local z capped by two spheres (entry of a union = min)."""
    body = cylinder_entry(x, y, rot, pos, radius, half_length)
    radii = np.full(3, radius)
    caps = [ellipsoid_entry(x, y, rot, pos + rot[:, 2] * s * half_length, radii) for s in (-1.0, 1.0)]
    return np.minimum(body, np.minimum(*caps))


def mesh_entry(
    x: np.ndarray, y: np.ndarray, rot: np.ndarray, pos: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
    cutoff: float = np.inf,
) -> np.ndarray:
    """Triangle mesh (``vertices`` (V, 3) mm in the object frame, ``faces`` (F, 3) int), rasterised.

    Triangles entirely above ``cutoff`` (mm) are skipped, so heights above it may read +inf.
    Requires a regular grid (uniform spacing of ``x`` and ``y``).
    """
    out = np.full((y.size, x.size), np.inf)
    v = vertices @ rot.T + pos
    tri = v[faces]  # (F, 3, 3)
    tri = tri[tri[:, :, 2].min(axis=1) <= cutoff]
    if tri.size == 0:
        return out
    dx = x[1] - x[0] if x.size > 1 else 1.0
    dy = y[1] - y[0] if y.size > 1 else 1.0
    ax, ay = tri[:, 0, 0], tri[:, 0, 1]
    e1x, e1y = tri[:, 1, 0] - ax, tri[:, 1, 1] - ay
    e2x, e2y = tri[:, 2, 0] - ax, tri[:, 2, 1] - ay
    det = e1x * e2y - e1y * e2x
    good = np.abs(det) > 1e-12  # edge-on triangles are covered by their neighbours
    j0 = np.ceil((tri[:, :, 0].min(axis=1) - x[0]) / dx - 1e-9).astype(np.intp)
    j1 = np.floor((tri[:, :, 0].max(axis=1) - x[0]) / dx + 1e-9).astype(np.intp)
    i0 = np.ceil((tri[:, :, 1].min(axis=1) - y[0]) / dy - 1e-9).astype(np.intp)
    i1 = np.floor((tri[:, :, 1].max(axis=1) - y[0]) / dy + 1e-9).astype(np.intp)
    j0, i0 = np.maximum(j0, 0), np.maximum(i0, 0)
    j1, i1 = np.minimum(j1, x.size - 1), np.minimum(i1, y.size - 1)
    wj, wi = j1 - j0 + 1, i1 - i0 + 1
    keep = good & (wj > 0) & (wi > 0)
    idx = np.flatnonzero(keep)
    counts = wj[idx] * wi[idx]
    total = int(counts.sum())
    if total == 0:
        return out
    t = np.repeat(idx, counts)
    local = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)
    jj = j0[t] + local % wj[t]
    ii = i0[t] + local // wj[t]
    px, py = x[jj] - ax[t], y[ii] - ay[t]
    inv = 1.0 / det[t]
    b1 = (px * e2y[t] - py * e2x[t]) * inv
    b2 = (e1x[t] * py - e1y[t] * px) * inv
    eps = -1e-9
    inside = (b1 >= eps) & (b2 >= eps) & (b1 + b2 <= 1.0 - eps)
    z = tri[t, 0, 2] + b1 * (tri[t, 1, 2] - tri[t, 0, 2]) + b2 * (tri[t, 2, 2] - tri[t, 0, 2])
    np.minimum.at(out.ravel(), (ii * x.size + jj)[inside], z[inside])
    return out
