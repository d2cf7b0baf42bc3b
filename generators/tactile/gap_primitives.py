"""Pure geometry: where vertical lines through the gel grid first enter an object, in the pad frame (mm).

Every ``*_entry`` function takes the grid's cell centres ``x`` (nx,), ``y`` (ny,) (mm, pad frame) and the
object's pose in the pad frame (rotation ``rot`` (3, 3) object-to-pad, centre ``pos`` (3,) mm), and returns the
height z (ny, nx) mm at which the line {(x, y, t), t from -inf} enters the object (+inf where it misses).
Convex primitives are solved in closed form (quadratic or slab intersection); a triangle mesh, convex or not,
is rasterised: each triangle's projection onto the gel plane is scanned and the lowest interpolated height kept.

Every ``*_extent`` function returns the xy bounding box ``(x_lo, x_hi, y_lo, y_hi)`` mm (pad frame) of the
object's part at z <= ``z_max`` mm, or None when the object lies wholly above it: a line outside that box
enters the object above ``z_max`` or never, so the caller evaluates only the cells inside it.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "box_entry", "box_extent", "capsule_entry", "capsule_extent", "cylinder_entry", "cylinder_extent",
    "ellipsoid_entry", "ellipsoid_extent", "mesh_entry", "mesh_triangles", "triangle_hits", "union_extent",
]

Extent = tuple[float, float, float, float]

# Rounding slack, mm: heights and positions differ from exact geometry by ~1e-12 mm, so boxes and height
# cuts are widened by this much to never drop a cell whose computed entry lies below the cut.
SLACK_MM = 1e-5


def _local_origin(x: np.ndarray, y: np.ndarray, rot: np.ndarray, pos: np.ndarray, k: int) -> np.ndarray:
    """Component ``k`` (ny, nx) of the line origins in the object's frame: (rot.T @ (x - px, y - py, -pz))[k].

    An outer sum of a row and a column term, so the box and cylinder read one component at a time and build
    no (ny, nx, 3) array (the same operations in the same order as the 3-vector form: bit-identical).
    """
    return ((x - pos[0]) * rot[0, k])[None, :] + ((y - pos[1]) * rot[1, k])[:, None] - pos[2] * rot[2, k]


def _quadratic_entry(a: float | np.ndarray, b: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Roots (t_in, t_out) of a t^2 + b t + c = 0 (a > 0), +inf/-inf where there is none."""
    disc = b * b - 4.0 * a * c
    ok = disc >= 0.0
    sq = np.sqrt(np.where(ok, disc, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        t_in = np.where(ok, (-b - sq) / (2.0 * a), np.inf)
        t_out = np.where(ok, (-b + sq) / (2.0 * a), -np.inf)
    return t_in, t_out


def _quadratic_first_root(a: float, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """t_in of :func:`_quadratic_entry` alone (the same arithmetic), for callers that need no exit."""
    disc = b * b - 4.0 * a * c
    ok = disc >= 0.0
    np.sqrt(disc, out=disc, where=ok)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_in = (-b - disc) / (2.0 * a)
    t_in[~ok] = np.inf
    return t_in


def ellipsoid_entry(x: np.ndarray, y: np.ndarray, rot: np.ndarray, pos: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Ellipsoid with semi-axes ``radii`` (3,) mm (a sphere when equal)."""
    o = np.empty((y.size, x.size, 3))
    for k in range(3):  # scaled to the unit sphere as they are written, one pass over (ny, nx, 3) fewer
        np.divide(_local_origin(x, y, rot, pos, k), radii[k], out=o[..., k])
    d = rot[2] / radii
    return _quadratic_first_root(float(d @ d), 2.0 * (o @ d), np.einsum("ijk,ijk->ij", o, o) - 1.0)


def _slab(o: np.ndarray, d: float, lo: float, hi: float) -> tuple[np.ndarray, np.ndarray]:
    if abs(d) < 1e-12:
        inside = (o >= lo) & (o <= hi)
        return np.where(inside, -np.inf, np.inf), np.where(inside, np.inf, -np.inf)
    t1, t2 = (lo - o) / d, (hi - o) / d
    return np.minimum(t1, t2), np.maximum(t1, t2)


def box_entry(x: np.ndarray, y: np.ndarray, rot: np.ndarray, pos: np.ndarray, half: np.ndarray) -> np.ndarray:
    """Box with half-sizes ``half`` (3,) mm."""
    d = rot[2]
    # max(-inf, a) is a: the first slab is the running interval, the other two narrow it in place
    t_in, t_out = _slab(_local_origin(x, y, rot, pos, 0), float(d[0]), -half[0], half[0])
    for k in (1, 2):
        a, b = _slab(_local_origin(x, y, rot, pos, k), float(d[k]), -half[k], half[k])
        np.maximum(t_in, a, out=t_in)
        np.minimum(t_out, b, out=t_out)
    t_in[t_in > t_out] = np.inf
    return t_in


def _tube(o0: np.ndarray, o1: np.ndarray, d: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Infinite cylinder about the local z axis; ``o0``, ``o1`` (ny, nx) local x and y of the line origins."""
    a = float(d[0] ** 2 + d[1] ** 2)
    c = o0**2 + o1**2 - radius * radius
    if a < 1e-12:
        inside = c <= 0.0
        return np.where(inside, -np.inf, np.inf), np.where(inside, np.inf, -np.inf)
    return _quadratic_entry(a, 2.0 * (o0 * d[0] + o1 * d[1]), c)


def cylinder_entry(
    x: np.ndarray, y: np.ndarray, rot: np.ndarray, pos: np.ndarray, radius: float, half_height: float
) -> np.ndarray:
    """Solid cylinder along the local z axis (MuJoCo's convention)."""
    d = rot[2]
    a_in, a_out = _tube(_local_origin(x, y, rot, pos, 0), _local_origin(x, y, rot, pos, 1), d, radius)
    b_in, b_out = _slab(_local_origin(x, y, rot, pos, 2), float(d[2]), -half_height, half_height)
    t_in, t_out = np.maximum(a_in, b_in), np.minimum(a_out, b_out)
    t_in[t_in > t_out] = np.inf
    return t_in


def capsule_entry(
    x: np.ndarray, y: np.ndarray, rot: np.ndarray, pos: np.ndarray, radius: float, half_length: float
) -> np.ndarray:
    """Capsule: cylinder of ``half_length`` along local z capped by two spheres (entry of a union = min)."""
    body = cylinder_entry(x, y, rot, pos, radius, half_length)
    radii = np.full(3, radius)
    caps = [ellipsoid_entry(x, y, rot, pos + rot[:, 2] * s * half_length, radii) for s in (-1.0, 1.0)]
    return np.minimum(body, np.minimum(*caps))


def _clip_below(a: np.ndarray, b: np.ndarray, z_max: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Segments a-b (..., 3) mm cut to their part at z <= ``z_max``: new ends (..., 2) (xy) and a mask of the
    segments with such a part."""
    za, zb = a[..., 2], b[..., 2]
    a_in, b_in = za <= z_max, zb <= z_max
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):  # level or infinite: no crossing used
        t = ((z_max - za) / (zb - za))[..., None]
        cross = a[..., :2] + t * (b[..., :2] - a[..., :2])
    ends_a = np.where(a_in[..., None], a[..., :2], cross)
    ends_b = np.where(b_in[..., None], b[..., :2], cross)
    return ends_a, ends_b, a_in | b_in


def _segments_extent(a: np.ndarray, b: np.ndarray, z_max: float) -> Extent | None:
    """xy box (mm) of the segments a-b (K, 3) cut at ``z_max``; for the edges of a convex polytope, the box of
    the polytope's part below ``z_max`` (whose corners are its vertices below and its edges' crossings)."""
    ends_a, ends_b, keep = _clip_below(a, b, z_max)
    if not keep.any():
        return None
    ends = np.concatenate([ends_a[keep], ends_b[keep]])
    lo, hi = ends.min(axis=0), ends.max(axis=0)
    return (float(lo[0]) - SLACK_MM, float(hi[0]) + SLACK_MM, float(lo[1]) - SLACK_MM, float(hi[1]) + SLACK_MM)


def union_extent(*extents: Extent | None) -> Extent | None:
    """The box (mm) holding every given box; None when all are None."""
    boxes = [e for e in extents if e is not None]
    if not boxes:
        return None
    return (min(e[0] for e in boxes), max(e[1] for e in boxes), min(e[2] for e in boxes), max(e[3] for e in boxes))


def ellipsoid_extent(rot: np.ndarray, pos: np.ndarray, radii: np.ndarray, z_max: float) -> Extent | None:
    """Ellipsoid (semi-axes ``radii`` (3,) mm) below ``z_max``, exactly from its shape matrix.

    With M = rot diag(radii^2) rot.T the ellipsoid is {w : w.T M^-1 w <= 1} about ``pos``; its slice at height
    w_z = h is an ellipse centred at M[:2, 2] h / M_zz with shape (1 - h^2 / M_zz)(M[:2, :2] - M[:2, 2] M[2, :2]
    / M_zz) (as when conditioning a Gaussian). The extreme along x (or y) of the part below ``z_max`` is the
    whole ellipsoid's extreme when that point lies below ``z_max``, else the slice at ``z_max``'s.
    """
    m = (rot * np.square(radii)) @ rot.T
    mzz = float(m[2, 2])
    pz = float(pos[2])
    if pz - math.sqrt(mzz) > z_max:
        return None
    h = z_max - pz
    shrink = max(1.0 - h * h / mzz, 0.0)
    box = []
    for k in (0, 1):
        mkk, mkz, pk = float(m[k, k]), float(m[k, 2]), float(pos[k])
        reach = math.sqrt(mkk)
        lift = mkz / reach  # height above the centre of the extreme point toward +k
        slice_mid = pk + mkz * h / mzz
        slice_half = math.sqrt(shrink * max(mkk - mkz * mkz / mzz, 0.0))
        lo = pk - reach if pz - lift <= z_max else slice_mid - slice_half
        hi = pk + reach if pz + lift <= z_max else slice_mid + slice_half
        box += [lo - SLACK_MM, hi + SLACK_MM]
    return (box[0], box[1], box[2], box[3])


_BOX_CORNERS = np.array([[sx, sy, sz] for sx in (-1.0, 1.0) for sy in (-1.0, 1.0) for sz in (-1.0, 1.0)])
_BOX_EDGES = np.array([(i, i | bit) for i in range(8) for bit in (1, 2, 4) if not i & bit])


def box_extent(rot: np.ndarray, pos: np.ndarray, half: np.ndarray, z_max: float) -> Extent | None:
    """Box (half-sizes ``half`` (3,) mm) below ``z_max``, exactly from its corners and edges."""
    corners = (_BOX_CORNERS * half) @ rot.T + pos
    return _segments_extent(corners[_BOX_EDGES[:, 0]], corners[_BOX_EDGES[:, 1]], z_max)


# A cylinder lies inside the prism on the regular polygon circumscribing its cross-section; with 32 sides the
# prism is 0.5 % wider, well under a pixel at the indenters' radii (a box need only hold the part, not fit it).
_PRISM_SIDES = 32
_PRISM_RING = np.column_stack([np.cos(np.arange(_PRISM_SIDES) * 2 * np.pi / _PRISM_SIDES),
                               np.sin(np.arange(_PRISM_SIDES) * 2 * np.pi / _PRISM_SIDES)]) / np.cos(np.pi / _PRISM_SIDES)
_PRISM_CORNERS = np.vstack([np.column_stack([_PRISM_RING, np.full(_PRISM_SIDES, z)]) for z in (-1.0, 1.0)])
_PRISM_EDGES = np.array([(i, (i + 1) % _PRISM_SIDES) for i in range(_PRISM_SIDES)]
                        + [(_PRISM_SIDES + i, _PRISM_SIDES + (i + 1) % _PRISM_SIDES) for i in range(_PRISM_SIDES)]
                        + [(i, _PRISM_SIDES + i) for i in range(_PRISM_SIDES)])


def cylinder_extent(rot: np.ndarray, pos: np.ndarray, radius: float, half_height: float, z_max: float) -> Extent | None:
    """Cylinder (along local z) below ``z_max``, from its circumscribed 32-sided prism (a slightly larger box)."""
    corners = (_PRISM_CORNERS * np.array([radius, radius, half_height])) @ rot.T + pos
    return _segments_extent(corners[_PRISM_EDGES[:, 0]], corners[_PRISM_EDGES[:, 1]], z_max)


def capsule_extent(rot: np.ndarray, pos: np.ndarray, radius: float, half_length: float, z_max: float) -> Extent | None:
    """Capsule below ``z_max``: the box holding its cylinder's and its two caps' boxes."""
    radii = np.full(3, radius)
    caps = [ellipsoid_extent(rot, pos + rot[:, 2] * s * half_length, radii, z_max) for s in (-1.0, 1.0)]
    return union_extent(cylinder_extent(rot, pos, radius, half_length, z_max), *caps)


def _triangle_boxes(tri: np.ndarray, z_max: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per-triangle xy box (x_lo, x_hi, y_lo, y_hi), each (F,) mm, of the part of ``tri`` (F, 3, 3) at z <=
    ``z_max``, which must hold a vertex of each: a cell outside the box meets the triangle higher up or never."""
    if not np.isfinite(z_max):
        lo, hi = tri[:, :, :2].min(axis=1), tri[:, :, :2].max(axis=1)
        return lo[:, 0], hi[:, 0], lo[:, 1], hi[:, 1]
    ends_a, ends_b, keep = _clip_below(tri, np.roll(tri, -1, axis=1), z_max)  # (F, 3 edges, 2)
    # an edge wholly above contributes nothing: stand in the triangle's lowest vertex, which is in the box anyway
    lowest = tri[np.arange(len(tri)), tri[:, :, 2].argmin(axis=1), :2][:, None, :]
    ends = np.where(np.concatenate([keep, keep], axis=1)[..., None], np.concatenate([ends_a, ends_b], axis=1), lowest)
    lo, hi = ends.min(axis=1), ends.max(axis=1)
    return lo[:, 0] - SLACK_MM, hi[:, 0] + SLACK_MM, lo[:, 1] - SLACK_MM, hi[:, 1] + SLACK_MM


def _row_spans(
    tri: np.ndarray, rows: np.ndarray, y: np.ndarray, tri_of_row: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """x-span (lo, hi) mm, each (R,), of triangle ``tri[tri_of_row]`` (of (F, 3, 3), mm) along grid row
    ``y[rows]``, from where its edges cross the row (widened by SLACK_MM, so a cell the scan skips lies outside
    the triangle by more than rounding: scanning spans, not boxes, halves the cells tested on a slanted edge)."""
    yy = y[rows]
    corners = tri[tri_of_row]  # (R, 3, 3)
    p, q = corners, np.roll(corners, -1, axis=1)
    py, qy = p[:, :, 1], q[:, :, 1]
    rise = qy - py
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.clip((yy[:, None] - py) / rise, 0.0, 1.0)
    s = np.where(rise != 0.0, s, 0.0)  # a level edge on the row is met at its ends by the other two edges
    xs = p[:, :, 0] + s * (q[:, :, 0] - p[:, :, 0])
    meets = (yy[:, None] >= np.minimum(py, qy) - SLACK_MM) & (yy[:, None] <= np.maximum(py, qy) + SLACK_MM)
    lo = np.where(meets, xs, np.inf).min(axis=1) - SLACK_MM
    hi = np.where(meets, xs, -np.inf).max(axis=1) + SLACK_MM
    return lo, hi


def _runs(starts: np.ndarray, counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For runs of ``counts`` consecutive integers from ``starts``: each member's run index and value."""
    run = np.repeat(np.arange(counts.size), counts)
    offset = np.arange(run.size) - np.repeat(np.cumsum(counts) - counts, counts)
    return run, starts[run] + offset


def mesh_triangles(rot: np.ndarray, pos: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Triangles (F, 3, 3) mm in the pad frame of a mesh (``vertices`` (V, 3) mm in the object frame, ``faces``
    (F, 3) int)."""
    return (vertices @ rot.T + pos)[faces]


def mesh_entry(
    x: np.ndarray, y: np.ndarray, rot: np.ndarray, pos: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
    cutoff: float = np.inf,
) -> np.ndarray:
    """Triangle mesh (``vertices`` (V, 3) mm in the object frame, ``faces`` (F, 3) int), rasterised.

    Triangles entirely above ``cutoff`` (mm) are skipped, and each other triangle is scanned only over its
    part below ``cutoff``, so heights above it may read +inf. Requires a regular grid (uniform spacing of
    ``x`` and ``y``).
    """
    out = np.full((y.size, x.size), np.inf)
    cells, z = triangle_hits(x, y, mesh_triangles(rot, pos, vertices, faces), cutoff)
    np.minimum.at(out.ravel(), cells, z)
    return out


def triangle_hits(x: np.ndarray, y: np.ndarray, tri: np.ndarray, cutoff: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
    """Cells of the regular grid (``x`` (nx,), ``y`` (ny,) mm) covered by triangles ``tri`` (F, 3, 3) mm, pad
    frame, below ``cutoff`` mm: flat indices (N,) into (ny, nx) and the heights (N,) mm there, a cell once per
    triangle over it (the entry is the lowest height per cell). Triangles wholly above ``cutoff`` are skipped,
    and the others scanned only over the box of their part below it.
    """
    none = (np.empty(0, np.intp), np.empty(0))
    tri = tri[tri[:, :, 2].min(axis=1) <= cutoff]
    if tri.size == 0:
        return none
    dx = x[1] - x[0] if x.size > 1 else 1.0
    dy = y[1] - y[0] if y.size > 1 else 1.0
    ax, ay = tri[:, 0, 0], tri[:, 0, 1]
    e1x, e1y = tri[:, 1, 0] - ax, tri[:, 1, 1] - ay
    e2x, e2y = tri[:, 2, 0] - ax, tri[:, 2, 1] - ay
    det = e1x * e2y - e1y * e2x
    good = np.abs(det) > 1e-12  # edge-on triangles are covered by their neighbours
    x_lo, x_hi, y_lo, y_hi = _triangle_boxes(tri, cutoff + SLACK_MM)
    j0 = np.maximum(np.ceil((x_lo - x[0]) / dx - 1e-9).astype(np.intp), 0)
    j1 = np.minimum(np.floor((x_hi - x[0]) / dx + 1e-9).astype(np.intp), x.size - 1)
    i0 = np.maximum(np.ceil((y_lo - y[0]) / dy - 1e-9).astype(np.intp), 0)
    i1 = np.minimum(np.floor((y_hi - y[0]) / dy + 1e-9).astype(np.intp), y.size - 1)
    keep = np.flatnonzero(good & (j1 >= j0) & (i1 >= i0))
    if keep.size == 0:
        return none
    # one run of cells per (triangle, row): the row's span of the triangle, inside the triangle's box
    tr, ii = _runs(i0[keep], i1[keep] - i0[keep] + 1)
    tr = keep[tr]
    span_lo, span_hi = _row_spans(tri, ii, y, tr)
    jlo = np.maximum(np.ceil((span_lo - x[0]) / dx - 1e-9).astype(np.intp), j0[tr])
    jhi = np.minimum(np.floor((span_hi - x[0]) / dx + 1e-9).astype(np.intp), j1[tr])
    row_cells = np.maximum(jhi - jlo + 1, 0)
    # constants of each run (the barycentric terms that do not depend on the column)
    py = y[ii] - ay[tr]
    inv = 1.0 / det[tr]
    consts = np.column_stack([ax[tr], e2y[tr], py * e2x[tr], e1x[tr] * py, e1y[tr], inv, tri[tr, 0, 2],
                              tri[tr, 1, 2] - tri[tr, 0, 2], tri[tr, 2, 2] - tri[tr, 0, 2]])
    run, jj = _runs(jlo, row_cells)
    c = consts[run].T
    px = x[jj] - c[0]
    b1 = (px * c[1] - c[2]) * c[5]
    b2 = (c[3] - c[4] * px) * c[5]
    eps = -1e-9
    inside = (b1 >= eps) & (b2 >= eps) & (b1 + b2 <= 1.0 - eps)
    z = c[6] + b1 * c[7] + b2 * c[8]
    return (ii[run] * x.size + jj)[inside], z[inside]
