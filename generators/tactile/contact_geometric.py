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
    depth = np.zeros(grid.shape)
    pressure = np.zeros(grid.shape)
    mask = np.zeros(grid.shape, dtype=bool)
    gap = np.ascontiguousarray(gap_mm, dtype=np.float64)
    (s0, s1), (t0, t1) = ((0, h), (0, w)) if gap_box is None else (gap_box[0].indices(h)[:2], gap_box[1].indices(w)[:2])
    runs = _overlap_runs(gap, s0, s1, t0, t1)
    if runs.shape[1] == 0:
        return ContactResult(depth, pressure, mask, 0.0, box=(slice(0, 0), slice(0, 0)))
    piece, deepest = _run_pieces(runs)
    stats = _contact_pass(gap, runs, piece, deepest, config.contact_fraction, depth, pressure, mask)
    count, sum_h, sum_root_h, rim_sum, rim_count, rim_pixels = stats
    r0, r1 = int(runs[0, 0]), int(runs[0, -1]) + 1
    c0, c1 = int(runs[1].min()), int(runs[2].max())
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
    _fill(gap, win[0].start, win[0].stop, win[1].start, win[1].stop, runs, piece, rim_pixels, pressure_scale,
          radius, rim, blend, sphere, punch, grid.dy_mm, grid.dx_mm, block, depth, pressure, mask)
    return ContactResult(depth, pressure, mask, float(force.sum()), box=win)


@numba.njit(cache=True, nogil=True)
def _overlap_runs(gap: np.ndarray, s0: int, s1: int, t0: int, t1: int) -> np.ndarray:  # pragma: no cover
    # the overlap (gap < 0) in rows s0:s1, cols t0:t1 as runs along the rows, in raster order: (3, n) int64 of
    # image row, first column and the column past the last
    out = np.empty((3, (s1 - s0) * ((t1 - t0 + 1) // 2)), np.int64)
    n = 0
    for i in range(s0, s1):
        row = gap[i]
        j = t0
        while j < t1:
            if row[j] >= 0.0:
                j += 1
                continue
            start = j
            while j < t1 and row[j] < 0.0:
                j += 1
            out[0, n], out[1, n], out[2, n] = i, start, j
            n += 1
    return out[:, :n].copy()  # a C array whatever n: a slice that happens to be contiguous would recompile


@numba.njit(cache=True, nogil=True)
def _run_pieces(runs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover
    # 8-connected pieces of the runs: each run's piece (n,) int32, numbered in the raster order of each piece's
    # first pixel (union-find, each set's root its first run), and a zeroed array for each piece's deepest
    # overlap (_contact_pass fills it). Runs of consecutive rows touch when their column spans overlap or meet
    # at a corner.
    n = runs.shape[1]
    parent = np.arange(n)
    lo = 0  # first run of the previous row
    i = 0
    while i < n:
        row = runs[0, i]
        end = i
        while end < n and runs[0, end] == row:
            end += 1
        prev_lo, prev_hi = lo, i
        if prev_hi > prev_lo and runs[0, prev_lo] != row - 1:
            prev_lo = prev_hi  # the previous run row is not adjacent
        a = prev_lo
        for b in range(i, end):
            while a < prev_hi and runs[2, a] < runs[1, b]:  # ends left of b's first column - 1
                a += 1
            c = a
            while c < prev_hi and runs[1, c] <= runs[2, b]:
                ra, rb = c, b
                while parent[ra] != ra:
                    ra = parent[ra]
                while parent[rb] != rb:
                    rb = parent[rb]
                if ra < rb:
                    parent[rb] = ra
                elif rb < ra:
                    parent[ra] = rb
                c += 1
        lo, i = i, end
    piece = np.empty(n, np.int32)
    count = 0
    for k in range(n):
        r = k
        while parent[r] != r:
            r = parent[r]
        parent[k] = r
        if r == k:
            piece[k] = count
            count += 1
        else:
            piece[k] = piece[r]
    return piece, np.zeros(count)


@numba.njit(cache=True, nogil=True)
def _contact_pass(gap: np.ndarray, runs: np.ndarray, piece: np.ndarray, deepest: np.ndarray, fraction: float,
                  depth: np.ndarray, pressure: np.ndarray, mask: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover
    # fills ``deepest`` (each piece's deepest overlap, mm), then per piece: contact cells (o > fraction d), sum
    # of h = o - d / 2 and of sqrt(h) over them, and the sum and count of the gel's level on the contact's rim
    # (each side of a contact cell that faces a cell out of contact). Contact cells get the mask, the overlap as
    # depth and sqrt(h) as pressure (_fill scales it). Also the contact's rim pixels (2, k) in raster order:
    # contact pixels with a neighbour inside the image out of contact, and their piece (3, k).
    n = runs.shape[1]
    for r in range(n):
        i, k = runs[0, r], piece[r]
        row = gap[i]
        low = deepest[k]
        for j in range(runs[1, r], runs[2, r]):
            low = max(low, -row[j])
        deepest[k] = low
    m = deepest.size
    count, sum_h, sum_root, rim_sum, rim_count = np.zeros(m), np.zeros(m), np.zeros(m), np.zeros(m), np.zeros(m)
    h, w = gap.shape
    total = 0
    for r in range(n):
        total += runs[2, r] - runs[1, r]
    rim_pixels = np.empty((3, total), np.int32)
    n_rim = 0
    for r in range(n):
        i, k = runs[0, r], piece[r]
        level = fraction * deepest[k]
        half = 0.5 * deepest[k]
        # the piece's sums in locals for the run (a run is one piece's): the same additions in the same order
        # as on the arrays, without a store and a reload a pixel
        n_cells, s_h, s_root, s_rim, n_rim_sides = count[k], sum_h[k], sum_root[k], rim_sum[k], rim_count[k]
        row, mask_row, depth_row, pressure_row = gap[i], mask[i], depth[i], pressure[i]
        has_up, has_down = i > 0, i + 1 < h
        up_row = gap[i - 1] if has_up else row
        down_row = gap[i + 1] if has_down else row
        for j in range(runs[1, r], runs[2, r]):
            o = -row[j]
            if o <= level:
                continue
            n_cells += 1.0
            above = o - half
            root = 0.0
            if above > 0.0:
                s_h += above
                root = np.sqrt(above)
                s_root += root
            mask_row[j] = True
            depth_row[j] = o
            pressure_row[j] = root
            # the rim's level, across each side out of contact (up, down, left, right): where the object goes on
            # beyond the contact (its overlap there is positive) the surface crosses fraction d between the two
            # pixels; where it ends (a sharp edge, as a punch's, or the image's border), the gel is held at this
            # pixel's overlap. A 4-neighbour in overlap belongs to this pixel's piece.
            # Interior pixels (every side in the image and in contact; a side out of the image reads -inf) are
            # the common case: one test for them.
            left_o = -row[j - 1] if j > 0 else -np.inf
            right_o = -row[j + 1] if j + 1 < w else -np.inf
            up_o = -up_row[j] if has_up else -np.inf
            down_o = -down_row[j] if has_down else -np.inf
            if min(min(up_o, down_o), min(left_o, right_o)) > level:
                continue
            on_rim = False
            for side in range(4):
                if side == 0:
                    inside, outside_o = has_up, up_o
                elif side == 1:
                    inside, outside_o = has_down, down_o
                elif side == 2:
                    inside, outside_o = j > 0, left_o
                else:
                    inside, outside_o = j + 1 < w, right_o
                if inside:
                    if outside_o > level:
                        continue
                    on_rim = True
                    s_rim += level if outside_o > 0.0 else o
                else:
                    s_rim += o
                n_rim_sides += 1.0
            if on_rim:
                rim_pixels[0, n_rim], rim_pixels[1, n_rim], rim_pixels[2, n_rim] = i, j, k
                n_rim += 1
        count[k], sum_h[k], sum_root[k], rim_sum[k], rim_count[k] = n_cells, s_h, s_root, s_rim, n_rim_sides
    return count, sum_h, sum_root, rim_sum, rim_count, rim_pixels[:, :n_rim].copy()  # C: see _overlap_runs


@numba.njit(cache=True, nogil=True, inline="always")
def _take(near_r: np.ndarray, near_c: np.ndarray, near_piece: np.ndarray, dist2: np.ndarray, i: int, j: int, p: int,
          q: int, k: int, centre: float, dy: float, dx: float) -> None:  # pragma: no cover (compiled)
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
        near_piece[i, j] = near_piece[p, q]
        dist2[i, j] = d


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _fill(gap: np.ndarray, w0: int, w1: int, v0: int, v1: int, runs: np.ndarray, run_piece: np.ndarray,
          rim_pixels: np.ndarray, pressure_scale: np.ndarray, radius: np.ndarray, rim: np.ndarray,
          blend: np.ndarray, sphere: np.ndarray, punch: np.ndarray, dy: float, dx: float, k: int,
          depth: np.ndarray, pressure: np.ndarray, mask: np.ndarray) -> None:  # pragma: no cover (compiled)
    # rows w0:w1, cols v0:v1 of the image. Contact cells (already masked, with the overlap as depth) get the
    # Hertz-shaped pressure. The sink-in is found on k x k blocks of the window: each block takes the piece of
    # the nearest block holding contact (propagated in raster passes, as in a vector distance transform) and that
    # piece's profile at the distance between the two blocks' centres less half a block (the rim lies inside the
    # contact block); blocks holding contact take the rim's overlap. Each pixel off the contact then reads the
    # blocks bilinearly, never less than its overlap. The sink-in varies over a contact radius, which spans 8
    # blocks or more, so this costs a k^2-th of a per-pixel transform and changes the depth by well under a
    # micrometre.
    h, w = w1 - w0, v1 - v0
    ch, cw = -(-h // k), -(-w // k)
    centre = 0.5 * (k - 1)
    near_r = np.full((ch, cw), -1, np.int32)  # nearest rim pixel: window row, col
    near_c = np.full((ch, cw), -1, np.int32)
    near_piece = np.full((ch, cw), -1, np.int32)  # the piece of that rim pixel
    piece = np.full((ch, cw), -1, np.int32)  # the piece of a block holding contact
    dist2 = np.full((ch, cw), np.inf)
    for r in range(runs.shape[1]):
        gi, p = runs[0, r], run_piece[r]
        scale = pressure_scale[p]
        mask_row, pressure_row, piece_row = mask[gi], pressure[gi], piece[(gi - w0) // k]
        # block column and the pixel column where the next block begins: no division a pixel
        b = (runs[1, r] - v0) // k
        next_block = v0 + (b + 1) * k
        for gj in range(runs[1, r], runs[2, r]):
            if gj == next_block:
                b += 1
                next_block += k
            if mask_row[gj]:
                pressure_row[gj] *= scale
                piece_row[b] = p
    for r in range(rim_pixels.shape[1]):  # rim pixels seed their blocks: each block keeps the one nearest its centre
        gi, gj = rim_pixels[0, r], rim_pixels[1, r]
        a, b = (gi - w0) // k, (gj - v0) // k
        ea, eb = (a * k + centre - (gi - w0)) * dy, (b * k + centre - (gj - v0)) * dx
        d = ea * ea + eb * eb
        if d < dist2[a, b]:
            near_r[a, b], near_c[a, b], near_piece[a, b], dist2[a, b] = gi - w0, gj - v0, rim_pixels[2, r], d
    for i in range(ch):  # down the blocks: from the row above, then along the row both ways
        for j in range(cw):
            _take(near_r, near_c, near_piece, dist2, i, j, i - 1, j - 1, k, centre, dy, dx)
            _take(near_r, near_c, near_piece, dist2, i, j, i - 1, j, k, centre, dy, dx)
            _take(near_r, near_c, near_piece, dist2, i, j, i - 1, j + 1, k, centre, dy, dx)
            _take(near_r, near_c, near_piece, dist2, i, j, i, j - 1, k, centre, dy, dx)
        for j in range(cw - 2, -1, -1):
            _take(near_r, near_c, near_piece, dist2, i, j, i, j + 1, k, centre, dy, dx)
    for i in range(ch - 1, -1, -1):  # and up
        for j in range(cw - 1, -1, -1):
            _take(near_r, near_c, near_piece, dist2, i, j, i + 1, j + 1, k, centre, dy, dx)
            _take(near_r, near_c, near_piece, dist2, i, j, i + 1, j, k, centre, dy, dx)
            _take(near_r, near_c, near_piece, dist2, i, j, i + 1, j - 1, k, centre, dy, dx)
            _take(near_r, near_c, near_piece, dist2, i, j, i, j + 1, k, centre, dy, dx)
        for j in range(1, cw):
            _take(near_r, near_c, near_piece, dist2, i, j, i, j - 1, k, centre, dy, dx)
    sink = np.zeros((ch, cw))
    half_pixel = 0.5 * min(dx, dy)  # from a rim pixel's centre to the rim
    last = sphere.size - 2
    for i in range(ch):
        for j in range(cw):
            if near_r[i, j] < 0:
                continue
            p = near_piece[i, j]
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
        depth_row, mask_row, gap_row = depth[gi, v0:v1], mask[gi, v0:v1], gap[gi, v0:v1]
        for j in range(w):
            a = col_lo[j]
            left = blended[a]
            u = max(left + (blended[a + hi_c] - left) * col_t[j], -gap_row[j], 0.0)
            depth_row[j] = depth_row[j] if mask_row[j] else u
