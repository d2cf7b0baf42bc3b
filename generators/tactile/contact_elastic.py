"""Elastic contact: a rigid object pressed into a linear-elastic gel (a bonded layer or a half-space),
non-negative pressure.

Unknown: the pressure p (MPa) on the solver grid. The gel surface moves toward the camera by
``u = K * p`` (mm; K = Love's rectangular-cell influence coefficients, :mod:`.kernels`, convolved by
zero-padded FFT). With the rigid gap g (mm, negative = overlap) the complementarity problem is

    r = g + u >= 0,  p >= 0,  r * p = 0     (r: remaining gap after deformation)

which is the minimum of the convex energy 1/2 p.K p + g.p over p >= 0. It is solved by the conjugate gradient
of Polonsky & Keer (Wear 231, 1999) in its displacement-driven form (the approach is in g, so there is no
force constraint and no mean-gap shift): CG on the current contact set, projection onto p >= 0, and
re-entry of cells that are overlapped but unloaded (PK's step that restarts the conjugacy).

Speed: the pressure can only be non-zero where g < 0, so the CG runs on a window around the overlap's bounding
box (plus two cells, or ``window_margin`` of its size), whose padded FFT is small and whose kernel spectrum is
cached. The window's convolutions run in single precision, and K p follows the step (K p - alpha K t) plus a
direct sum over the few cells the projection changed, so most iterations cost one convolution, not two. The
displacement over the whole grid (the sink-in ring, which falls off like 1/r) is then one full-grid
convolution, also in single precision. Outputs: D = u (>= overlap, equal to it in contact), p, force = sum(p) * cell area, mask p > 0.

Finite gel thickness: with ``thickness_mm`` the normal influence coefficients are those of a layer of that
thickness bonded to a rigid backing (:mod:`.kernels`): stiffer than the half-space once the contact radius
nears the thickness (2 to 4 mm here, contact radii of 1 to 2 mm at the grasp depth), and its sink-in dies out
within a few thicknesses instead of falling off like 1/r. Without it (``ContactConfig.gel = "half_space"``)
the solver is the half-space one, exact against its closed forms (Hertz, flat punch), which the tests keep.
The layer's pile-up around the contact (the surface rising toward the object: 3 to 9 % of the press beside
a 5 mm sphere, up to 29 % beside a cylinder across the pad; benchmarks/gel_models.py) is clipped: D is an
indentation, >= 0.
"""

from __future__ import annotations

import numpy as np
import scipy.fft as sfft

from univtac_data.schema.sensors import Material

from .contact import ContactConfig, ContactResult
from .kernels import convolve, kernel_set
from .sensor_model import SensorGrid

__all__ = ["overlap_window", "pk_solve", "solve_elastic"]


def overlap_window(gap_mm: np.ndarray, margin: float) -> tuple[slice, slice] | None:
    """Rows/columns slice pair around the overlap (g < 0), grown by ``margin`` of its size per side (at
    least 2 cells), rounded to FFT-friendly sizes so kernel spectra are reused; ``None`` when no overlap."""
    rows = np.flatnonzero((gap_mm < 0.0).any(axis=1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero((gap_mm[rows[0] : rows[-1] + 1] < 0.0).any(axis=0))
    out = []
    for lo, hi, n in ((rows[0], rows[-1] + 1, gap_mm.shape[0]), (cols[0], cols[-1] + 1, gap_mm.shape[1])):
        grow = max(2, int(np.ceil(margin * (hi - lo))))
        size = min(n, sfft.next_fast_len(max(8, hi - lo + 2 * grow)))
        size = min(n, -(-size // 8) * 8)
        start = int(np.clip((lo + hi - size) // 2, 0, n - size))
        out.append(slice(start, start + size))
    return out[0], out[1]


# Cells whose pressure the projection or re-entry changed, up to which K p is updated cell by cell (one
# window-sized add each) instead of by a full convolution (two transforms of the padded window).
SPARSE_UPDATE_CELLS = 16


def pk_solve(
    gap_mm: np.ndarray, dx: float, dy: float, material: Material, tol: float, max_iter: int,
    p_init: np.ndarray | None = None, thickness_mm: float | None = None,
) -> tuple[np.ndarray, int, bool]:
    """Polonsky-Keer CG on a (sub)grid: pressure (ny, nx) MPa, iterations, converged. ``p_init`` (ny, nx)
    MPa: a starting pressure (used where it is positive and the gap overlaps). ``thickness_mm``: gel layer
    thickness (None: half-space)."""
    ks = kernel_set(gap_mm.shape, dx, dy, material.youngs_modulus_mpa, material.poisson_ratio, thickness_mm)
    pad, spec = ks.pad_shape, ks.zz_single
    gap_mm = gap_mm.astype(np.float32)
    overlap = np.maximum(-gap_mm, 0.0)
    if p_init is not None and p_init.shape == gap_mm.shape and bool((p_init > 0.0).any()):
        p = np.where(overlap > 0.0, np.maximum(p_init, 0.0), 0.0)
    else:
        # start from the pressure of a Winkler bed matched to a flat punch of the overlap's size
        area = np.count_nonzero(overlap) * dx * dy
        p = overlap * np.float32(2.0 * ks.e_star / (np.pi * np.sqrt(area / np.pi)))
    p = p.astype(np.float32)
    t = np.zeros_like(p)
    g_old, delta = 1.0, 0.0
    converged = False
    it = 0
    u = convolve(p, spec, pad)  # K * p, kept up to date without a convolution when the step is not clipped
    for it in range(1, max_iter + 1):
        r = u + gap_mm
        active = p > 0.0
        g_now = float(np.dot(r[active], r[active]))
        t = np.where(active, r + (delta * g_now / g_old) * t, 0.0)
        g_old = g_now if g_now > 0.0 else 1.0
        tau = convolve(t, spec, pad)
        denom = float(np.dot(tau[active], t[active]))
        alpha = float(np.dot(r[active], t[active])) / denom if denom > 0.0 else 0.0
        p_prev = p
        stepped = p - alpha * t
        p = np.maximum(stepped, 0.0)
        reenter = (p == 0.0) & (r < 0.0)
        if reenter.any():
            p[reenter] -= alpha * r[reenter]
            delta = 0.0
        else:
            delta = 1.0
        # K p for the new p: linear in the step, plus the few cells the projection or re-entry changed
        changed = np.flatnonzero(p != stepped)
        if changed.size <= SPARSE_UPDATE_CELLS:
            u -= alpha * tau
            rows, cols = np.unravel_index(changed, p.shape)
            ks.add_cells(u, rows, cols, p[rows, cols] - stepped[rows, cols])
        else:
            u = convolve(p, spec, pad)
        total = float(p.sum())
        if total > 0.0 and float(np.abs(p - p_prev).sum()) <= tol * total:
            converged = True
            break
        if total == 0.0:
            converged = True
            break
    return p.astype(np.float64), it, converged


def solve_elastic(gap_mm: np.ndarray, grid: SensorGrid, material: Material, config: ContactConfig,
                  initial_pressure_mpa: np.ndarray | None = None, thickness_mm: float | None = None) -> ContactResult:
    """Elastic contact of the gap field (ny, nx) mm on ``grid``: a bonded gel layer ``thickness_mm`` thick, or
    the half-space (None); see the module docstring. ``initial_pressure_mpa`` (ny, nx) MPa on ``grid`` starts
    the solve (e.g. the previous frame's)."""
    window = overlap_window(gap_mm, config.window_margin)
    if window is None:
        zeros = np.zeros(grid.shape)
        return ContactResult(zeros, zeros.copy(), np.zeros(grid.shape, dtype=bool), 0.0)
    dx, dy = grid.dx_mm, grid.dy_mm
    start = None
    if initial_pressure_mpa is not None and initial_pressure_mpa.shape == gap_mm.shape:
        start = initial_pressure_mpa[window]
    p_win, iterations, converged = pk_solve(gap_mm[window], dx, dy, material, config.tol, config.max_iter, start,
                                            thickness_mm)
    pressure = np.zeros(grid.shape)
    pressure[window] = p_win
    full = kernel_set(grid.shape, dx, dy, material.youngs_modulus_mpa, material.poisson_ratio, thickness_mm)
    # single precision, as in the window: the depth is stored in whole micrometres, float32 resolves 1e-6 mm
    depth = np.maximum(convolve(pressure.astype(np.float32), full.zz_single, full.pad_shape,
                                (window[0].start, window[0].stop)), 0.0).astype(np.float64)
    # in contact the surface follows the object exactly (the CG leaves a residual of order tol)
    mask = pressure > 0.0
    depth[mask] = -gap_mm[mask]
    return ContactResult(
        depth_mm=depth, pressure_mpa=pressure, contact_mask=mask,
        normal_force_n=float(pressure.sum() * dx * dy), iterations=iterations, converged=converged,
    )
