"""Influence coefficients of a linear-elastic half-space, or of a layer bonded to a rigid backing, for
uniform tractions on rectangular cells, and their zero-padded FFT convolution.

A cell of size ``dx x dy`` (mm) carries a uniform traction (MPa). The surface displacement (mm) it causes at
offset (X, Y) = (x - x_cell, y - y_cell) is the integral of the point-load solution over the cell:

* normal pressure -> normal displacement (Boussinesq, integrated by Love 1929):
  ``u_z = 1 / (pi E*) * S[F]``, ``F(X, Y) = X asinh(Y/|X|) + Y asinh(X/|Y|)`` (the primitive of 1/r);
* normal pressure -> in-plane displacement (radial, zero for nu = 0.5):
  ``u_x = -(1 - 2 nu) / (4 pi G) * S[Hr]``, ``Hr(X, Y) = X atan(Y/X) + Y/2 ln(X^2 + Y^2)`` (primitive of X/r^2);
* tangential traction along x -> in-plane displacement (Cerruti):
  ``u_x = 1 / (2 pi G) * S[(1 - nu) F + nu Hxx]``, ``Hxx(X, Y) = Y asinh(X/|Y|)`` (primitive of X^2/r^3),
  ``u_y = nu / (2 pi G) * S[-r]`` (primitive of XY/r^3), and symmetrically for a traction along y.

Finite gel layer. A layer of thickness h bonded to a rigid backing, loaded on its free surface, has the
surface compliances (2-D Fourier transform, wavenumber k, s = k h, kappa = 3 - 4 nu) of the half-space times

    normal:                      R_N(s) = (kappa sinh 2s - 2s) / Den(s),
    tangential along k:          R_L(s) = (kappa sinh 2s + 2s) / Den(s),
    tangential across k:         R_T(s) = tanh s,
    Den(s) = kappa cosh 2s + 2 s^2 + (1 + kappa^2) / 2,

with the half-space's 2 / (E* k) (normal), (1 - nu) / (G k) (along) and 1 / (G k) (across), and the
pressure -> in-plane coupling C(s) / (G k), C(s) = (s^2 - kappa (1 - 2 nu) / 2 (cosh 2s - 1)) / Den(s), in
place of the half-space's -(1 - 2 nu) / (2 G k) (toward the load). All four come from Navier's equations in
plane strain with a traction-loaded top and zero displacement at the base (the surface problem depends on
|k| only, the across-k part is anti-plane shear); the tests rederive them. For s >> 1 they are the
half-space's; for s << 1 the thin layer's (oedometric compression h (1 + nu)(1 - 2 nu) / (E (1 - nu)), simple
shear h / G; for nu = 1/2 the squeeze-film law k^2 h^3 / (3 G)). The coupling changes sign: a pressed,
nearly incompressible layer pushes its surface outward, where the half-space draws it in.

In space each coefficient is the cell-integrated half-space one plus a smooth correction, the Hankel
transform of the difference (for a point load of unit size; rho = r / h, x^ = x / r):

    normal:        1 / (pi E* h) T[R_N - 1, J0](rho)
    tangential:    1 / (2 pi G h) (delta_ij (T[a, J0] + T[b, J0] / 2) - (x^_i x^_j - delta_ij / 2) T[b, J2])
                   with a = R_T - 1, b = (1 - nu)(R_L - 1) - (R_T - 1)
    coupling:      1 / (2 pi G h) x^_i T[C + (1 - 2 nu) / 2, J1](rho)
    T[g, Jn](rho) = integral_0^inf g(s) Jn(s rho) ds

which cancels the half-space's 1/r tail (T -> g(0) / rho): the layer's response dies off within a few
thicknesses instead of like 1/r; its normal one is negative (a pile-up) from about one thickness out. The
corrections vary on the scale of h (2 to 4 mm), so they are sampled at cell centres (times the cell area).

``S[f]`` is the four-corner sum ``f(X+a, Y+b) - f(X+a, Y-b) - f(X-a, Y+b) + f(X-a, Y-b)`` with ``a = dx/2``,
``b = dy/2``. The tangential -> normal coupling (proportional to 1 - 2 nu, small for silicone at nu ~ 0.48) is
neglected; for the layer too, where it is the pressure -> in-plane coupling's mirror (Maxwell-Betti) and
larger: C(1) is 6.6 times the half-space's value (with the opposite sign) for nu = 0.48. E* = E / (1 - nu^2), G = E / (2 (1 + nu)).

Convolutions are circular FFTs over a grid padded to twice the field size in each direction, so a field of
(ny, nx) cells sees every other cell of the same grid exactly (no wrap-around). Kernel spectra are cached per
(shape, cell size, material).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import scipy.fft as sfft
from scipy.special import j0, j1

__all__ = ["KernelSet", "convolve", "kernel_set", "layer_profile", "layer_ratios", "padded_inverse", "padded_spectrum",
           "strang_eigenvalues"]

# T[g, Jn](rho) is tabulated on [0, LAYER_RHO_MAX] and taken as g(0) / rho beyond, where the two differ by
# < 2e-6 (relative 1e-4 or less); the integrands have decayed below 1e-25 at s = LAYER_S_MAX.
LAYER_RHO_MAX = 16.0
LAYER_S_MAX = 30.0
_LAYER_RHO_STEP = 0.01
_LAYER_S_STEP = 0.005


def strang_eigenvalues(centred: np.ndarray) -> np.ndarray:
    """Eigenvalues, as a (ny, nx // 2 + 1) float64 rfft2 spectrum, of Strang's circulant approximation of the
    Toeplitz operator whose coefficients at offsets -(n-1)..(n-1) are ``centred`` (2 ny - 1, 2 nx - 1): the
    coefficients within half the grid of each cell, wrapped onto the (ny, nx) grid."""
    ny, nx = (centred.shape[0] + 1) // 2, (centred.shape[1] + 1) // 2
    oy, ox = np.arange(ny), np.arange(nx)
    oy, ox = np.where(oy <= ny // 2, oy, oy - ny), np.where(ox <= nx // 2, ox, ox - nx)
    return np.fft.rfft2(centred[(ny - 1 + oy)[:, None], (nx - 1 + ox)[None, :]].astype(np.float64)).real


def layer_ratios(s: np.ndarray, nu: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(R_N, R_L, R_T, C) at s = k h >= 0, nu: the bonded layer's normal, along-k and across-k tangential
    compliances over the half-space's, and its pressure -> in-plane coupling in units of 1 / (G k) (see the
    module docstring). Written with exp(-2 s) so that large s does not overflow."""
    s = np.asarray(s, dtype=np.float64)
    kappa = 3.0 - 4.0 * nu
    e2 = np.exp(-2.0 * s)
    sech = 2.0 * e2 / (1.0 + e2 * e2)   # 1 / cosh 2s
    tanh = (1.0 - e2 * e2) / (1.0 + e2 * e2)   # tanh 2s
    den = kappa + (2.0 * s * s + 0.5 * (1.0 + kappa * kappa)) * sech   # Den(s) / cosh 2s
    normal = (kappa * tanh - 2.0 * s * sech) / den
    along = (kappa * tanh + 2.0 * s * sech) / den
    coupling = (s * s * sech - 0.5 * kappa * (1.0 - 2.0 * nu) * (1.0 - sech)) / den
    return normal, along, np.tanh(s), coupling


def _tangential_b(s: np.ndarray, nu: float) -> np.ndarray:
    _, along, across, _ = layer_ratios(s, nu)
    return (1.0 - nu) * (along - 1.0) - (across - 1.0)


#: The differences from the half-space that the spatial corrections transform, by name: (order of the Bessel
#: function, g(s, nu)).
_LAYER_TERMS = {
    "normal": (0, lambda s, nu: layer_ratios(s, nu)[0] - 1.0),
    "tangential_a": (0, lambda s, nu: layer_ratios(s, nu)[2] - 1.0),
    "tangential_b0": (0, _tangential_b),
    "tangential_b2": (2, _tangential_b),
    "coupling": (1, lambda s, nu: layer_ratios(s, nu)[3] + 0.5 * (1.0 - 2.0 * nu)),
}


@lru_cache(maxsize=8)
def _layer_tables(nu: float) -> dict[str, tuple[np.ndarray, float]]:
    """T[g, Jn] of every term of ``_LAYER_TERMS`` on the rho grid, and g(0): one pass over the Bessel
    functions for all of them (J2 by the recurrence 2 J1(x) / x - J0(x): scipy's j0 and j1 are much faster
    than its any-order jv)."""
    step = _LAYER_S_STEP
    s = np.arange(0.0, LAYER_S_MAX + step / 2, step)
    weights = np.full(s.size, step)
    weights[[0, -1]] = step / 2
    values = {term: g(s, nu) for term, (_, g) in _LAYER_TERMS.items()}
    weighted = np.stack([values[term] * weights for term in _LAYER_TERMS])   # (terms, s)
    orders = [order for order, _ in _LAYER_TERMS.values()]
    rho = np.arange(0.0, LAYER_RHO_MAX + _LAYER_RHO_STEP / 2, _LAYER_RHO_STEP)
    tables = np.empty((len(orders), rho.size))
    for i, r in enumerate(rho):
        x = s * r
        bessel0, bessel1 = j0(x), j1(x)
        bessel2 = np.where(x > 0.0, 2.0 * bessel1 / np.where(x > 0.0, x, 1.0) - bessel0, 0.0)
        by_order = (bessel0, bessel1, bessel2)
        tables[:, i] = [float(np.dot(weighted[k], by_order[order])) for k, order in enumerate(orders)]
    out = {}
    for k, (term, order) in enumerate(zip(_LAYER_TERMS, orders, strict=True)):
        # Euler-Maclaurin end correction at s = 0 (the integrand is flat at s = LAYER_S_MAX): the
        # trapezoid's error, step^2 / 12 times the integrand's slope there, drops from 2e-6 to below 1e-8
        v = values[term]
        slope = (-3.0 * v[0] + 4.0 * v[1] - v[2]) / (2.0 * step) if order == 0 else \
            (0.5 * v[0] * rho if order == 1 else 0.0)
        out[term] = (tables[k] + step * step / 12.0 * slope, float(v[0]))
    return out


def layer_profile(term: str, rho: np.ndarray, nu: float) -> np.ndarray:
    """T[g, Jn](rho) of the module docstring for ``term`` ("normal", "tangential_a", "tangential_b0",
    "tangential_b2", "coupling") at rho = r / h >= 0 (dimensionless)."""
    rho = np.asarray(rho, dtype=np.float64)
    table, g0 = _layer_tables(float(nu))[term]
    inside = np.interp(rho, np.arange(table.size) * _LAYER_RHO_STEP, table)
    return np.where(rho <= LAYER_RHO_MAX, inside, g0 / np.maximum(rho, LAYER_RHO_MAX))


def _asinh_ratio(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    """num * asinh(den / |num|) with the limit 0 at num = 0."""
    with np.errstate(divide="ignore", invalid="ignore"):
        out = num * np.arcsinh(den / np.abs(num))
    return np.where(num == 0.0, 0.0, out)


def _f_inv_r(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return _asinh_ratio(x, y) + _asinh_ratio(y, x)


def _h_xx(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return _asinh_ratio(y, x)


def _h_xy(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return -np.hypot(x, y)


def _h_radial(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore", invalid="ignore"):
        a = np.where(x == 0.0, 0.0, x * np.arctan(y / x))
        r2 = x * x + y * y
        b = np.where(r2 == 0.0, 0.0, 0.5 * y * np.log(np.where(r2 == 0.0, 1.0, r2)))
    return a + b


def _corner_sum(f, x: np.ndarray, y: np.ndarray, a: float, b: float) -> np.ndarray:  # type: ignore[no-untyped-def]
    return f(x + a, y + b) - f(x + a, y - b) - f(x - a, y + b) + f(x - a, y - b)


class KernelSet:
    """Spectra (rfft2 over the padded (2 ny, 2 nx) grid) of the influence coefficients for one grid.

    ``zz``: pressure -> u_z (mm per MPa); ``rx``/``ry``: pressure -> u_x / u_y (radial term);
    ``xx``, ``xy``, ``yy``: tangential traction -> in-plane displacement (``xy`` serves both couplings).
    All are the bonded layer's when ``thickness_mm`` (mm) is given, else the half-space's. Spatial kernels
    are built lazily, the normal one always.
    """

    def __init__(self, shape: tuple[int, int], dx: float, dy: float, e_mpa: float, nu: float,
                 thickness_mm: float | None = None) -> None:
        self.shape = shape
        self.thickness_mm = thickness_mm
        self._layer_geom: tuple[np.ndarray, tuple[np.ndarray, np.ndarray]] | None = None
        self.pad_shape = (2 * shape[0], 2 * shape[1])
        ny, nx = shape
        # offsets of the padded circular grid: 0..n-1 then -n..-1
        oy = np.fft.ifftshift(np.arange(-ny, ny)) * dy
        ox = np.fft.ifftshift(np.arange(-nx, nx)) * dx
        self._x, self._y = np.meshgrid(ox, oy)
        self._a, self._b = dx / 2.0, dy / 2.0
        self.e_star = e_mpa / (1.0 - nu * nu)
        self.g = e_mpa / (2.0 * (1.0 + nu))
        self.nu = nu
        zz_spatial = _corner_sum(_f_inv_r, self._x, self._y, self._a, self._b) / (np.pi * self.e_star)
        if thickness_mm is not None:
            rho, _ = self._layer_geometry()
            zz_spatial += layer_profile("normal", rho, nu) * (dx * dy / (np.pi * self.e_star * thickness_mm))
        self.zz = self._spectrum(zz_spatial)
        self._zz_single: np.ndarray | None = None
        self._zz_preconditioner: np.ndarray | None = None
        # offsets -(n-1)..(n-1) in order: the response of the field to one cell is a slice of it
        self.zz_centred = np.fft.fftshift(zz_spatial)[1:, 1:].astype(np.float32)
        self._tangential: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._tangential_single: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._tangential_centred: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._radial: tuple[np.ndarray, np.ndarray] | None = None
        self._in_plane_single: np.ndarray | None = None

    def _spectrum(self, k: np.ndarray) -> np.ndarray:
        return sfft.rfft2(k, workers=1)

    @property
    def zz_single(self) -> np.ndarray:
        """``zz`` in single precision (complex64): convolving a float32 field with it runs in float32."""
        if self._zz_single is None:
            self._zz_single = self.zz.astype(np.complex64)
        return self._zz_single

    @property
    def zz_preconditioner(self) -> np.ndarray:
        """(ny, nx // 2 + 1) float32 multipliers of the rfft2 over this grid (not padded) that approximately
        invert the normal operator: the inverse, frequency by frequency, of the circulant matrix that keeps the
        coefficients within half the grid of each cell (Strang's preconditioner for Toeplitz systems, as
        ``shear.circulant_inverse`` for the tangential one). Eigenvalues below a thousandth of the largest
        (the layer's far field is negative) are raised to it, so the multipliers stay positive."""
        if self._zz_preconditioner is None:
            eigen = strang_eigenvalues(self.zz_centred)
            inverse = (1.0 / np.maximum(eigen, 1e-3 * float(eigen.max()))).astype(np.float32)
            inverse.flags.writeable = False
            self._zz_preconditioner = inverse
        return self._zz_preconditioner

    def _tangential_spatial(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        x, y, a, b, nu, g = self._x, self._y, self._a, self._b, self.nu, self.g
        f = _corner_sum(_f_inv_r, x, y, a, b)
        c = 1.0 / (2.0 * np.pi * g)
        xx = c * ((1.0 - nu) * f + nu * _corner_sum(_h_xx, x, y, a, b))
        xy = c * nu * _corner_sum(_h_xy, x, y, a, b)
        yy = c * ((1.0 - nu) * f + nu * _corner_sum(_h_xx, y, x, b, a))
        if self.thickness_mm is not None:
            h = self.thickness_mm
            rho, (ux, uy) = self._layer_geometry()
            scale = 2.0 * a * 2.0 * b / (2.0 * np.pi * g * h)   # cell area / (2 pi G h)
            iso = layer_profile("tangential_a", rho, nu) + 0.5 * layer_profile("tangential_b0", rho, nu)
            aniso = layer_profile("tangential_b2", rho, nu)
            xx = xx + scale * (iso - (ux * ux - 0.5) * aniso)
            xy = xy - scale * ux * uy * aniso
            yy = yy + scale * (iso - (uy * uy - 0.5) * aniso)
        return xx, xy, yy

    def _layer_geometry(self) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
        """rho = r / h of each offset of the padded grid, and the unit vector (x^, y^) toward it (0 at r = 0,
        where the terms it multiplies vanish); computed once per kernel set."""
        assert self.thickness_mm is not None
        if self._layer_geom is None:
            r = np.hypot(self._x, self._y)
            safe = np.where(r > 0.0, r, 1.0)
            unit = (np.where(r > 0.0, self._x / safe, 0.0), np.where(r > 0.0, self._y / safe, 0.0))
            self._layer_geom = (r / self.thickness_mm, unit)
        return self._layer_geom

    def tangential(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(xx, xy, yy) spectra: traction (MPa) -> in-plane displacement (mm)."""
        if self._tangential is None:
            self._tangential = tuple(self._spectrum(k) for k in self._tangential_spatial())  # type: ignore[assignment]
        assert self._tangential is not None
        return self._tangential

    def tangential_centred(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(xx, xy, yy) influence coefficients (mm per MPa) as float32 (2 ny - 1, 2 nx - 1) arrays: entry
        (ny - 1 + dr, nx - 1 + dc) is the displacement of a cell dr rows and dc columns from the loaded one."""
        if self._tangential_centred is None:
            self._tangential_centred = tuple(  # type: ignore[assignment]
                np.fft.fftshift(k)[1:, 1:].astype(np.float32) for k in self._tangential_spatial())
        assert self._tangential_centred is not None
        return self._tangential_centred

    def tangential_single(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``tangential()`` in single precision (complex64), converted once."""
        if self._tangential_single is None:
            self._tangential_single = tuple(k.astype(np.complex64) for k in self.tangential())  # type: ignore[assignment]
        assert self._tangential_single is not None
        return self._tangential_single

    def in_plane_single(self) -> np.ndarray:
        """(2, 3, ...) complex64 spectra taking the rfft2 of (pressure, traction x, traction y) to in-plane
        displacement (x, y): ``[[rx, xx, xy], [ry, xy, yy]]``, built once."""
        if self._in_plane_single is None:
            (rx, ry), (xx, xy, yy) = self.radial(), self.tangential()
            self._in_plane_single = np.array([[rx, xx, xy], [ry, xy, yy]], dtype=np.complex64)
        return self._in_plane_single

    def radial(self) -> tuple[np.ndarray, np.ndarray]:
        """(rx, ry) spectra: normal pressure (MPa) -> in-plane displacement (mm), toward the load for nu < 0.5."""
        if self._radial is None:
            x, y, a, b = self._x, self._y, self._a, self._b
            c = -(1.0 - 2.0 * self.nu) / (4.0 * np.pi * self.g)
            rx = c * _corner_sum(_h_radial, x, y, a, b)
            ry = c * _corner_sum(_h_radial, y, x, b, a)
            if self.thickness_mm is not None:
                rho, (ux, uy) = self._layer_geometry()
                coupling = layer_profile("coupling", rho, self.nu) * (
                    2.0 * a * 2.0 * b / (2.0 * np.pi * self.g * self.thickness_mm))
                rx, ry = rx + ux * coupling, ry + uy * coupling
            self._radial = (self._spectrum(rx), self._spectrum(ry))
        return self._radial


@lru_cache(maxsize=64)
def kernel_set(shape: tuple[int, int], dx: float, dy: float, e_mpa: float, nu: float,
               thickness_mm: float | None = None) -> KernelSet:
    """Cached :class:`KernelSet` for a field of ``shape`` (ny, nx) cells of ``dx x dy`` mm; ``thickness_mm``:
    the coefficients are those of a bonded layer this thick (None: the half-space's)."""
    return KernelSet(shape, dx, dy, e_mpa, nu, thickness_mm)


def convolve(field: np.ndarray, spectrum: np.ndarray, pad_shape: tuple[int, int],
             rows: tuple[int, int] | None = None) -> np.ndarray:
    """Linear (non-circular) convolution of ``field`` (ny, nx) with a kernel given by its padded spectrum.
    ``rows``: (start, stop), the rows outside which ``field`` is zero, if known."""
    return padded_inverse(padded_spectrum(field, pad_shape, rows) * spectrum, pad_shape, field.shape)


# rfft2 and irfft2 over the zero-padded grid, one axis at a time, so that the transforms along each row run only
# on rows that matter: forward on the rows that hold the field (the padding and any rows known to be zero
# transform to zero), inverse on the rows of the grid (the padding is dropped): rfft2 and irfft2 transform the
# padding's rows too. Equal to float rounding (tested).


def padded_spectrum(fields: np.ndarray, pad_shape: tuple[int, int], rows: tuple[int, int] | None = None) -> np.ndarray:
    """``rfft2(fields, s=pad_shape)`` of ``fields`` (..., ny, nx), which are zero outside ``rows`` (start, stop)
    (None: all ny rows)."""
    (pad_rows, pad_cols), (r0, r1) = pad_shape, rows if rows is not None else (0, fields.shape[-2])
    spectra = np.zeros((*fields.shape[:-2], pad_rows, pad_cols // 2 + 1), np.result_type(fields, np.complex64))
    spectra[..., r0:r1, :] = sfft.rfft(fields[..., r0:r1, :], n=pad_cols, axis=-1, workers=1)
    return sfft.fft(spectra, axis=-2, workers=1, overwrite_x=True)


def padded_inverse(spectra: np.ndarray, pad_shape: tuple[int, int], shape: tuple[int, int]) -> np.ndarray:
    """``irfft2(spectra, s=pad_shape)[..., :ny, :nx]`` for ``shape`` (ny, nx)."""
    grid_rows = sfft.ifft(spectra, axis=-2, workers=1)[..., : shape[0], :]
    return sfft.irfft(grid_rows, n=pad_shape[1], axis=-1, workers=1)[..., : shape[1]]
