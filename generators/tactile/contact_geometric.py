"""Geometric contact: Hertz's footprint and load from the overlap alone, with an elastic-shaped sink-in around it.
Cheap: no elastic solve, a few passes over the contact's window.

The overlap o = max(-g, 0) (mm) is split into connected pieces (8-connected). In each piece, of deepest overlap
d, the gel touches the object where o > ``contact_fraction`` d (default 1/2). For a sphere that is Hertz's contact
radius a = sqrt(R d) (the rigid overlap's rim is at sqrt(2 R d), 41 % wider); for a flat punch it is the whole
face. In contact the gel takes the object's shape (D = o).

Load, from the contact's equivalent radius a = sqrt(A / pi) (A its area) and the overlap above the contact
level, h = o - d / 2 (mean <h> over the contact):

    F = E* a (2/3 d + 8/3 <h>)

exact for both of the closed forms it is built from: a paraboloid (<h> = d / 4: F = 4/3 E* a d, Hertz) and a
flat punch (<h> = d / 2: F = 2 E* a d). The pressure has Hertz's shape, p proportional to sqrt(h) (a sphere's
h = (a^2 - r^2) / 2R makes it p0 sqrt(1 - r^2 / a^2) with Hertz's p0), scaled to F.

Outside the contact the gel sinks in as the half-space does around the two closed forms, at the distance r
from the contact's rim: D = u_e S(rho), rho = 1 + r / a, with u_e the overlap on the contact's rim (d / 2 for a
sphere, d for a punch) and S a blend of the sphere's exterior displacement
(2 / pi) ((2 - rho^2) asin(1 / rho) + sqrt(rho^2 - 1)) and the punch's (2 / pi) asin(1 / rho), weighted so that
the far field is the load's F / (pi E* r) (all sphere for a paraboloid, all punch for a flat face). Where the
rigid overlap is deeper than that (a sphere's annulus between a and sqrt(2) a) the gel follows the overlap: it
cannot pass through the object. Beyond ``tail_start`` contact radii S is continued by the parabola that meets
its value and slope there and reaches zero with zero slope (about three times further), so the sink-in, which
falls off like 1 / r, ends smoothly within a window a few contact radii wide: the images need the deformation
beside the contact (its slopes shade it), the cost stays with the contact's size. Pieces of one overlap are
treated apart: the sink-in of each pixel is that of the nearest contact (no superposition).

Accuracy (tests/test_tactile_mechanics.py, benchmarks/tactile_speed_vs_accuracy.py): a sphere's force, radius
and peak pressure are Hertz's within the pixel grid's resolution; a flat punch's force is 2 a E* d. Other shapes
are approximations, compared with the elastic solver in benchmarks/tactile_speed_vs_accuracy.py.
"""

from __future__ import annotations

from functools import lru_cache

import numba
import numpy as np

from univtac_data.schema.sensors import Material

from .contact import ContactConfig, ContactResult
from .sensor_model import SensorGrid

__all__ = ["exterior_profiles", "solve_geometric"]

TABLE_PER_UNIT = 128  # samples of the exterior profiles per unit of rho
EXTERIOR_BLOCKS_PER_RADIUS = 8  # the sink-in is evaluated on pixel blocks at least this many per contact radius


@lru_cache(maxsize=8)
def exterior_profiles(tail_start: float) -> tuple[np.ndarray, np.ndarray, float]:
    """(sphere, punch, rho_end): the exterior sink-in of a paraboloid and of a flat punch, each divided by its
    value at the rim (rho = r / a = 1), tabulated at rho = 1 + k / ``TABLE_PER_UNIT``, each continued beyond
    ``tail_start`` by the parabola of the same value and slope that ends at zero with zero slope; rho_end: where
    the later of the two ends (both tables are zero from there on)."""
    def sphere(rho: np.ndarray) -> np.ndarray:
        return 2.0 / np.pi * ((2.0 - rho * rho) * np.arcsin(1.0 / rho) + np.sqrt(rho * rho - 1.0))

    def punch(rho: np.ndarray) -> np.ndarray:
        return 2.0 / np.pi * np.arcsin(1.0 / rho)

    def slope(f, rho: float) -> float:  # type: ignore[no-untyped-def]
        eps = 1e-6
        return float((f(np.array(rho + eps)) - f(np.array(rho - eps))) / (2.0 * eps))

    ends = []
    for f in (sphere, punch):
        value, s = float(f(np.array(tail_start))), slope(f, tail_start)
        ends.append((value, tail_start + 2.0 * value / -s))
    rho_end = max(end for _, end in ends)
    rho = 1.0 + np.arange(int(np.ceil((rho_end - 1.0) * TABLE_PER_UNIT)) + 2) / TABLE_PER_UNIT
    tables = []
    for f, (value, end) in zip((sphere, punch), ends):
        length = end - tail_start
        tail = value * (np.clip(end - rho, 0.0, None) / length) ** 2
        table = np.where(rho < tail_start, f(np.maximum(rho, 1.0)), tail)
        table.setflags(write=False)
        tables.append(table)
    return tables[0], tables[1], rho_end


def solve_geometric(gap_mm: np.ndarray, grid: SensorGrid, material: Material, config: ContactConfig,
                    gap_box: tuple[slice, slice] | None = None) -> ContactResult:
    """Geometric contact of the gap field (ny, nx) mm on ``grid``; see the module docstring. ``gap_box``:
    (rows, cols) outside which the gap is positive, if known: the overlap is looked for only there."""
    h, w = grid.shape
    if gap_box is None:
        local = gap_mm < 0.0
        r_off = c_off = 0
    else:
        local = gap_mm[gap_box] < 0.0
        r_off, c_off = gap_box[0].indices(h)[0], gap_box[1].indices(w)[0]
    depth = np.zeros(grid.shape)
    pressure = np.zeros(grid.shape)
    mask = np.zeros(grid.shape, dtype=bool)
    rows = np.flatnonzero(local.any(axis=1))
    if rows.size == 0:
        return ContactResult(depth, pressure, mask, 0.0, box=(slice(0, 0), slice(0, 0)))
    cols = np.flatnonzero(local[rows[0] : rows[-1] + 1].any(axis=0)) + c_off
    rows += r_off
    gap = np.ascontiguousarray(gap_mm, dtype=np.float64)
    r0, r1, c0, c1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
    labels, deepest = _pieces(gap, r0, r1, c0, c1)
    stats = _contact_stats(gap, r0, r1, c0, c1, labels, deepest, config.contact_fraction)
    count, sum_h, sum_root_h, rim_sum, rim_count = stats
    e_star = material.youngs_modulus_mpa / (1.0 - material.poisson_ratio**2)
    cell = grid.cell_area_mm2
    radius = np.sqrt(count * cell / np.pi)  # equivalent contact radius of each piece, mm
    force = e_star * radius * (2.0 / 3.0 * deepest + 8.0 / 3.0 * sum_h / count)  # N (MPa mm^2)
    pressure_scale = force / (sum_root_h * cell)  # p = scale sqrt(h), MPa / sqrt(mm)
    rim = rim_sum / np.maximum(rim_count, 1)  # overlap on the contact's rim, mm
    # the far field u -> F / (pi E* r): sphere's 8/3 u_e a / (pi r), punch's 2 u_e a / (pi r)
    blend = np.clip(1.5 * (force / (e_star * radius * rim) - 2.0), 0.0, 1.0)
    sphere, punch, rho_end = exterior_profiles(config.tail_start)
    reach = float(radius.max()) * (rho_end - 1.0)  # mm beyond the contact where the sink-in ends
    grow_r, grow_c = int(np.ceil(reach / grid.dy_mm)) + 1, int(np.ceil(reach / grid.dx_mm)) + 1
    win = (slice(max(r0 - grow_r, 0), min(r1 + grow_r, h)), slice(max(c0 - grow_c, 0), min(c1 + grow_c, w)))
    # blocks of the sink-in: at least EXTERIOR_BLOCKS_PER_RADIUS across the smallest contact radius
    block = max(1, int(float(radius.min()) / (EXTERIOR_BLOCKS_PER_RADIUS * max(grid.dx_mm, grid.dy_mm))))
    _fill(gap, win[0].start, win[0].stop, win[1].start, win[1].stop, r0, c0, labels, deepest,
          config.contact_fraction, pressure_scale, radius, rim, blend, sphere, punch, grid.dy_mm, grid.dx_mm,
          block, depth, pressure, mask)
    return ContactResult(depth, pressure, mask, float(force.sum()), box=win)


@numba.njit(cache=True, nogil=True)
def _pieces(gap: np.ndarray, r0: int, r1: int, c0: int, c1: int) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover
    # 8-connected pieces of the overlap (gap < 0) in the box: labels (box) int32, -1 off the overlap, and each
    # piece's deepest overlap (mm), by a depth-first flood fill
    h, w = r1 - r0, c1 - c0
    labels = np.full((h, w), -1, np.int32)
    deepest = np.zeros(16)
    stack = np.empty(h * w, np.int64)
    n = 0
    for i in range(h):
        for j in range(w):
            if labels[i, j] >= 0 or gap[r0 + i, c0 + j] >= 0.0:
                continue
            if n == deepest.size:
                grown = np.zeros(2 * n)
                grown[:n] = deepest
                deepest = grown
            labels[i, j] = n
            top, low = 1, 0.0
            stack[0] = i * w + j
            while top > 0:
                top -= 1
                k = stack[top]
                a, b = k // w, k % w
                low = max(low, -gap[r0 + a, c0 + b])
                for da in range(-1, 2):
                    for db in range(-1, 2):
                        p, q = a + da, b + db
                        if 0 <= p < h and 0 <= q < w and labels[p, q] < 0 and gap[r0 + p, c0 + q] < 0.0:
                            labels[p, q] = n
                            stack[top] = p * w + q
                            top += 1
            deepest[n] = low
            n += 1
    return labels, deepest[:n].copy()


@numba.njit(cache=True, nogil=True)
def _contact_stats(gap: np.ndarray, r0: int, r1: int, c0: int, c1: int, labels: np.ndarray, deepest: np.ndarray,
                   fraction: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover
    # per piece: contact cells (o > fraction d), sum of h = o - d / 2 and of sqrt(h) over them, and the sum and
    # count of the gel's level on the contact's rim (each side of a contact cell that faces a cell out of contact)
    n = deepest.size
    count, sum_h, sum_root, rim_sum, rim_count = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)
    h, w = r1 - r0, c1 - c0
    for i in range(h):
        for j in range(w):
            k = labels[i, j]
            if k < 0:
                continue
            level = fraction * deepest[k]
            o = -gap[r0 + i, c0 + j]
            if o <= level:
                continue
            count[k] += 1.0
            above = o - 0.5 * deepest[k]
            if above > 0.0:
                sum_h[k] += above
                sum_root[k] += np.sqrt(above)
            # the rim's level, across each side out of contact: where the object goes on beyond the contact (its
            # overlap there is positive) the surface crosses fraction d between the two pixels; where it ends (a
            # sharp edge, as a punch's), the gel is held at this pixel's overlap
            for p, q in ((i - 1, j), (i + 1, j), (i, j - 1), (i, j + 1)):
                outside_o = 0.0
                if 0 <= p < h and 0 <= q < w:
                    outside_o = -gap[r0 + p, c0 + q]
                    if labels[p, q] == k and outside_o > level:
                        continue
                rim_sum[k] += level if outside_o > 0.0 else o
                rim_count[k] += 1.0
    return count, sum_h, sum_root, rim_sum, rim_count


@numba.njit(cache=True, nogil=True, inline="always")
def _take(near_r: np.ndarray, near_c: np.ndarray, dist2: np.ndarray, i: int, j: int, p: int, q: int, k: int,
          centre: float, dy: float, dx: float) -> None:  # pragma: no cover (compiled)
    # block (i, j) takes the rim pixel (window row, col) nearest to block (p, q) when it is nearer to its own
    # centre (pixel i k + centre, j k + centre) than its current one (mm^2)
    if p < 0 or q < 0 or p >= near_r.shape[0] or q >= near_r.shape[1]:
        return
    a = near_r[p, q]
    if a < 0:
        return
    ea, eb = (i * k + centre - a) * dy, (j * k + centre - near_c[p, q]) * dx
    d = ea * ea + eb * eb
    if d < dist2[i, j]:
        near_r[i, j] = a
        near_c[i, j] = near_c[p, q]
        dist2[i, j] = d


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _fill(gap: np.ndarray, w0: int, w1: int, v0: int, v1: int, r0: int, c0: int, labels: np.ndarray,
          deepest: np.ndarray, fraction: float, pressure_scale: np.ndarray, radius: np.ndarray, rim: np.ndarray,
          blend: np.ndarray, sphere: np.ndarray, punch: np.ndarray, dy: float, dx: float, k: int,
          depth: np.ndarray, pressure: np.ndarray, mask: np.ndarray) -> None:  # pragma: no cover (compiled)
    # rows w0:w1, cols v0:v1 of the image. Contact cells get the overlap and the Hertz-shaped pressure. The sink-in
    # is found on k x k blocks of the window: each block takes the piece of the nearest block holding contact
    # (propagated in raster passes, as in a vector distance transform) and that piece's profile at the distance
    # between the two blocks' centres less half a block (the rim lies inside the contact block); blocks holding
    # contact take the rim's overlap. Each pixel off the contact then reads the blocks bilinearly, never less than
    # its overlap. The sink-in varies over a contact radius, which spans 8 blocks or more, so this costs a
    # k^2-th of a per-pixel transform and changes the depth by well under a micrometre.
    h, w = w1 - w0, v1 - v0
    ch, cw = -(-h // k), -(-w // k)
    centre = 0.5 * (k - 1)
    near_r = np.full((ch, cw), -1, np.int32)  # nearest rim pixel: window row, col
    near_c = np.full((ch, cw), -1, np.int32)
    piece = np.full((ch, cw), -1, np.int32)  # the piece of a block holding contact
    dist2 = np.full((ch, cw), np.inf)
    lh, lw = labels.shape
    for i in range(lh):
        for j in range(lw):
            p = labels[i, j]
            if p < 0:
                continue
            o = -gap[r0 + i, c0 + j]
            if o > fraction * deepest[p]:
                gi, gj = r0 + i, c0 + j
                mask[gi, gj] = True
                depth[gi, gj] = o
                pressure[gi, gj] = pressure_scale[p] * np.sqrt(max(o - 0.5 * deepest[p], 0.0))
                piece[(gi - w0) // k, (gj - v0) // k] = p
    for i in range(lh):  # rim pixels seed their blocks: each block keeps the one nearest its centre
        gi = r0 + i
        for j in range(lw):
            gj = c0 + j
            if not mask[gi, gj] or (mask[max(gi - 1, 0), gj] and mask[min(gi + 1, mask.shape[0] - 1), gj]
                                    and mask[gi, max(gj - 1, 0)] and mask[gi, min(gj + 1, mask.shape[1] - 1)]):
                continue
            a, b = (gi - w0) // k, (gj - v0) // k
            ea, eb = (a * k + centre - (gi - w0)) * dy, (b * k + centre - (gj - v0)) * dx
            d = ea * ea + eb * eb
            if d < dist2[a, b]:
                near_r[a, b], near_c[a, b], dist2[a, b] = gi - w0, gj - v0, d
    for i in range(ch):  # down the blocks: from the row above, then along the row both ways
        for j in range(cw):
            _take(near_r, near_c, dist2, i, j, i - 1, j - 1, k, centre, dy, dx)
            _take(near_r, near_c, dist2, i, j, i - 1, j, k, centre, dy, dx)
            _take(near_r, near_c, dist2, i, j, i - 1, j + 1, k, centre, dy, dx)
            _take(near_r, near_c, dist2, i, j, i, j - 1, k, centre, dy, dx)
        for j in range(cw - 2, -1, -1):
            _take(near_r, near_c, dist2, i, j, i, j + 1, k, centre, dy, dx)
    for i in range(ch - 1, -1, -1):  # and up
        for j in range(cw - 1, -1, -1):
            _take(near_r, near_c, dist2, i, j, i + 1, j + 1, k, centre, dy, dx)
            _take(near_r, near_c, dist2, i, j, i + 1, j, k, centre, dy, dx)
            _take(near_r, near_c, dist2, i, j, i + 1, j - 1, k, centre, dy, dx)
            _take(near_r, near_c, dist2, i, j, i, j + 1, k, centre, dy, dx)
        for j in range(1, cw):
            _take(near_r, near_c, dist2, i, j, i, j - 1, k, centre, dy, dx)
    sink = np.zeros((ch, cw))
    half_pixel = 0.5 * min(dx, dy)  # from a rim pixel's centre to the rim
    last = sphere.size - 2
    for i in range(ch):
        for j in range(cw):
            if near_r[i, j] < 0:
                continue
            p = labels[near_r[i, j] + w0 - r0, near_c[i, j] + v0 - c0]
            if piece[i, j] >= 0:  # a block holding contact: the rim's level
                sink[i, j] = rim[piece[i, j]]
                continue
            t = max(np.sqrt(dist2[i, j]) - half_pixel, 0.0) / radius[p] * TABLE_PER_UNIT
            m = int(t)
            if m < last:
                f = t - m
                shape = blend[p] * (sphere[m] * (1.0 - f) + sphere[m + 1] * f) + \
                    (1.0 - blend[p]) * (punch[m] * (1.0 - f) + punch[m + 1] * f)
                sink[i, j] = rim[p] * shape
    # bilinear between block centres ((k - 1) / 2 px into the block), held constant beyond the outer ones: each
    # row first blends its two block rows, then each pixel its two blocks (a quarter of the arithmetic of
    # blending four blocks a pixel)
    inv_k = 1.0 / k
    col_lo, col_t = np.empty(w, np.int64), np.empty(w)
    for j in range(w):
        x = min(max((j - centre) * inv_k, 0.0), cw - 1.0)
        lo = min(int(x), max(cw - 2, 0))
        col_lo[j], col_t[j] = lo, x - lo
    hi_c = min(1, cw - 1)
    blended = np.empty(cw)
    for i in range(h):
        y = min(max((i - centre) * inv_k, 0.0), ch - 1.0)
        lo = min(int(y), max(ch - 2, 0))
        ty = y - lo
        up, down = sink[lo], sink[min(lo + 1, ch - 1)]
        for c in range(cw):
            blended[c] = up[c] + (down[c] - up[c]) * ty
        gi = w0 + i
        depth_row, mask_row, gap_row = depth[gi], mask[gi], gap[gi]
        for j in range(w):
            gj = v0 + j
            if mask_row[gj]:
                continue
            a = col_lo[j]
            left = blended[a]
            u = left + (blended[a + hi_c] - left) * col_t[j]
            depth_row[gj] = max(u, -gap_row[gj], 0.0)
