"""Elastic contact: a rigid object pressed into a linear-elastic gel (a bonded layer or a half-space),
non-negative pressure.

Unknown: the pressure p (MPa) on the solver grid. The gel surface moves toward the camera by
``u = K * p`` (mm; K = Love's rectangular-cell influence coefficients, :mod:`.kernels`, convolved by
zero-padded FFT). With the rigid gap g (mm, negative = overlap) the complementarity problem is

    r = g + u >= 0,  p >= 0,  r * p = 0     (r: remaining gap after deformation)

which is the minimum of the convex energy 1/2 p.K p + g.p over p >= 0. It is solved by the conjugate gradient
of Polonsky & Keer (Wear 231, 1999) in its displacement-driven form (the approach is in g, so there is no
force constraint and no mean-gap shift): CG on the current contact set, projection onto p >= 0, and
re-entry of cells that are overlapped but unloaded (PK's step that restarts the conjugacy). The CG is
preconditioned: the residual on the contact set is multiplied by the inverse of Strang's circulant
approximation of K over the window (``KernelSet.zz_preconditioner``) and restricted to the set again, which
takes about a third of the iterations (a cylinder across the GelSight Mini pad: 15 instead of 46). It starts
from Hertz's pressure shape (p ~ sqrt(overlap - half its deepest value)) or, if given and better, from the
previous frame's pressure, each scaled to the energy's least value along it.

Speed: the pressure can only be non-zero where g < 0, so the CG runs on a window around the overlap's bounding
box (plus two cells, or ``window_margin`` of its size), whose padded FFT is small and whose kernel spectrum is
cached. The iteration is compiled (numba; numpy.fft inside it is rocket-fft's) and convolves in single
precision, and K p follows the step (K p - alpha K t) plus a direct sum over the few cells the projection
changed, so most iterations cost one convolution and one window-sized transform pair (the preconditioner).
The displacement over the whole grid (the sink-in ring, which falls off like 1/r) is then one full-grid
convolution, also in single precision, or the iteration's own K p when the window is the grid. Outputs:
D = u (>= overlap, equal to it in contact), p, force = sum(p) * cell area, mask p > 0.

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

import numba
import numpy as np
import scipy.fft as sfft

from univtac_data.schema.sensors import Material

from .contact import ContactConfig, ContactResult
from .kernels import kernel_set
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
# window-sized multiply-add each, compiled) instead of by a full convolution (two transforms of the padded
# window): on windows of 32 x 32 to 120 x 160 cells 64 adds cost 0.4 to 0.5 of a convolution.
SPARSE_UPDATE_CELLS = 64


def pk_solve(
    gap_mm: np.ndarray, dx: float, dy: float, material: Material, tol: float, max_iter: int,
    p_init: np.ndarray | None = None, thickness_mm: float | None = None,
) -> tuple[np.ndarray, int, bool]:
    """Polonsky-Keer CG on a (sub)grid: pressure (ny, nx) MPa, iterations, converged. ``p_init`` (ny, nx)
    MPa: a starting pressure (used where it is positive and the gap overlaps). ``thickness_mm``: gel layer
    thickness (None: half-space)."""
    p, _, iterations, converged = _pk_window(gap_mm, dx, dy, material, tol, max_iter, p_init, thickness_mm)
    return p.astype(np.float64), iterations, converged


@numba.njit(cache=True, nogil=True)
def _start_terms(gap: np.ndarray, p: np.ndarray, u: np.ndarray) -> tuple[float, float]:  # pragma: no cover
    # -g.p and p.K p (u = K p) of a start p: the energy 1/2 p.K p + g.p along c p is least at
    # c = -g.p / p.K p, where it is -(g.p)^2 / (2 p.K p)
    along, curvature = 0.0, 0.0
    for i in range(gap.shape[0]):
        for j in range(gap.shape[1]):
            along -= float(gap[i, j]) * float(p[i, j])
            curvature += float(p[i, j]) * float(u[i, j])
    return along, curvature


def _pk_window(
    gap_mm: np.ndarray, dx: float, dy: float, material: Material, tol: float, max_iter: int,
    p_init: np.ndarray | None, thickness_mm: float | None,
) -> tuple[np.ndarray, np.ndarray, int, bool]:
    """:func:`pk_solve`, returning the float32 pressure (MPa) and the normal displacement K p (mm) over the
    (sub)grid, iterations and converged."""
    ks = kernel_set(gap_mm.shape, dx, dy, material.youngs_modulus_mpa, material.poisson_ratio, thickness_mm)
    gap_mm = np.ascontiguousarray(gap_mm, dtype=np.float32)
    overlap = np.maximum(-gap_mm, 0.0)
    # Hertz's pressure shape: for a sphere the contact is where the overlap exceeds half its deepest value, and
    # p ~ sqrt(overlap - half of it) there (sqrt(1 - r^2 / a^2)); the iteration scales it. A given start (the
    # previous frame's pressure) is tried too and the one that lowers the energy more is kept: a press that
    # deepens leaves the previous contact too small, which the Hertz shape can beat on a sphere.
    starts = [np.sqrt(np.maximum(overlap - 0.5 * float(overlap.max()), 0.0))]
    if p_init is not None and p_init.shape == gap_mm.shape and bool((p_init > 0.0).any()):
        starts.insert(0, np.where(overlap > 0.0, np.maximum(p_init, 0.0), 0.0))
    candidates = []
    for start in starts:
        p = np.ascontiguousarray(start, dtype=np.float32)
        u = _convolve_window(p, ks.zz_single, ks.pad_shape)
        along, curvature = _start_terms(gap_mm, p, u)
        gain = 0.0
        if curvature > 0.0 and along > 0.0:
            # scaled to the energy's least value along it; the larger the gain, the lower that value
            scale = np.float32(along / curvature)
            p *= scale
            u *= scale
            gain = along * along / curvature
        candidates.append((gain, p, u))
    _, p, u = max(candidates, key=lambda c: c[0])
    iterations, converged = _pk_iterate(gap_mm, p, u, ks.zz_single, ks.pad_shape, ks.zz_preconditioner,
                                        ks.zz_centred, float(tol), int(max_iter), SPARSE_UPDATE_CELLS)
    return p, u, int(iterations), bool(converged)


@numba.njit(cache=True, nogil=True)
def _convolve_window(field: np.ndarray, spectrum: np.ndarray, pad: tuple[int, int]) -> np.ndarray:  # pragma: no cover
    return _convolve_rows(field, spectrum, pad, 0, field.shape[0])


@numba.njit(cache=True, nogil=True)
def _convolve_rows(field: np.ndarray, spectrum: np.ndarray, pad: tuple[int, int], first: int,
                   stop: int) -> np.ndarray:  # pragma: no cover (compiled)
    # kernels.convolve compiled (numpy.fft in numba comes from rocket-fft; float32 in, float32 out), for a
    # ``field`` that is zero outside rows first:stop: the row transforms run on those rows only, the rest
    # and the padding's rows transform to zero
    ny, nx = field.shape
    rows = np.fft.rfft(field[first:stop], n=pad[1], axis=1)
    columns = np.zeros((pad[0], rows.shape[1]), np.complex64)
    columns[first:stop] = rows
    columns = np.fft.fft(columns, axis=0) * spectrum
    back = np.fft.ifft(columns, axis=0)[:ny]
    return np.ascontiguousarray(np.fft.irfft(back, n=pad[1], axis=1)[:, :nx])


@numba.njit(cache=True, nogil=True)
def _pk_iterate(gap: np.ndarray, p: np.ndarray, u: np.ndarray, spectrum: np.ndarray, pad: tuple[int, int],
                inverse: np.ndarray, centred: np.ndarray, tol: float, max_iter: int,
                sparse_cells: int) -> tuple[int, bool]:  # pragma: no cover (compiled)
    # The Polonsky-Keer iteration on the window, in place on ``p`` (float32), preconditioned: the residual on
    # the current contact set is multiplied by ``inverse`` (KernelSet.zz_preconditioner) over the window
    # and restricted to the set again, an approximate inverse of the operator there, so the conjugate
    # directions reach the tolerance in about a third of the iterations (15 instead of 46 on a cylinder across
    # the pad). K p (``u``) follows the step and a direct sum over the cells the projection or re-entry
    # changed, or is recomputed when they are many. Sums accumulate in float64. ``u`` = K p on entry and on
    # return. Returns the iterations and whether the tolerance was met.
    ny, nx = gap.shape
    t = np.zeros((ny, nx), np.float32)
    residual = np.zeros((ny, nx), np.float32)
    changed_rows = np.empty(sparse_cells, np.int64)
    changed_cols = np.empty(sparse_cells, np.int64)
    changed_by = np.empty(sparse_cells, np.float32)
    g_old, delta = 1.0, 0.0
    for it in range(1, max_iter + 1):
        for i in range(ny):
            for j in range(nx):
                residual[i, j] = u[i, j] + gap[i, j] if p[i, j] > 0.0 else np.float32(0.0)
        z = np.fft.irfft2(np.fft.rfft2(residual) * inverse, s=(ny, nx))
        g_now = 0.0
        for i in range(ny):
            for j in range(nx):
                if p[i, j] > 0.0:
                    g_now += float(residual[i, j]) * float(z[i, j])
        beta = delta * g_now / g_old
        for i in range(ny):
            for j in range(nx):
                t[i, j] = np.float32(z[i, j] + beta * t[i, j]) if p[i, j] > 0.0 else np.float32(0.0)
        g_old = g_now if g_now > 0.0 else 1.0
        tau = _convolve_window(t, spectrum, pad)
        num, den = 0.0, 0.0
        for i in range(ny):
            for j in range(nx):
                if p[i, j] > 0.0:
                    num += float(residual[i, j]) * float(t[i, j])
                    den += float(tau[i, j]) * float(t[i, j])
        alpha = num / den if den > 0.0 else 0.0
        # step along t, project onto p >= 0, and let overlapped unloaded cells re-enter (PK's restart)
        n_changed, reentered, total, moved = 0, False, 0.0, 0.0
        for i in range(ny):
            for j in range(nx):
                old = p[i, j]
                stepped = np.float32(old - alpha * t[i, j])
                new = stepped if stepped > 0.0 else np.float32(0.0)
                r = u[i, j] + gap[i, j]
                if new == 0.0 and r < 0.0:
                    new = np.float32(-alpha * r)
                    reentered = True
                if new != stepped:
                    if n_changed < sparse_cells:
                        changed_rows[n_changed], changed_cols[n_changed] = i, j
                        changed_by[n_changed] = new - stepped
                    n_changed += 1
                p[i, j] = new
                total += float(new)
                moved += abs(float(new) - float(old))
        delta = 0.0 if reentered else 1.0
        if n_changed <= sparse_cells:
            step = np.float32(alpha)
            for i in range(ny):
                for j in range(nx):
                    u[i, j] -= step * tau[i, j]
            for k in range(n_changed):
                r0, c0, v = ny - 1 - changed_rows[k], nx - 1 - changed_cols[k], changed_by[k]
                for i in range(ny):
                    for j in range(nx):
                        u[i, j] += v * centred[r0 + i, c0 + j]
        else:
            u[:] = _convolve_window(p, spectrum, pad)
        if total == 0.0 or moved <= tol * total:
            return it, True
    return max_iter, False


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
    p_win, u_win, iterations, converged = _pk_window(gap_mm[window], dx, dy, material, config.tol, config.max_iter,
                                                     start, thickness_mm)
    pressure = np.zeros(grid.shape, np.float32)
    pressure[window] = p_win
    if u_win.shape == grid.shape:
        # the window is the grid: the iteration's K p is the surface's displacement already
        depth = np.maximum(u_win, 0.0).astype(np.float64)
    else:
        full = kernel_set(grid.shape, dx, dy, material.youngs_modulus_mpa, material.poisson_ratio, thickness_mm)
        # single precision, as in the window: the depth is stored in whole micrometres, float32 resolves 1e-6 mm
        depth = np.maximum(_convolve_rows(pressure, full.zz_single, full.pad_shape, window[0].start,
                                          window[0].stop), 0.0).astype(np.float64)
    pressure = pressure.astype(np.float64)
    # in contact the surface follows the object exactly (the CG leaves a residual of order tol)
    mask = pressure > 0.0
    depth[mask] = -gap_mm[mask]
    return ContactResult(
        depth_mm=depth, pressure_mpa=pressure, contact_mask=mask,
        normal_force_n=float(pressure.sum() * dx * dy), iterations=iterations, converged=converged,
    )
