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
   conjugate gradient with the Cerruti influence coefficients (:mod:`.kernels`; symmetric positive definite).
3. Gross slip. If the total tangential force exceeds mu * P (or the torque exceeds mu * sum(p |x - c|) dA) the
   object slides: the load is scaled back to the friction limit and the reference follows the object, so the
   excess displacement is accumulated in ``slip_mm`` (mm; a twist slide counts as the mean contact radius
   times the angle). While stuck, ``slip_mm`` stays 0; it resets when contact ends.
4. Partial slip (Cattaneo-Mindlin). Cells whose stuck traction exceeds mu * p slide: their traction is set to
   mu * p along the stuck direction and the stick region is solved again (a few rounds).
5. In-plane displacement. ``u = K_t * q`` plus the radial term of the normal load
   (``-(1 - 2 nu) / (4 pi G)`` Boussinesq, zero at nu = 0.5), both by FFT convolution over the grid.

Simplification: one reference per contact (not per cell), so partial-slip history is not carried between
frames; the slip state is that of the whole contact. Tangential loads do not move the surface along the normal.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.fft as sfft

from univtac_data.schema.sensors import Material

from .kernels import kernel_set

__all__ = ["ContactState", "ShearResult", "solve_shear"]


@dataclass(frozen=True)
class ContactState:
    """Stick/slip history of one pad, passed from frame to frame (``TactileFrame.state`` -> next call).

    ``in_contact``: the previous frame had contact. ``reference_mm``: object tangential displacement (x, y) mm
    at which the gel is unstrained. ``reference_twist_rad``: likewise for the twist, rad.
    ``slip_mm``: sliding accumulated since contact onset, mm. ``pressure_mpa``: the previous frame's normal
    pressure on the solver grid (ny, nx) MPa, or None: the elastic solve starts from it (consecutive frames
    differ little, so the conjugate gradient needs a few iterations instead of tens).
    """

    in_contact: bool = False
    reference_mm: tuple[float, float] = (0.0, 0.0)
    reference_twist_rad: float = 0.0
    slip_mm: float = 0.0
    pressure_mpa: np.ndarray | None = field(default=None, compare=False, repr=False)


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


def _window(mask: np.ndarray, grow: int) -> tuple[slice, slice]:
    out = []
    for axis in (1, 0):
        idx = np.flatnonzero(mask.any(axis=axis))
        n = mask.shape[1 - axis]
        size = min(n, sfft.next_fast_len(idx[-1] + 1 - idx[0] + 2 * grow))
        start = int(np.clip((idx[0] + idx[-1] + 1 - size) // 2, 0, n - size))
        out.append(slice(start, start + size))
    return out[0], out[1]


class _TangentialOperator:
    """q (2, ny, nx) MPa -> in-plane displacement (2, ny, nx) mm on a window."""

    def __init__(self, shape: tuple[int, int], dx: float, dy: float, material: Material) -> None:
        ks = kernel_set(shape, dx, dy, material.youngs_modulus_mpa, material.poisson_ratio)
        # single precision: the solve stops at a relative residual of 1e-4, far above float32's 1e-7
        self.xx, self.xy, self.yy = ks.tangential_single()
        self.pad = ks.pad_shape
        self.shape = shape

    def __call__(self, q: np.ndarray) -> np.ndarray:
        # both components in one transform each way: on these small windows the per-call overhead of the
        # FFT, not its arithmetic, is what the solve pays for
        fx, fy = sfft.rfft2(q.astype(np.float32), s=self.pad, axes=(-2, -1), workers=1)
        ny, nx = self.shape
        spectrum = np.stack([self.xx * fx + self.xy * fy, self.xy * fx + self.yy * fy])
        return sfft.irfft2(spectrum, s=self.pad, axes=(-2, -1), workers=1)[:, :ny, :nx]


# Relative residual at which the tangential solves stop. Marker positions are stored in px, where 1e-4 of the
# displacement is far below a thousandth of a pixel; 1e-8 costs three times the iterations for nothing.
CG_TOLERANCE = 1e-4


# Tolerance of the intermediate partial-slip rounds, which only decide which cells slide; the settled slip set
# is then solved once at CG_TOLERANCE.
SLIP_ROUND_TOLERANCE = 1e-2


def _cg(op: _TangentialOperator, cells: np.ndarray, rhs: np.ndarray, tol: float = CG_TOLERANCE,
        max_iter: int = 200, start: np.ndarray | None = None) -> np.ndarray:
    """Solve op(q) = rhs on ``cells`` (q = 0 elsewhere) by conjugate gradient; (2, ny, nx). ``start``: an
    initial guess (used on ``cells``). Stops when the residual is ``tol`` of the right-hand side, so a good
    guess saves iterations without changing what "converged" means."""
    b = np.where(cells, rhs, 0.0)
    if start is None:
        q = np.zeros_like(rhs)
        r = b
    else:
        q = np.where(cells, start, 0.0)
        r = b - np.where(cells, op(q), 0.0)
    d = r.copy()
    rr = float(np.vdot(r, r))
    stop = tol * tol * max(float(np.vdot(b, b)), 1e-300)
    for _ in range(max_iter):
        if rr <= stop:
            break
        ad = np.where(cells, op(d), 0.0)
        alpha = rr / float(np.vdot(d, ad))
        q += alpha * d
        r -= alpha * ad
        rr_new = float(np.vdot(r, r))
        d = r + (rr_new / rr) * d
        rr = rr_new
    return q


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
) -> ShearResult:
    """Tangential tractions, in-plane displacement (on the grid of ``pressure_mpa`` (ny, nx), cell centres
    ``x_mm`` (nx,), ``y_mm`` (ny,)), force and slip; see the module docstring."""
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

    win = _window(contact_mask, 2)
    p = pressure_mpa[win]
    cells = contact_mask[win]
    gx, gy = np.meshgrid(x_mm[win[1]], y_mm[win[0]])
    total_p = float(p.sum())
    cx, cy = float((p * gx).sum() / total_p), float((p * gy).sum() / total_p)
    rx, ry = gx - cx, gy - cy
    op = _TangentialOperator(p.shape, dx_mm, dy_mm, material)
    ones = np.ones(p.shape)

    q = np.zeros((2, *p.shape))
    lam_s = lam_t = 1.0
    if np.any(s != 0.0):
        q_s = _cg(op, cells, np.stack([s[0] * ones, s[1] * ones]))
        force = np.hypot(*(q_s.sum(axis=(1, 2)) * area))
        limit = mu * total_p * area
        lam_s = min(1.0, limit / force) if force > 0.0 else 1.0
        q += lam_s * q_s
    if theta != 0.0:
        q_t = _cg(op, cells, np.stack([-theta * ry, theta * rx]))
        torque = abs(float((rx * q_t[1] - ry * q_t[0]).sum() * area))
        limit = mu * float((p * np.hypot(rx, ry)).sum() * area)
        lam_t = min(1.0, limit / torque) if torque > 0.0 else 1.0
        q += lam_t * q_t
    reference = reference + (1.0 - lam_s) * s
    twist_ref = twist_ref + (1.0 - lam_t) * theta
    r_mean = float((p * np.hypot(rx, ry)).sum() / total_p)
    slip += (1.0 - lam_s) * float(np.hypot(*s)) + (1.0 - lam_t) * abs(theta) * r_mean

    if np.any(q != 0.0):
        target = np.stack([lam_s * s[0] - lam_t * theta * ry, lam_s * s[1] + lam_t * theta * rx])
        limit_cell = mu * p
        sliding = np.zeros(p.shape, dtype=bool)
        q_slip = np.zeros_like(q)
        rounds, solved_loose = 0, False
        while True:
            mag = np.hypot(q[0], q[1])
            over = cells & ~sliding & (mag > limit_cell * (1.0 + 1e-9))
            if over.any() and rounds < slip_rounds:
                sliding |= over
                rounds += 1
                with np.errstate(invalid="ignore", divide="ignore"):
                    unit = np.where(mag > 0.0, q / np.where(mag > 0.0, mag, 1.0), 0.0)
                q_slip = np.where(sliding, limit_cell * unit, q_slip)
                tol = SLIP_ROUND_TOLERANCE
            elif solved_loose:
                tol = CG_TOLERANCE  # the slip set has settled (or the rounds are spent): converge it once
            else:
                break
            stick = cells & ~sliding
            # the previous round's stuck tractions are a close guess: only the cells that just began to slide moved
            q = q_slip + (_cg(op, stick, target - op(q_slip), tol=tol, start=q - q_slip) if stick.any() else 0.0)
            solved_loose = tol == SLIP_ROUND_TOLERANCE
        q = np.where(cells, q, 0.0)

    traction = np.zeros((2, *shape))
    traction[(slice(None), *win)] = q
    ks = kernel_set(shape, dx_mm, dy_mm, material.youngs_modulus_mpa, material.poisson_ratio)
    displacement = np.zeros((2, *shape))
    if material.poisson_ratio < 0.5:
        kx, ky = ks.radial()
        fp = sfft.rfft2(pressure_mpa, s=ks.pad_shape, workers=1)
        displacement[0] = sfft.irfft2(fp * kx, s=ks.pad_shape, workers=1)[: shape[0], : shape[1]]
        displacement[1] = sfft.irfft2(fp * ky, s=ks.pad_shape, workers=1)[: shape[0], : shape[1]]
    if np.any(q != 0.0):
        kxx, kxy, kyy = ks.tangential()
        fx = sfft.rfft2(traction[0], s=ks.pad_shape, workers=1)
        fy = sfft.rfft2(traction[1], s=ks.pad_shape, workers=1)
        displacement[0] += sfft.irfft2(kxx * fx + kxy * fy, s=ks.pad_shape, workers=1)[: shape[0], : shape[1]]
        displacement[1] += sfft.irfft2(kxy * fx + kyy * fy, s=ks.pad_shape, workers=1)[: shape[0], : shape[1]]
    new_state = ContactState(
        in_contact=True, reference_mm=(float(reference[0]), float(reference[1])),
        reference_twist_rad=float(twist_ref), slip_mm=float(slip),
    )
    return ShearResult(traction, displacement, q.sum(axis=(1, 2)) * area, float(slip), new_state)

