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

import numba
import numpy as np

__all__ = [
    "box_entry", "box_extent", "capsule_entry", "capsule_extent", "cylinder_entry", "cylinder_extent",
    "ellipsoid_entry", "ellipsoid_extent", "mesh_entry", "mesh_triangles", "rasterise_lowest", "union_extent",
]

Extent = tuple[float, float, float, float]

# Rounding slack, mm: heights and positions differ from exact geometry by ~1e-12 mm, so boxes and height
# cuts are widened by this much to never drop a cell whose computed entry lies below the cut.
SLACK_MM = 1e-5


ELLIPSOID, BOX, CYLINDER = 0, 1, 2  # convex primitive kinds of ``lower_to_entry``


def lower_to_entry(heights: np.ndarray, x: np.ndarray, y: np.ndarray, kind: int, rot: np.ndarray, pos: np.ndarray,
                   size: np.ndarray, window: tuple[slice, slice] | None = None) -> None:
    """Lower ``heights`` (ny, nx) mm to the entry height of a convex primitive where that is lower:
    an ellipsoid (``size`` = semi-axes (3,) mm), a box (half-sizes (3,) mm) or a cylinder along its local z
    (radius, half-height, unused) mm, with pose ``rot``, ``pos`` (pad frame) over cell centres ``x`` (nx,),
    ``y`` (ny,) mm. ``window``: the (rows, cols) slices of ``heights`` to evaluate (default: all of it)."""
    ny, nx = heights.shape
    rows, cols = window if window is not None else (slice(0, ny), slice(0, nx))
    (r0, r1), (c0, c1) = rows.indices(ny)[:2], cols.indices(nx)[:2]
    if r1 <= r0 or c1 <= c0:
        return
    _lower_convex(heights, r0, r1, c0, c1, np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64), kind,
                  np.ascontiguousarray(rot, dtype=np.float64), np.ascontiguousarray(pos, dtype=np.float64),
                  np.ascontiguousarray(size, dtype=np.float64))


def _entry(x: np.ndarray, y: np.ndarray, kind: int, rot: np.ndarray, pos: np.ndarray, size: np.ndarray) -> np.ndarray:
    out = np.full((y.size, x.size), np.inf)
    lower_to_entry(out, x, y, kind, rot, pos, size)
    return out


def ellipsoid_entry(x: np.ndarray, y: np.ndarray, rot: np.ndarray, pos: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Ellipsoid with semi-axes ``radii`` (3,) mm (a sphere when equal)."""
    return _entry(x, y, ELLIPSOID, rot, pos, radii)


def box_entry(x: np.ndarray, y: np.ndarray, rot: np.ndarray, pos: np.ndarray, half: np.ndarray) -> np.ndarray:
    """Box with half-sizes ``half`` (3,) mm."""
    return _entry(x, y, BOX, rot, pos, half)


def cylinder_entry(
    x: np.ndarray, y: np.ndarray, rot: np.ndarray, pos: np.ndarray, radius: float, half_height: float
) -> np.ndarray:
    """Solid cylinder along the local z axis (MuJoCo's convention)."""
    return _entry(x, y, CYLINDER, rot, pos, np.array([radius, half_height, 0.0]))


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _lower_convex(heights: np.ndarray, r0: int, r1: int, c0: int, c1: int, x: np.ndarray, y: np.ndarray, kind: int,
                  rot: np.ndarray, pos: np.ndarray, size: np.ndarray) -> None:  # pragma: no cover (compiled)
    # Per cell, the vertical line {(x, y, t)} in the object's frame: origin o = rot.T @ ((x, y, 0) - pos) and
    # direction d = rot.T @ (0, 0, 1) = rot[2]; then the closed-form entry (quadratic or slabs). Row by row:
    # the origins first, then the entry in a branch-free loop over the row with every per-line constant (the
    # direction's reciprocals, the quadratic's leading term) hoisted, which the compiler vectorises (7x a
    # per-cell loop with its divisions and branches).
    d = (rot[2, 0], rot[2, 1], rot[2, 2])
    w = c1 - c0
    o0, o1, o2 = np.empty(w), np.empty(w), np.empty(w)
    t_in, t_out = np.empty(w), np.empty(w)
    inf = np.inf
    for i in range(r0, r1):
        row = heights[i, c0:c1]
        dy = y[i] - pos[1]
        for j in range(w):
            dx = x[c0 + j] - pos[0]
            o0[j] = (dx * rot[0, 0] + dy * rot[1, 0]) - pos[2] * rot[2, 0]
            o1[j] = (dx * rot[0, 1] + dy * rot[1, 1]) - pos[2] * rot[2, 1]
            o2[j] = (dx * rot[0, 2] + dy * rot[1, 2]) - pos[2] * rot[2, 2]
        if kind == ELLIPSOID:   # scaled to the unit sphere
            s0, s1, s2 = 1.0 / size[0], 1.0 / size[1], 1.0 / size[2]
            e0, e1, e2 = d[0] * s0, d[1] * s1, d[2] * s2
            a = e0 * e0 + e1 * e1 + e2 * e2
            four_a, half_over_a = 4.0 * a, 0.5 / a
            for j in range(w):
                u0, u1, u2 = o0[j] * s0, o1[j] * s1, o2[j] * s2
                b = 2.0 * (u0 * e0 + u1 * e1 + u2 * e2)
                c = (u0 * u0 + u1 * u1 + u2 * u2) - 1.0
                disc = b * b - four_a * c
                entry = (-b - np.sqrt(max(disc, 0.0))) * half_over_a
                row[j] = min(row[j], entry if disc >= 0.0 else inf)
            continue
        if kind == BOX:
            _slab(o0, d[0], -size[0], size[0], t_in, t_out, True)
            _slab(o1, d[1], -size[1], size[1], t_in, t_out, False)
        else:   # cylinder: the infinite tube about local z, cut by the slab of its height
            radius = size[0]
            a = d[0] * d[0] + d[1] * d[1]
            if a < 1e-12:
                for j in range(w):
                    inside = o0[j] * o0[j] + o1[j] * o1[j] - radius * radius <= 0.0
                    t_in[j] = -inf if inside else inf
                    t_out[j] = inf if inside else -inf
            else:
                four_a, half_over_a = 4.0 * a, 0.5 / a
                for j in range(w):
                    b = 2.0 * (o0[j] * d[0] + o1[j] * d[1])
                    c = o0[j] * o0[j] + o1[j] * o1[j] - radius * radius
                    disc = b * b - four_a * c
                    root = np.sqrt(max(disc, 0.0))
                    t_in[j] = (-b - root) * half_over_a if disc >= 0.0 else inf
                    t_out[j] = (-b + root) * half_over_a if disc >= 0.0 else -inf
        _slab(o2, d[2], -size[2 if kind == BOX else 1], size[2 if kind == BOX else 1], t_in, t_out, False)
        for j in range(w):
            row[j] = min(row[j], t_in[j] if t_in[j] <= t_out[j] else inf)


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _slab(o: np.ndarray, d: float, lo: float, hi: float, t_in: np.ndarray, t_out: np.ndarray,
          first: bool) -> None:  # pragma: no cover (compiled)
    # intersect [t_in, t_out] (or set it, when ``first``) with where the lines o + t d lie in lo <= . <= hi
    inf = np.inf
    if abs(d) < 1e-12:
        for j in range(o.size):
            inside = lo <= o[j] <= hi
            enter, leave = (-inf if inside else inf), (inf if inside else -inf)
            t_in[j] = enter if first else max(t_in[j], enter)
            t_out[j] = leave if first else min(t_out[j], leave)
        return
    inv = 1.0 / d
    for j in range(o.size):
        t1, t2 = (lo - o[j]) * inv, (hi - o[j]) * inv
        t_in[j] = min(t1, t2) if first else max(t_in[j], min(t1, t2))
        t_out[j] = max(t1, t2) if first else min(t_out[j], max(t1, t2))


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


def _segments_extent(corners: np.ndarray, edges: np.ndarray, z_max: float) -> Extent | None:
    """xy box (mm) of the segments between ``corners`` (N, 3) mm given by ``edges`` (K, 2) int, cut at
    ``z_max``; for the edges of a convex polytope, the box of the polytope's part below ``z_max`` (whose
    corners are its vertices below and its edges' crossings)."""
    found, x_lo, x_hi, y_lo, y_hi = _edges_box(np.ascontiguousarray(corners, dtype=np.float64), edges, z_max)
    if not found:
        return None
    return (x_lo - SLACK_MM, x_hi + SLACK_MM, y_lo - SLACK_MM, y_hi + SLACK_MM)


@numba.njit(cache=True, nogil=True)
def _edges_box(corners: np.ndarray, edges: np.ndarray, z_max: float) -> tuple[bool, float, float, float, float]:  # pragma: no cover
    # compiled: a cylinder's prism has 96 edges, and array code on them cost ~60 us a part, several parts a frame.
    # The same arithmetic as _clip_below: an end below the cut stays, an end above moves to the crossing.
    found = False
    x_lo, x_hi, y_lo, y_hi = np.inf, -np.inf, np.inf, -np.inf
    for k in range(edges.shape[0]):
        a, b = corners[edges[k, 0]], corners[edges[k, 1]]
        a_in, b_in = a[2] <= z_max, b[2] <= z_max
        if not (a_in or b_in):
            continue
        found = True
        t = (z_max - a[2]) / (b[2] - a[2]) if not (a_in and b_in) else 0.0
        for end_in, end in ((a_in, a), (b_in, b)):
            px = end[0] if end_in else a[0] + t * (b[0] - a[0])
            py = end[1] if end_in else a[1] + t * (b[1] - a[1])
            x_lo, x_hi, y_lo, y_hi = min(x_lo, px), max(x_hi, px), min(y_lo, py), max(y_hi, py)
    return found, x_lo, x_hi, y_lo, y_hi


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
    return _segments_extent((_BOX_CORNERS * half) @ rot.T + pos, _BOX_EDGES, z_max)


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
    return _segments_extent((_PRISM_CORNERS * np.array([radius, radius, half_height])) @ rot.T + pos, _PRISM_EDGES,
                            z_max)


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
    rasterise_lowest(out, x, y, mesh_triangles(rot, pos, vertices, faces), cutoff)
    return out


def rasterise_lowest(heights: np.ndarray, x: np.ndarray, y: np.ndarray, tri: np.ndarray,
                     cutoff: float = np.inf) -> tuple[slice, slice] | None:
    """Lower ``heights`` (ny, nx) mm, C-contiguous, on the regular grid (``x`` (nx,), ``y`` (ny,) mm) to the height
    of every triangle of ``tri`` (F, 3, 3) mm (pad frame) over each cell centre, where that is lower. Triangles
    wholly above ``cutoff`` mm are skipped, and the others scanned only over the box of their part below it.
    Returns the (rows, cols) box of the cells scanned (None: none), outside which ``heights`` is unchanged.
    """
    tri = tri[tri[:, :, 2].min(axis=1) <= cutoff]
    if tri.size == 0:
        return None
    dx = x[1] - x[0] if x.size > 1 else 1.0
    dy = y[1] - y[0] if y.size > 1 else 1.0
    x_lo, x_hi, y_lo, y_hi = _triangle_boxes(tri, cutoff + SLACK_MM)
    j0 = np.maximum(np.ceil((x_lo - x[0]) / dx - 1e-9).astype(np.intp), 0)
    j1 = np.minimum(np.floor((x_hi - x[0]) / dx + 1e-9).astype(np.intp), x.size - 1)
    i0 = np.maximum(np.ceil((y_lo - y[0]) / dy - 1e-9).astype(np.intp), 0)
    i1 = np.minimum(np.floor((y_hi - y[0]) / dy + 1e-9).astype(np.intp), y.size - 1)
    keep = np.flatnonzero((j1 >= j0) & (i1 >= i0))
    if not keep.size:
        return None
    i0, i1, j0, j1 = i0[keep], i1[keep], j0[keep], j1[keep]
    _scan_triangles(heights.reshape(-1), np.ascontiguousarray(x, dtype=np.float64),
                    np.ascontiguousarray(y, dtype=np.float64), np.ascontiguousarray(tri[keep]),
                    i0, i1, j0, j1, float(dx))
    return slice(int(i0.min()), int(i1.max()) + 1), slice(int(j0.min()), int(j1.max()) + 1)


@numba.njit(cache=True, nogil=True)
def _scan_triangles(heights: np.ndarray, x: np.ndarray, y: np.ndarray, tri: np.ndarray, i0: np.ndarray,
                    i1: np.ndarray, j0: np.ndarray, j1: np.ndarray, dx: float) -> None:  # pragma: no cover (compiled)
    # Per triangle and grid row in its box: the row's x-span from where the edges cross it (widened by SLACK_MM,
    # so a cell the scan skips lies outside the triangle by more than rounding), then barycentric coordinates per
    # cell (accepting -1e-9 of rounding) and the interpolated height, kept where lower. Compiled: a triangle
    # covers a handful of cells, where array code pays per call.
    nx = x.size
    for t in range(tri.shape[0]):
        ax, ay = tri[t, 0, 0], tri[t, 0, 1]
        e1x, e1y = tri[t, 1, 0] - ax, tri[t, 1, 1] - ay
        e2x, e2y = tri[t, 2, 0] - ax, tri[t, 2, 1] - ay
        det = e1x * e2y - e1y * e2x
        if not abs(det) > 1e-12:   # edge-on triangles are covered by their neighbours
            continue
        inv = 1.0 / det
        z0 = tri[t, 0, 2]
        dz1, dz2 = tri[t, 1, 2] - z0, tri[t, 2, 2] - z0
        for i in range(i0[t], i1[t] + 1):
            yy = y[i]
            lo, hi, met = np.inf, -np.inf, False
            for e in range(3):
                px, py = tri[t, e, 0], tri[t, e, 1]
                qx, qy = tri[t, (e + 1) % 3, 0], tri[t, (e + 1) % 3, 1]
                if not (min(py, qy) - SLACK_MM <= yy <= max(py, qy) + SLACK_MM):
                    continue
                rise = qy - py
                s = min(max((yy - py) / rise, 0.0), 1.0) if rise != 0.0 else 0.0
                xs = px + s * (qx - px)
                lo, hi, met = min(lo, xs), max(hi, xs), True
            if not met:
                continue
            jlo = max(int(np.ceil((lo - SLACK_MM - x[0]) / dx - 1e-9)), j0[t])
            jhi = min(int(np.floor((hi + SLACK_MM - x[0]) / dx + 1e-9)), j1[t])
            py_rel = yy - ay
            py_e2x, e1x_py = py_rel * e2x, e1x * py_rel
            for j in range(jlo, jhi + 1):
                px_rel = x[j] - ax
                b1 = (px_rel * e2y - py_e2x) * inv
                b2 = (e1x_py - e1y * px_rel) * inv
                if b1 >= -1e-9 and b2 >= -1e-9 and b1 + b2 <= 1.0 + 1e-9:
                    z = z0 + b1 * dz1 + b2 * dz2
                    cell = i * nx + j
                    if z < heights[cell]:
                        heights[cell] = z
