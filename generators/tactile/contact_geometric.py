"""Geometric contact: the overlap, clipped and smoothed (Taxim-like). Cheap, no elastic solve.

The gel takes the shape of the overlap o = max(-g, 0) (mm). A pyramid of Gaussian blurs
(sigma, sigma/2, ...; ``smooth_sigma_mm`` and ``smooth_levels``) gives the rim a soft skirt, and after
each blur the overlap is restored where it is deeper than the blurred surface (D = max(blur(D), o)), as Taxim
(Si & Yuan, RA-L 2022) restores its contact region. The contact mask is the overlap (o > 0), so a sphere's
contact radius is the geometric sqrt(2 R d), 41 % above Hertz's sqrt(R d); use the elastic method when the
contact size matters.

Pressure and force: a Winkler bed p = k o with k = 2 E* / (pi a_eq), a_eq = sqrt(A / pi) the radius of a
disc with the overlap's area A. That k makes a flat circular punch exact (F = 2 a E* d) and a sphere 6 %
stiffer than Hertz (F = sqrt(2) E* sqrt(R) d^1.5 instead of 4/3 E* sqrt(R) d^1.5).

Work is confined to the overlap's bounding box grown by 4 sigma, so the cost scales with the contact size.
"""

from __future__ import annotations

from functools import lru_cache

import numba
import numpy as np

from univtac_data.schema.sensors import Material

from .contact import ContactConfig, ContactResult
from .sensor_model import SensorGrid

__all__ = ["solve_geometric"]


def solve_geometric(gap_mm: np.ndarray, grid: SensorGrid, material: Material, config: ContactConfig,
                    gap_box: tuple[slice, slice] | None = None) -> ContactResult:
    """Geometric contact of the gap field (ny, nx) mm on ``grid``; see the module docstring. ``gap_box``:
    (rows, cols) outside which the gap is positive, if known: the overlap is looked for only there."""
    if gap_box is None:
        mask = local = gap_mm < 0.0
        r_off = c_off = 0
    else:
        mask = np.zeros(grid.shape, dtype=bool)
        local = mask[gap_box]
        np.less(gap_mm[gap_box], 0.0, out=local)
        r_off, c_off = gap_box[0].indices(grid.shape[0])[0], gap_box[1].indices(grid.shape[1])[0]
    depth = np.zeros(grid.shape)
    pressure = np.zeros(grid.shape)
    rows = np.flatnonzero(local.any(axis=1))
    if rows.size == 0:
        return ContactResult(depth, pressure, mask, 0.0, box=(slice(0, 0), slice(0, 0)))
    cols = np.flatnonzero(local[rows[0] : rows[-1] + 1].any(axis=0)) + c_off
    rows += r_off
    sigma = config.smooth_sigma_mm
    grow_r = int(np.ceil(4.0 * sigma / grid.dy_mm)) + 1
    grow_c = int(np.ceil(4.0 * sigma / grid.dx_mm)) + 1
    win = (
        slice(max(rows[0] - grow_r, 0), min(rows[-1] + 1 + grow_r, grid.shape[0])),
        slice(max(cols[0] - grow_c, 0), min(cols[-1] + 1 + grow_c, grid.shape[1])),
    )
    # the overlap, zero off the contact (which lies inside the window), and in single precision for the
    # blur: depth is stored in whole micrometres, float32 resolves 1e-6 mm at 10 mm
    (r0, r1), (c0, c1) = (win[0].start, win[0].stop), (win[1].start, win[1].stop)
    overlap, overlap_single, cells = _overlap(np.ascontiguousarray(gap_mm), r0, r1, c0, c1)
    d = overlap_single
    for level in range(config.smooth_levels):
        s = sigma / (2.0**level)
        d = _separable_blur(d, _gaussian_weights(s / grid.dy_mm), _gaussian_weights(s / grid.dx_mm), overlap_single)
    area = cells * grid.cell_area_mm2
    e_star = material.youngs_modulus_mpa / (1.0 - material.poisson_ratio**2)
    stiffness = 2.0 * e_star / (np.pi * np.sqrt(area / np.pi))
    # the overlap itself stays exact (float64) in the depth
    load = _depth_and_pressure(d, overlap, stiffness, depth, pressure, r0, c0)
    return ContactResult(depth, pressure, mask, load * grid.cell_area_mm2, box=win)


# The kernels below take whole C-contiguous arrays and a window, and loop over row slices: the compiler
# vectorises a loop over a contiguous row, not one indexing a 2-D view element by element (9x slower).


@numba.njit(cache=True, nogil=True)
def _overlap(gap: np.ndarray, r0: int, r1: int, c0: int, c1: int) -> tuple[np.ndarray, np.ndarray, int]:  # pragma: no cover
    # max(-gap, 0) over the window in float64 and float32, and the number of cells in contact, in one pass
    exact, single = np.empty((r1 - r0, c1 - c0)), np.empty((r1 - r0, c1 - c0), np.float32)
    cells = 0
    for i in range(r1 - r0):
        row, exact_row, single_row = gap[r0 + i, c0:c1], exact[i], single[i]
        for j in range(c1 - c0):
            o = max(-row[j], 0.0)
            exact_row[j] = o
            single_row[j] = np.float32(o)
            cells += row[j] < 0.0
    return exact, single, cells


@numba.njit(cache=True, nogil=True)
def _depth_and_pressure(skirt: np.ndarray, overlap: np.ndarray, stiffness: float, depth: np.ndarray,
                        pressure: np.ndarray, r0: int, c0: int) -> float:  # pragma: no cover (compiled)
    # depth = max(skirt, overlap) and pressure = stiffness * overlap in the window at (r0, c0); returns the
    # summed pressure
    total = 0.0
    h, w = overlap.shape
    for i in range(h):
        skirt_row, overlap_row = skirt[i], overlap[i]
        depth_row, pressure_row = depth[r0 + i, c0 : c0 + w], pressure[r0 + i, c0 : c0 + w]
        for j in range(w):
            o = overlap_row[j]
            depth_row[j] = max(np.float64(skirt_row[j]), o)
            p = stiffness * o
            pressure_row[j] = p
            total += p
    return total


TRUNCATE_SIGMAS = 3.0  # the Gaussian is cut at 3 sigma (0.3 % of its peak)


def gaussian_blur(field: np.ndarray, sigma_rows_px: float, sigma_cols_px: float) -> np.ndarray:
    """(h, w) float32 field blurred by a Gaussian of the given sigmas (px), zero outside the field, cut at
    ``TRUNCATE_SIGMAS``: scipy's ``gaussian_filter(field, (sigma_rows_px, sigma_cols_px), mode="constant",
    truncate=3.0)`` to float32 rounding (tested), compiled: 3x faster on the skirt's windows."""
    return _separable_blur(np.ascontiguousarray(field, dtype=np.float32), _gaussian_weights(sigma_rows_px),
                           _gaussian_weights(sigma_cols_px), np.zeros((0, 0), np.float32))


@lru_cache(maxsize=32)
def _gaussian_weights(sigma_px: float) -> np.ndarray:
    """Normalised float32 weights of a Gaussian of ``sigma_px`` over offsets -r..r, r = int(3 sigma + 0.5)."""
    radius = int(TRUNCATE_SIGMAS * sigma_px + 0.5)
    offsets = np.arange(-radius, radius + 1)
    weights = np.exp(-0.5 / (sigma_px * sigma_px) * offsets.astype(np.float64) ** 2)
    weights = (weights / weights.sum()).astype(np.float32)
    weights.setflags(write=False)
    return weights


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _separable_blur(field: np.ndarray, row_weights: np.ndarray, col_weights: np.ndarray,
                    floor: np.ndarray) -> np.ndarray:  # pragma: no cover
    # along the rows' axis first, then along each row, every inner loop over one contiguous row view so that it
    # vectorises (scipy's correlate1d runs a scalar loop per output); the first pass writes into rows padded
    # with zeros, so the second needs no bounds. A non-empty ``floor`` (h, w) bounds the result from below,
    # max(blur(field), floor), in the same pass. (Folding the even weights, as scipy does, halves the products
    # but measured no faster: the loops are bound by loads and stores.)
    h, w = field.shape
    r_rows, r_cols = (row_weights.size - 1) // 2, (col_weights.size - 1) // 2
    n_rows, n_cols = row_weights.size, col_weights.size
    across = np.zeros((h, w + 2 * r_cols), np.float32)
    for i in range(h):
        row = across[i, r_cols : r_cols + w]
        k, k_end = max(0, r_rows - i), min(n_rows, h + r_rows - i)  # the taps whose source row is in the field
        while k + 4 <= k_end:  # four taps per pass over the row: a quarter of the loads and stores of the sum
            s0, s1, s2, s3 = field[i + k - r_rows], field[i + k + 1 - r_rows], field[i + k + 2 - r_rows], \
                field[i + k + 3 - r_rows]
            w0, w1, w2, w3 = row_weights[k], row_weights[k + 1], row_weights[k + 2], row_weights[k + 3]
            for j in range(w):
                total = row[j]   # added tap by tap, in order: the same sums as one tap per pass
                total += w0 * s0[j]
                total += w1 * s1[j]
                total += w2 * s2[j]
                total += w3 * s3[j]
                row[j] = total
            k += 4
        for k in range(k, k_end):
            weight, source_row = row_weights[k], field[i + k - r_rows]
            for j in range(w):
                row[j] += weight * source_row[j]
    out = np.zeros((h, w), np.float32)
    bounded = floor.shape[0] > 0
    for i in range(h):
        out_row, padded = out[i], across[i]
        k = 0
        while k + 4 <= n_cols:
            w0, w1, w2, w3 = col_weights[k], col_weights[k + 1], col_weights[k + 2], col_weights[k + 3]
            for j in range(w):
                total = out_row[j]
                total += w0 * padded[j + k]
                total += w1 * padded[j + k + 1]
                total += w2 * padded[j + k + 2]
                total += w3 * padded[j + k + 3]
                out_row[j] = total
            k += 4
        for k in range(k, n_cols):
            weight = col_weights[k]
            for j in range(w):
                out_row[j] += weight * padded[j + k]
        if bounded:
            floor_row = floor[i]
            for j in range(w):
                out_row[j] = max(out_row[j], floor_row[j])
    return out
