"""Shear: tangential tractions with stick and slip, in-plane surface displacement, and the slip state.

Inputs per frame: the normal pressure p (MPa) and contact mask on a grid, the object's tangential
displacement ``tangential_mm`` (dx, dy) in the pad frame and its twist ``twist_rad`` about the pad normal
(+z), and the :class:`ContactState` carried from the previous frame.

1. Reference. At contact onset the gel is unstrained: the state records the object's displacement and twist
   then (``reference_mm``, ``reference_twist_rad``); the elastic tangential load comes from
   ``s = tangential_mm - reference_mm`` and ``theta = twist_rad - reference_twist_rad``. With ``state=None``
   the reference is zero: the inputs are already "since contact onset".
2. Stuck tractions. Cells in contact move with the object, ``u_t(x) = s + theta z x (x - c)`` (c: the
   pressure centroid). The tractions q (MPa, 2 components) that produce u_t on the contact set are found by
   conjugate gradient with the Cerruti influence coefficients (:mod:`.kernels`; symmetric positive definite):
   as a dense matrix over the contact's cells when there are at most ``DENSE_MAX_CELLS``, else by FFT
   convolution over the contact's window.
3. Gross slip. If the total tangential force exceeds mu * P (or the torque exceeds mu * sum(p |x - c|) dA),
   by more than ``SLIDE_TOLERANCE``, the object slides: the load is scaled back to the friction limit and the
   reference follows the object, so the excess displacement is accumulated in ``slip_mm`` (mm; a twist slide
   counts as the mean contact radius times the angle). While stuck, ``slip_mm`` stays 0; it resets when contact ends.
4. Partial slip (Cattaneo-Mindlin). Cells whose stuck traction exceeds mu * p slide: their traction is set to
   mu * p along the stuck direction and the stick region is solved again (a few rounds).
5. In-plane displacement. ``u = K_t * q`` plus the radial term of the normal load
   (``-(1 - 2 nu) / (4 pi G)`` Boussinesq, zero at nu = 0.5), both by FFT convolution over the grid.

With ``thickness_mm`` (``ContactConfig.gel = "layer"``) the coefficients of steps 2 and 5 are those of a gel
layer bonded to its backing (:mod:`.kernels`): stiffer in shear, and a pressed layer pushes its surface
outward where the half-space draws it in.

Simplification: one reference per contact (not per cell), so partial-slip history is not carried between
frames; the slip state is that of the whole contact. Tangential loads do not move the surface along the normal.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field
from functools import lru_cache

import numba
import numpy as np
import scipy.fft as sfft

from univtac_data.schema.sensors import Material

from .kernels import KernelSet, kernel_set, padded_inverse, padded_spectrum, strang_eigenvalues

__all__ = ["ContactState", "ShearResult", "solve_shear"]


@dataclass(frozen=True)
class ContactState:
    """Stick/slip history of one pad, passed from frame to frame (``TactileFrame.state`` -> next call).

    ``in_contact``: the previous frame had contact. ``reference_mm``: object tangential displacement (x, y) mm
    at which the gel is unstrained. ``reference_twist_rad``: likewise for the twist, rad.
    ``slip_mm``: sliding accumulated since contact onset, mm. ``pressure_mpa``: the previous frame's normal
    pressure on the solver grid (ny, nx) MPa, or None: the elastic solve starts from it (consecutive frames
    differ little, so the conjugate gradient needs a few iterations instead of tens).
    ``slide_solution``: the previous frame's fully stuck tractions per mm of slide, (2, ny, nx) MPa/mm, for
    a slide along ``slide_direction`` (unit (x, y)); ``twist_solution``: likewise per rad of twist,
    (2, ny, nx) MPa/rad. Or None. The tangential solves start from them: a held contact changes little
    between frames, and a cold start costs about three times the iterations. ``unit_basis``: the stuck
    solutions per unit load on the previous frame's contact cells (:class:`UnitBasis`), or None: while the
    cells stay the same, this frame's stuck solutions are their combinations, with no solve.
    """

    in_contact: bool = False
    reference_mm: tuple[float, float] = (0.0, 0.0)
    reference_twist_rad: float = 0.0
    slip_mm: float = 0.0
    pressure_mpa: np.ndarray | None = field(default=None, compare=False, repr=False)
    slide_solution: np.ndarray | None = field(default=None, compare=False, repr=False)
    slide_direction: tuple[float, float] = (1.0, 0.0)
    twist_solution: np.ndarray | None = field(default=None, compare=False, repr=False)
    unit_basis: UnitBasis | None = field(default=None, compare=False, repr=False)


@dataclass(frozen=True)
class UnitBasis:
    """Fully stuck tractions per unit load on one set of contact cells (``rows``, ``cols``), flattened (2 m,)
    (x components, then y). The stuck tractions are linear in the load on fixed cells, so any slide and any
    twist about any centre is a combination of ``along`` (per mm of slide along the unit ``direction``),
    ``across`` (per mm along ``direction`` turned +90 deg) and ``twist`` (per rad of twist about
    ``centre_mm``), each MPa per unit, or None until a frame needed it."""

    rows: np.ndarray
    cols: np.ndarray
    direction: tuple[float, float] = (1.0, 0.0)
    along: np.ndarray | None = None
    across: np.ndarray | None = None
    twist: np.ndarray | None = None
    centre_mm: tuple[float, float] = (0.0, 0.0)

    def holds(self, rows: np.ndarray, cols: np.ndarray) -> bool:
        """Whether this basis is for the cells (``rows``, ``cols``)."""
        return np.array_equal(self.rows, rows) and np.array_equal(self.cols, cols)

    def slide(self, nx: float, ny: float) -> np.ndarray | None:
        """The stuck tractions per mm of slide along the unit (``nx``, ``ny``), or None if a part is missing."""
        dx, dy = self.direction
        cos, sin = dx * nx + dy * ny, dx * ny - dy * nx
        if self.along is None or (sin != 0.0 and self.across is None):
            return None
        return cos * self.along if sin == 0.0 else cos * self.along + sin * self.across

    def twist_about(self, cx: float, cy: float) -> np.ndarray | None:
        """The stuck tractions per rad of twist about (``cx``, ``cy``) mm, or None if a part is missing: the
        twist's load about another centre differs by a uniform slide (cy - cy0, -(cx - cx0)) per rad."""
        if self.twist is None:
            return None
        shift_x, shift_y = cy - self.centre_mm[1], -(cx - self.centre_mm[0])
        size = float(np.hypot(shift_x, shift_y))
        if size == 0.0:
            return self.twist
        shifted = self.slide(shift_x / size, shift_y / size)
        return None if shifted is None else self.twist + size * shifted


@dataclass(frozen=True)
class ShearResult:
    """``traction_mpa``: (2, ny, nx) tangential traction on the gel, MPa. ``displacement_mm``: (2, ny, nx)
    in-plane surface displacement (x, y), mm. ``shear_force_n``: (2,) total tangential force on the gel along
    pad x, y, N. ``slip_mm``: accumulated slip, mm. ``state``: the state to pass to the next frame."""

    traction_mpa: np.ndarray
    displacement_mm: np.ndarray
    shear_force_n: np.ndarray
    slip_mm: float
    state: ContactState


def _window(rows: np.ndarray, cols: np.ndarray, shape: tuple[int, int], grow: int) -> tuple[slice, slice]:
    """The window of the cells (``rows``, ``cols``) of a (ny, nx) grid, grown by ``grow`` cells a side (within
    the grid), each side a length the FFT is fast at."""
    return _window_of_span(int(rows.min()), int(rows.max()), int(cols.min()), int(cols.max()), shape, grow)


@lru_cache(maxsize=256)
def _window_of_span(first_row: int, last_row: int, first_col: int, last_col: int, shape: tuple[int, int],
                    grow: int) -> tuple[slice, slice]:
    # cached: a held contact keeps its span for many frames, and the scalar arithmetic below costs tens of us
    out = []
    for first, last, n in ((first_row, last_row, shape[0]), (first_col, last_col, shape[1])):
        size = min(n, sfft.next_fast_len(last + 1 - first + 2 * grow))
        start = min(max((first + last + 1 - size) // 2, 0), n - size)
        out.append(slice(start, start + size))
    return out[0], out[1]


class _Preconditioned:
    """The preconditioner both cell operators share (so both solve with the same iterates): ``circulant_inverse``
    over the window around the contact's cells."""

    def _set_preconditioner(self, rows: np.ndarray, cols: np.ndarray, grid_shape: tuple[int, int], dx: float,
                            dy: float, material: Material, thickness_mm: float | None) -> tuple[slice, slice]:
        win = _window(rows, cols, grid_shape, 2)
        self.shape = (win[0].stop - win[0].start, win[1].stop - win[1].start)
        self.rows, self.cols = rows - win[0].start, cols - win[1].start
        self.inverse = circulant_inverse(self.shape, dx, dy, material.youngs_modulus_mpa, material.poisson_ratio,
                                         thickness_mm)
        return win

    def precondition(self, r: np.ndarray) -> np.ndarray:
        """The preconditioner applied to a residual ``r`` (2, m) of the contact's cells."""
        return _precondition_cells(self.inverse, self.shape, self.rows, self.cols, r.reshape(-1)).reshape(2, -1)


# Contacts of at most this many cells get the dense operator below; larger ones the FFT operator. Both run in
# compiled code; on the task recordings (Lift Can, Grasp Classify) 300 was fastest of 100-400: below it a
# matrix-vector product beats an FFT pair, above it building the matrix (a contact changes shape most frames)
# costs more than the solve saves.
DENSE_MAX_CELLS = 300


class _DenseCells(_Preconditioned):
    """Traction on the contact cells (2, m) MPa -> in-plane displacement of those cells (2, m) mm, as one
    float32 matrix: on the few hundred cells of a typical contact a matrix-vector product takes
    microseconds, where each FFT convolution pays tens of microseconds of call overhead."""

    def __init__(self, rows: np.ndarray, cols: np.ndarray, grid_shape: tuple[int, int], dx: float, dy: float,
                 material: Material, thickness_mm: float | None = None) -> None:
        self._set_preconditioner(rows, cols, grid_shape, dx, dy, material, thickness_mm)
        # the matrix depends only on the cells' relative positions: a contact that keeps its shape from one
        # frame to the next (about half the frames) reuses it
        rows, cols = rows - rows.min(), cols - cols.min()
        key = (grid_shape, dx, dy, material.youngs_modulus_mpa, material.poisson_ratio, thickness_mm,
               rows.tobytes(), cols.tobytes())
        matrix = _RECENT_MATRICES.pop(key, None)
        if matrix is None:
            matrix = _dense_matrix(rows, cols, kernel_set(grid_shape, dx, dy, material.youngs_modulus_mpa,
                                                           material.poisson_ratio, thickness_mm))
        _RECENT_MATRICES[key] = matrix
        while len(_RECENT_MATRICES) > RECENT_MATRICES_KEPT:
            _RECENT_MATRICES.popitem(last=False)
        self.matrix = matrix

    def __call__(self, q: np.ndarray) -> np.ndarray:
        return (self.matrix @ q.astype(np.float32).reshape(-1)).reshape(2, -1)


RECENT_MATRICES_KEPT = 4   # two pads, each with the contact of this frame and the last
_RECENT_MATRICES: OrderedDict[tuple[object, ...], np.ndarray] = OrderedDict()


def _dense_matrix(rows: np.ndarray, cols: np.ndarray, ks: KernelSet) -> np.ndarray:
    """(2 m, 2 m) float32 [[xx, xy], [xy, yy]] influence matrix of cells (``rows``, ``cols``) of ``ks``'s grid."""
    xx, xy, yy = ks.tangential_centred()
    matrix = _fill_dense_matrix(np.ascontiguousarray(rows, dtype=np.int64), np.ascontiguousarray(cols, dtype=np.int64),
                                np.ascontiguousarray(xx, dtype=np.float32), np.ascontiguousarray(xy, dtype=np.float32),
                                np.ascontiguousarray(yy, dtype=np.float32), ks.shape[0], ks.shape[1])
    matrix.flags.writeable = False    # shared between frames through the cache
    return matrix


@numba.njit(cache=True, nogil=True)
def _fill_dense_matrix(rows: np.ndarray, cols: np.ndarray, xx: np.ndarray, xy: np.ndarray, yy: np.ndarray,
                       ny: int, nx: int) -> np.ndarray:  # pragma: no cover (compiled)
    # entry (i, j) is the kernel at the offset of cell i from cell j, the (2 ny - 1, 2 nx - 1) kernels centred
    # at (ny - 1, nx - 1); the x-y coupling kernel is even in the offset, so its two blocks are equal.
    # Compiled: a contact changes shape most frames, and array code spent more on index arrays than on this.
    m = rows.size
    matrix = np.empty((2 * m, 2 * m), np.float32)
    for i in range(m):
        top, bottom = matrix[i], matrix[m + i]
        for j in range(m):
            r, c = rows[i] - rows[j] + ny - 1, cols[i] - cols[j] + nx - 1
            top[j], top[m + j] = xx[r, c], xy[r, c]
            bottom[j], bottom[m + j] = xy[r, c], yy[r, c]
    return matrix


class _WindowCells(_Preconditioned):
    """The same map as ``_DenseCells`` by FFT convolution over the window around the contact, for contacts
    too large for a matrix."""

    def __init__(self, contact_mask: np.ndarray, rows: np.ndarray, cols: np.ndarray, dx: float, dy: float,
                 material: Material, thickness_mm: float | None = None) -> None:
        self._set_preconditioner(rows, cols, contact_mask.shape, dx, dy, material, thickness_mm)
        ks = kernel_set(self.shape, dx, dy, material.youngs_modulus_mpa, material.poisson_ratio, thickness_mm)
        # single precision: the solve stops at a relative residual of 1e-4, far above float32's 1e-7
        self.xx, self.xy, self.yy = ks.tangential_single()
        self.pad = ks.pad_shape

    def __call__(self, q: np.ndarray) -> np.ndarray:
        field = np.zeros((2, *self.shape), np.float32)
        field[:, self.rows, self.cols] = q
        # both components in one transform each way: on these small windows the per-call overhead of the
        # FFT, not its arithmetic, is what the solve pays for
        fx, fy = padded_spectrum(field, self.pad)
        spectrum = np.stack([self.xx * fx + self.xy * fy, self.xy * fx + self.yy * fy])
        return padded_inverse(spectrum, self.pad, self.shape)[:, self.rows, self.cols]


@lru_cache(maxsize=64)
def circulant_inverse(shape: tuple[int, int], dx: float, dy: float, e_mpa: float, nu: float,
                      thickness_mm: float | None = None) -> np.ndarray:
    """(3, ny, nx // 2 + 1) float32 (xx, xy, yy) multipliers of the rfft2 over the window ``shape`` (ny, nx)
    cells of ``dx x dy`` mm that approximately invert the tangential operator: the inverse, frequency by
    frequency, of the circulant matrix that keeps the influence coefficients within half a window of each cell
    (Strang's preconditioner for Toeplitz systems). The operator on a contact's cells is that matrix with the
    far coefficients wrapped and the cells off the contact removed, so this preconditioned conjugate gradient
    takes 2 to 3 times fewer iterations (measured on the task recordings) for a transform a quarter the size of
    the operator's. Eigenvalues below a thousandth of the largest are raised to it, so the multipliers stay
    positive definite."""
    a, b, d = (strang_eigenvalues(k)
               for k in kernel_set(shape, dx, dy, e_mpa, nu, thickness_mm).tangential_centred())
    # the symmetric 2 x 2 [[a, b], [b, d]] at each frequency, through its eigenvalues
    mean, radius = 0.5 * (a + d), np.hypot(0.5 * (a - d), b)
    floor = 1e-3 * float((mean + radius).max())
    big, small = np.maximum(mean + radius, floor), np.maximum(mean - radius, floor)
    angle = 0.5 * np.arctan2(2.0 * b, a - d)
    c, s_ = np.cos(angle), np.sin(angle)
    inv_big, inv_small = 1.0 / big, 1.0 / small
    out = np.stack([c * c * inv_big + s_ * s_ * inv_small, c * s_ * (inv_big - inv_small),
                    s_ * s_ * inv_big + c * c * inv_small]).astype(np.float32)
    out.flags.writeable = False
    return out


@numba.njit(cache=True, nogil=True)
def _precondition_cells(inverse: np.ndarray, window: tuple[int, int], rows: np.ndarray, cols: np.ndarray,
                        r: np.ndarray) -> np.ndarray:  # pragma: no cover (compiled)
    # ``circulant_inverse`` on a flattened (2 m,) residual of the cells (rows, cols) of the window
    return _convolve_cells(inverse, window, window, rows, cols, r)


@numba.njit(cache=True, nogil=True)
def _convolve_cells(multipliers: np.ndarray, window: tuple[int, int], fft_shape: tuple[int, int], rows: np.ndarray,
                    cols: np.ndarray, v: np.ndarray) -> np.ndarray:  # pragma: no cover (compiled)
    # a flattened (2 m,) vector field on the cells (rows, cols) of the window, scattered on it, transformed over
    # ``fft_shape`` (the window, or the window zero-padded), multiplied frequency by frequency by the symmetric
    # 2 x 2 (xx, xy, yy) ``multipliers``, transformed back and gathered
    m = rows.size
    wr, fr, fc = window[0], fft_shape[0], fft_shape[1]
    field = np.zeros((2, wr, window[1]), np.float32)
    for i in range(m):
        field[0, rows[i], cols[i]] = v[i]
        field[1, rows[i], cols[i]] = v[m + i]
    # the rows past the window are zero padding, and only the window is read back: the row transforms skip them
    # (a separable transform, where rfft2 would transform every row of the padded grid)
    spectrum = np.zeros((2, fr, fc // 2 + 1), np.complex64)
    spectrum[:, :wr] = np.fft.rfft(field, n=fc, axis=2)
    spectrum = np.fft.fft(spectrum, axis=1)
    _multiply_2x2(multipliers, spectrum)
    grid = np.fft.irfft(np.fft.ifft(spectrum, axis=1)[:, :wr], n=fc, axis=2)
    out = np.empty(2 * m)
    for i in range(m):
        out[i] = grid[0, rows[i], cols[i]]
        out[m + i] = grid[1, rows[i], cols[i]]
    return out


@numba.njit(cache=True, nogil=True)
def _multiply_2x2(multipliers: np.ndarray, spectrum: np.ndarray) -> None:  # pragma: no cover (compiled)
    # spectrum (2, a, b) <- the symmetric 2 x 2 (xx, xy, yy) ``multipliers`` (3, a, b) times it, frequency by
    # frequency, in place (array expressions would make five spectrum-sized temporaries)
    for i in range(spectrum.shape[1]):
        for j in range(spectrum.shape[2]):
            fx, fy = spectrum[0, i, j], spectrum[1, i, j]
            xy = multipliers[1, i, j]
            spectrum[0, i, j] = multipliers[0, i, j] * fx + xy * fy
            spectrum[1, i, j] = xy * fx + multipliers[2, i, j] * fy


CellOperator = _DenseCells | _WindowCells


def _cell_operator(contact_mask: np.ndarray, rows: np.ndarray, cols: np.ndarray, dx: float, dy: float,
                   material: Material, dense_max_cells: int, thickness_mm: float | None = None) -> CellOperator:
    if rows.size <= dense_max_cells:
        return _DenseCells(rows, cols, contact_mask.shape, dx, dy, material, thickness_mm)
    return _WindowCells(contact_mask, rows, cols, dx, dy, material, thickness_mm)


# Relative residual at which the tangential solves stop. Marker positions are stored in px, where 1e-4 of the
# displacement is far below a thousandth of a pixel; 1e-8 costs three times the iterations for nothing.
CG_TOLERANCE = 1e-4


# A load this far (relative) above the friction limit still counts as stuck: at the limit, solves of the same state
# scatter by the CG tolerance around it, and a held contact would otherwise creep by that much every frame.
SLIDE_TOLERANCE = 10 * CG_TOLERANCE


# Tolerance of the intermediate partial-slip rounds, which only decide which cells slide; the settled slip set
# is then solved once at SETTLED_SLIP_TOLERANCE.
SLIP_ROUND_TOLERANCE = 1e-2


# Tolerance of that last solve, whose tractions are the frame's. On recorded Pull-out Key frames it moves the
# markers by at most 0.006 px and the shear force by 5e-4 N from a solve at 1e-8 (1e-4: 0.0002 px), for a fifth
# fewer operator applications a frame; the fully stuck solves, which decide gross sliding against
# SLIDE_TOLERANCE, stay at CG_TOLERANCE.
SETTLED_SLIP_TOLERANCE = 1e-3


def _cg(op: CellOperator, active: np.ndarray, rhs: np.ndarray, tol: float = CG_TOLERANCE,
        max_iter: int = 200, start: np.ndarray | None = None) -> np.ndarray:
    """Solve op(q) = rhs on the ``active`` contact cells (m,) bool (q = 0 on the others) by conjugate
    gradient, preconditioned with ``op.precondition``; q and rhs are (2, m).
    ``start``: an initial guess (used on ``active``). Stops when the residual is ``tol`` of the right-hand
    side, so a good guess or a preconditioner saves iterations without changing what "converged" means."""
    keep = active.astype(np.float64)
    b = rhs * keep
    if start is None or not b.any():   # a zero load has the zero solution, whatever the guess
        q = np.zeros_like(b)
        r = b
    else:
        q = start * keep
        r = b - op(q) * keep
    rr = float(np.vdot(r, r))
    stop = tol * tol * max(float(np.vdot(b, b)), 1e-300)
    if rr <= stop:
        return q
    z = op.precondition(r) * keep
    d = z.copy()
    rz = float(np.vdot(r, z))
    for _ in range(max_iter):
        ad = op(d) * keep
        curvature = float(np.vdot(d, ad))
        if curvature <= 0.0:   # the direction underflowed in single precision: nothing left to gain
            break
        alpha = rz / curvature
        q += alpha * d
        r -= alpha * ad
        if float(np.vdot(r, r)) <= stop:
            break
        z = op.precondition(r) * keep
        rz_new = float(np.vdot(r, z))
        d = z + (rz_new / rz) * d
        rz = rz_new
    return q


@numba.njit(cache=True, nogil=True)
def _apply_cells(matrix: np.ndarray, spectra: np.ndarray, pad: tuple[int, int], window: tuple[int, int],
                 rows: np.ndarray, cols: np.ndarray, q: np.ndarray) -> np.ndarray:  # pragma: no cover (compiled)
    # the cell operator on a flattened (2 m,) traction: the dense matrix when it has entries, else the FFT
    # convolution over the window (``_WindowCells``, single precision: the solves stop at a relative residual
    # of 1e-4, far above float32's 1e-7). numpy.fft inside compiled code comes from rocket-fft.
    if matrix.size > 0:
        return np.dot(matrix, q.astype(np.float32)).astype(np.float64)
    return _convolve_cells(spectra, window, pad, rows, cols, q)


@numba.njit(cache=True, nogil=True)
def _cg_cells(matrix: np.ndarray, spectra: np.ndarray, pad: tuple[int, int], window: tuple[int, int],
              rows: np.ndarray, cols: np.ndarray, inverse: np.ndarray, keep: np.ndarray, rhs: np.ndarray,
              start: np.ndarray, tol: float, max_iter: int) -> np.ndarray:  # pragma: no cover (compiled)
    # _cg's iteration on flattened (2 m,) vectors with the operator of _apply_cells, preconditioned with
    # _precondition_cells; an empty ``start``: none
    b = rhs * keep
    if start.size == 0 or not b.any():
        q = np.zeros(b.size)
        r = b.copy()
    else:
        q = start * keep
        r = b - _apply_cells(matrix, spectra, pad, window, rows, cols, q) * keep
    rr = np.dot(r, r)
    stop = tol * tol * max(np.dot(b, b), 1e-300)
    if rr <= stop:
        return q
    z = _precondition_cells(inverse, window, rows, cols, r) * keep
    d = z.copy()
    rz = np.dot(r, z)
    for _ in range(max_iter):
        ad = _apply_cells(matrix, spectra, pad, window, rows, cols, d) * keep
        curvature = np.dot(d, ad)
        if curvature <= 0.0:
            break
        alpha = rz / curvature
        q += alpha * d
        r -= alpha * ad
        if np.dot(r, r) <= stop:
            break
        z = _precondition_cells(inverse, window, rows, cols, r) * keep
        rz_new = np.dot(r, z)
        d = z + (rz_new / rz) * d
        rz = rz_new
    return q


def _stick_slip(op: CellOperator, p: np.ndarray, rx: np.ndarray, ry: np.ndarray, s: np.ndarray, theta: float,
                mu: float, area: float, total_p: float, slip_rounds: int, guess_s: np.ndarray | None = None,
                guess_t: np.ndarray | None = None) -> tuple[np.ndarray, float, float, np.ndarray, np.ndarray]:
    """Steps 2 to 4 of the module docstring on the m contact cells: tractions q (2, m) MPa for the elastic slide
    ``s`` (2,) mm and twist ``theta`` rad, with normal pressure ``p`` (m,) MPa at offsets ``rx``, ``ry`` (m,)
    mm from its centroid; the fractions ``lam_s``, ``lam_t`` of slide and twist the friction limit lets
    the gel hold (1: stuck); and the fully stuck tractions of the slide and of the twist (2, m) (zero when
    there is none). ``guess_s``, ``guess_t``: starting points for those two solves, or None."""
    ones = np.ones(p.shape)
    every = np.ones(p.shape, dtype=bool)
    q = np.zeros((2, *p.shape))
    q_s, q_t = np.zeros_like(q), np.zeros_like(q)
    lam_s = lam_t = 1.0
    if np.any(s != 0.0):
        q_s = _cg(op, every, np.stack([s[0] * ones, s[1] * ones]), start=guess_s)
        force = np.hypot(*(q_s.sum(axis=1) * area))
        limit = mu * total_p * area
        lam_s = limit / force if force > limit * (1.0 + SLIDE_TOLERANCE) else 1.0
        q += lam_s * q_s
    if theta != 0.0:
        q_t = _cg(op, every, np.stack([-theta * ry, theta * rx]), start=guess_t)
        torque = abs(float((rx * q_t[1] - ry * q_t[0]).sum() * area))
        limit = mu * float((p * np.hypot(rx, ry)).sum() * area)
        lam_t = limit / torque if torque > limit * (1.0 + SLIDE_TOLERANCE) else 1.0
        q += lam_t * q_t
    if not np.any(q != 0.0):
        return q, lam_s, lam_t, q_s, q_t
    target = np.stack([lam_s * s[0] - lam_t * theta * ry, lam_s * s[1] + lam_t * theta * rx])
    limit_cell = mu * p
    sliding = np.zeros(p.shape, dtype=bool)
    q_slip = np.zeros_like(q)
    rounds, solved_loose = 0, False
    while True:
        mag = np.hypot(q[0], q[1])
        over = ~sliding & (mag > limit_cell * (1.0 + 1e-9))
        if over.any() and rounds < slip_rounds:
            sliding |= over
            rounds += 1
            with np.errstate(invalid="ignore", divide="ignore"):
                unit = np.where(mag > 0.0, q / np.where(mag > 0.0, mag, 1.0), 0.0)
            q_slip = np.where(sliding, limit_cell * unit, q_slip)
            tol = SLIP_ROUND_TOLERANCE
        elif solved_loose:
            tol = SETTLED_SLIP_TOLERANCE  # the slip set has settled (or the rounds are spent): converge it once
        else:
            break
        stick = ~sliding
        # the previous round's stuck tractions are a close guess: only the cells that just began to slide moved
        q = q_slip + (_cg(op, stick, target - op(q_slip), tol=tol, start=q - q_slip) if stick.any() else 0.0)
        solved_loose = tol == SLIP_ROUND_TOLERANCE
    return q, lam_s, lam_t, q_s, q_t


@numba.njit(cache=True, nogil=True)
def _stick_slip_cells(matrix: np.ndarray, spectra: np.ndarray, pad: tuple[int, int], window: tuple[int, int],
                      win_rows: np.ndarray, win_cols: np.ndarray, inverse: np.ndarray, p: np.ndarray, rx: np.ndarray, ry: np.ndarray,
                      s_x: float, s_y: float, theta: float, mu: float, area: float, total_p: float,
                      slip_rounds: int, cg_tol: float, round_tol: float, settled_tol: float, slide_tol: float,
                      guess_s: np.ndarray, guess_t: np.ndarray, exact_s: bool = False,
                      exact_t: bool = False) -> tuple[np.ndarray, float, float, np.ndarray, np.ndarray]:  # pragma: no cover
    # _stick_slip compiled, on the operator of _apply_cells (the dense matrix, or with an empty matrix the FFT
    # over the window, preconditioned with ``inverse``): its dozens of array calls a round, and each FFT's call
    # overhead, cost more than the arithmetic on a contact's few hundred or thousand cells. Vectors are
    # flattened (2 m,): x components, then y; an empty guess: none. ``exact_s``, ``exact_t``: the guess is the
    # stuck solution itself (from a UnitBasis), not solved again.
    op = (matrix, spectra, pad, window, win_rows, win_cols, inverse)
    m = p.size
    every = np.ones(2 * m)
    q = np.zeros(2 * m)
    q_s, q_t = np.zeros(2 * m), np.zeros(2 * m)
    lam_s = lam_t = 1.0
    if s_x != 0.0 or s_y != 0.0:
        rhs = np.empty(2 * m)
        rhs[:m], rhs[m:] = s_x, s_y
        q_s = guess_s.copy() if exact_s else _cg_cells(*op, every, rhs, guess_s, cg_tol, 200)
        force = np.hypot(q_s[:m].sum() * area, q_s[m:].sum() * area)
        limit = mu * total_p * area
        if force > limit * (1.0 + slide_tol):
            lam_s = limit / force
        q += lam_s * q_s
    if theta != 0.0:
        rhs = np.empty(2 * m)
        rhs[:m], rhs[m:] = -theta * ry, theta * rx
        q_t = guess_t.copy() if exact_t else _cg_cells(*op, every, rhs, guess_t, cg_tol, 200)
        torque = abs((rx * q_t[m:] - ry * q_t[:m]).sum() * area)
        limit = mu * (p * np.hypot(rx, ry)).sum() * area
        if torque > limit * (1.0 + slide_tol):
            lam_t = limit / torque
        q += lam_t * q_t
    if not np.any(q != 0.0):
        return q.reshape(2, m), lam_s, lam_t, q_s.reshape(2, m), q_t.reshape(2, m)
    target = np.empty(2 * m)
    target[:m], target[m:] = lam_s * s_x - lam_t * theta * ry, lam_s * s_y + lam_t * theta * rx
    limit_cell = mu * p
    sliding = np.zeros(m, np.bool_)
    q_slip = np.zeros(2 * m)
    keep = np.empty(2 * m)
    pushed = np.empty(0)  # the displacement the sliding cells' tractions push the cells by, once computed
    rounds, solved_loose = 0, False
    while True:
        mag = np.hypot(q[:m], q[m:])
        over = ~sliding & (mag > limit_cell * (1.0 + 1e-9))
        if over.any() and rounds < slip_rounds:
            sliding |= over
            rounds += 1
            for i in range(m):
                if sliding[i]:
                    positive = mag[i] > 0.0
                    q_slip[i] = limit_cell[i] * (q[i] / mag[i]) if positive else 0.0
                    q_slip[m + i] = limit_cell[i] * (q[m + i] / mag[i]) if positive else 0.0
            pushed = np.empty(0)  # the sliding tractions changed
            tol = round_tol
        elif solved_loose:
            tol = settled_tol  # same sliding tractions as the last round: its push still holds
        else:
            break
        if sliding.all():
            q = q_slip.copy()
        else:
            for i in range(m):
                keep[i] = keep[m + i] = 0.0 if sliding[i] else 1.0
            if pushed.size == 0:
                pushed = _apply_cells(matrix, spectra, pad, window, win_rows, win_cols, q_slip)
            q = q_slip + _cg_cells(*op, keep, target - pushed, q - q_slip, tol, 200)
        solved_loose = tol == round_tol
    return q.reshape(2, m), lam_s, lam_t, q_s.reshape(2, m), q_t.reshape(2, m)


# the operator arguments of _stick_slip_cells that the other operator leaves empty
_NO_MATRIX = np.zeros((0, 0), np.float32)
_NO_MATRIX.flags.writeable = False  # as the dense matrices: one compiled signature for both
_NO_SPECTRA = np.zeros((3, 1, 1), np.complex64)


def _warm_start(state: ContactState | None, shape: tuple[int, ...], rows: np.ndarray, cols: np.ndarray,
                s: np.ndarray, theta: float) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Starting points, flattened (2 m,), for the stuck slide and twist solves from the previous frame's
    solutions per unit load: the twist's scaled by ``theta``; the slide's scaled by |s| and turned from the
    direction it was solved for to that of ``s`` (exact for an isotropic operator on a round contact, a close
    guess otherwise)."""
    if state is None or not state.in_contact:
        return None, None
    guess_s = guess_t = None
    if state.slide_solution is not None and state.slide_solution.shape[1:] == shape:
        size = float(np.hypot(s[0], s[1]))
        if size > 0.0:
            (ex, ey), nx_, ny_ = state.slide_direction, s[0] / size, s[1] / size
            guess_s = _gather_cells(state.slide_solution, rows, cols, ex * nx_ + ey * ny_, ex * ny_ - ey * nx_, size)
    if state.twist_solution is not None and state.twist_solution.shape[1:] == shape and theta != 0.0:
        guess_t = _gather_cells(state.twist_solution, rows, cols, 1.0, 0.0, theta)
    return guess_s, guess_t


def _new_basis(rows: np.ndarray, cols: np.ndarray, s: np.ndarray, theta: float, cx: float, cy: float,
               q_s: np.ndarray, q_t: np.ndarray) -> UnitBasis:
    """The basis this frame's stuck solutions (q_s, q_t (2, m)) give for its cells."""
    size = float(np.hypot(s[0], s[1]))
    return UnitBasis(rows, cols, direction=(float(s[0] / size), float(s[1] / size)) if size > 0.0 else (1.0, 0.0),
                     along=q_s.reshape(-1) / size if size > 0.0 else None,
                     twist=q_t.reshape(-1) / theta if theta != 0.0 else None, centre_mm=(cx, cy))


def _complete_basis(basis: UnitBasis, operator: tuple, s: np.ndarray, theta: float, cx: float, cy: float,
                    rx: np.ndarray, ry: np.ndarray) -> UnitBasis:
    """``basis`` with the parts this frame's slide ``s`` and twist ``theta`` about (cx, cy) need solved (each
    once for as long as the cells stay the same), each from the closest guess the basis has."""
    m = rx.size
    every = np.ones(2 * m)
    size = float(np.hypot(s[0], s[1]))
    needs_slide = size > 0.0 or (theta != 0.0 and basis.twist is not None and
                                 (cx, cy) != basis.centre_mm)
    if needs_slide and basis.along is None:
        # no slide yet on these cells: solve along this frame's slide, or along x for a twist's shift
        (nx, ny) = (s[0] / size, s[1] / size) if size > 0.0 else (1.0, 0.0)
        rhs = np.concatenate([np.full(m, nx), np.full(m, ny)])
        basis = UnitBasis(basis.rows, basis.cols, (float(nx), float(ny)),
                          _cg_cells(*operator, every, rhs, np.zeros(0), CG_TOLERANCE, 200), None, basis.twist,
                          basis.centre_mm)
    # as UnitBasis.slide decides it: a slide off the basis direction needs the turned solution too
    turn = (size > 0.0 and basis.direction[0] * (s[1] / size) - basis.direction[1] * (s[0] / size) != 0.0) or \
        (theta != 0.0 and basis.twist is not None and (cx, cy) != basis.centre_mm)
    if needs_slide and turn and basis.across is None:
        dx, dy = basis.direction
        rhs = np.concatenate([np.full(m, -dy), np.full(m, dx)])
        along = basis.along
        start = np.concatenate([-along[m:], along[:m]])  # along turned +90 deg: exact on a round contact
        basis = UnitBasis(basis.rows, basis.cols, basis.direction, basis.along,
                          _cg_cells(*operator, every, rhs, start, CG_TOLERANCE, 200), basis.twist, basis.centre_mm)
    if theta != 0.0 and basis.twist is None:
        rhs = np.concatenate([-ry, rx])
        basis = UnitBasis(basis.rows, basis.cols, basis.direction, basis.along, basis.across,
                          _cg_cells(*operator, every, rhs, np.zeros(0), CG_TOLERANCE, 200), (cx, cy))
    return basis


def _exact_from_basis(basis: UnitBasis, s: np.ndarray, theta: float, cx: float,
                      cy: float) -> tuple[np.ndarray | None, np.ndarray | None]:
    """This frame's stuck slide and twist solutions (2 m,) as combinations of a completed ``basis``."""
    size = float(np.hypot(s[0], s[1]))
    slide = basis.slide(s[0] / size, s[1] / size) if size > 0.0 else None
    twist = basis.twist_about(cx, cy) if theta != 0.0 else None
    return (None if slide is None else size * slide), (None if twist is None else theta * twist)


def _unit_solutions(state: ContactState | None, shape: tuple[int, ...], rows: np.ndarray, cols: np.ndarray,
                    s: np.ndarray, theta: float, q_s: np.ndarray, q_t: np.ndarray
                    ) -> tuple[np.ndarray | None, tuple[float, float], np.ndarray | None]:
    """This frame's stuck solutions per unit slide and twist on the grid, for the next frame's
    :func:`_warm_start`; a load that is zero this frame keeps the previous frame's."""
    carried = state if state is not None and state.in_contact else ContactState()
    slide, direction, twist = carried.slide_solution, carried.slide_direction, carried.twist_solution
    size = float(np.hypot(s[0], s[1]))
    if size > 0.0:
        slide = _scatter_cells(shape[0], shape[1], rows, cols, q_s, size)
        direction = (float(s[0] / size), float(s[1] / size))
    if theta != 0.0:
        twist = _scatter_cells(shape[0], shape[1], rows, cols, q_t, theta)
    return slide, direction, twist


@numba.njit(cache=True, nogil=True)
def _gather_cells(field: np.ndarray, rows: np.ndarray, cols: np.ndarray, cos: float, sin: float,
                  scale: float) -> np.ndarray:  # pragma: no cover (compiled)
    # ``scale`` times the vectors of ``field`` (2, ny, nx) at the cells, turned by the angle of (cos, sin),
    # flattened (2 m,): x components, then y (fancy indexing and stacking cost more than the solve's start saves)
    m = rows.size
    out = np.empty(2 * m)
    for i in range(m):
        ux, uy = field[0, rows[i], cols[i]], field[1, rows[i], cols[i]]
        out[i] = scale * (cos * ux - sin * uy)
        out[m + i] = scale * (sin * ux + cos * uy)
    return out


@numba.njit(cache=True, nogil=True)
def _scatter_cells(ny: int, nx: int, rows: np.ndarray, cols: np.ndarray, q: np.ndarray,
                   divisor: float) -> np.ndarray:  # pragma: no cover (compiled)
    # (2, ny, nx): ``q`` (2, m) / ``divisor`` on the cells, zero elsewhere
    out = np.zeros((2, ny, nx))
    for i in range(rows.size):
        out[0, rows[i], cols[i]] = q[0, i] / divisor
        out[1, rows[i], cols[i]] = q[1, i] / divisor
    return out


def solve_shear(
    pressure_mpa: np.ndarray,
    contact_mask: np.ndarray,
    dx_mm: float,
    dy_mm: float,
    x_mm: np.ndarray,
    y_mm: np.ndarray,
    material: Material,
    tangential_mm: tuple[float, float],
    twist_rad: float,
    state: ContactState | None,
    slip_rounds: int = 8,
    dense_max_cells: int = DENSE_MAX_CELLS,
    thickness_mm: float | None = None,
) -> ShearResult:
    """Tangential tractions, in-plane displacement (on the grid of ``pressure_mpa`` (ny, nx), cell centres
    ``x_mm`` (nx,), ``y_mm`` (ny,)), force and slip; see the module docstring. ``dense_max_cells``: contacts
    of at most this many cells are solved with a dense matrix, larger ones by FFT (same result within the
    solve's tolerance). ``thickness_mm``: the gel is a layer this thick bonded to its backing (None: a
    half-space), for the tangential compliance and the pressure's in-plane displacement."""
    shape = pressure_mpa.shape
    zero2 = np.zeros((2, *shape))
    if not contact_mask.any():
        return ShearResult(zero2, zero2.copy(), np.zeros(2), 0.0, ContactState())
    tangential = np.asarray(tangential_mm, dtype=np.float64)
    if state is None:
        reference, twist_ref, slip = np.zeros(2), 0.0, 0.0
    elif not state.in_contact:
        reference, twist_ref, slip = tangential.copy(), float(twist_rad), 0.0
    else:
        reference, twist_ref, slip = np.asarray(state.reference_mm, float), state.reference_twist_rad, state.slip_mm
    s = tangential - reference
    theta = float(twist_rad) - twist_ref
    area = dx_mm * dy_mm
    mu = material.friction

    # everything below lives on the m contact cells, as (m,) or (2, m) arrays
    # contiguous: np.nonzero gives strided views except for a single cell, and each layout is a compile
    rows, cols = (np.ascontiguousarray(index) for index in np.nonzero(contact_mask))
    p = pressure_mpa[rows, cols]
    gx, gy = x_mm[cols], y_mm[rows]
    total_p = float(p.sum())
    cx, cy = float((p * gx).sum() / total_p), float((p * gy).sum() / total_p)
    rx, ry = gx - cx, gy - cy
    op = _cell_operator(contact_mask, rows, cols, dx_mm, dy_mm, material, dense_max_cells, thickness_mm)
    if isinstance(op, _DenseCells):
        operator = (op.matrix, _NO_SPECTRA, (1, 1), op.shape, op.rows, op.cols, op.inverse)
    else:
        operator = (_NO_MATRIX, np.stack([op.xx, op.xy, op.yy]), op.pad, op.shape, op.rows, op.cols, op.inverse)
    basis = state.unit_basis if state is not None and state.in_contact else None
    if basis is not None and basis.holds(rows, cols):
        basis = _complete_basis(basis, operator, s, theta, cx, cy, rx, ry)
        exact_s, exact_t = _exact_from_basis(basis, s, theta, cx, cy)
        guess_s, guess_t = exact_s, exact_t
    else:
        basis, exact_s, exact_t = None, None, None
        guess_s, guess_t = _warm_start(state, shape, rows, cols, s, theta)
    none = np.zeros(0)
    q, lam_s, lam_t, q_s, q_t = _stick_slip_cells(
        *operator, p, rx, ry, float(s[0]), float(s[1]), theta, mu, area, total_p, slip_rounds, CG_TOLERANCE,
        SLIP_ROUND_TOLERANCE, SETTLED_SLIP_TOLERANCE, SLIDE_TOLERANCE, none if guess_s is None else guess_s,
        none if guess_t is None else guess_t, exact_s is not None, exact_t is not None)
    if basis is None:
        basis = _new_basis(rows, cols, s, theta, cx, cy, q_s, q_t)
    slide_solution, slide_direction, twist_solution = _unit_solutions(state, shape, rows, cols, s, theta, q_s, q_t)
    reference = reference + (1.0 - lam_s) * s
    twist_ref = twist_ref + (1.0 - lam_t) * theta
    r_mean = float((p * np.hypot(rx, ry)).sum() / total_p)
    slip += (1.0 - lam_s) * float(np.hypot(*s)) + (1.0 - lam_t) * abs(theta) * r_mean

    traction = np.zeros((2, *shape))
    traction[:, rows, cols] = q
    ks = kernel_set(shape, dx_mm, dy_mm, material.youngs_modulus_mpa, material.poisson_ratio, thickness_mm)
    # the radial term of p and the Cerruti term of q in one forward and one inverse transform (single precision:
    # the displacement moves markers stored in float32 px); the loads are zero off the contact's rows
    loads = np.empty((3, *shape), np.float32)
    loads[0], loads[1:] = pressure_mpa, traction
    spectra = padded_spectrum(loads, ks.pad_shape, (int(rows.min()), int(rows.max()) + 1))
    kernel = ks.in_plane_single()
    in_plane = kernel[:, 0] * spectra[0] + kernel[:, 1] * spectra[1] + kernel[:, 2] * spectra[2]
    displacement = padded_inverse(in_plane, ks.pad_shape, shape)
    new_state = ContactState(
        in_contact=True, reference_mm=(float(reference[0]), float(reference[1])),
        reference_twist_rad=float(twist_ref), slip_mm=float(slip), slide_solution=slide_solution,
        slide_direction=slide_direction, twist_solution=twist_solution, unit_basis=basis,
    )
    return ShearResult(traction, displacement, q.sum(axis=1) * area, float(slip), new_state)

