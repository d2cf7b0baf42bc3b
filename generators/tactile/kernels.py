"""Influence coefficients of a linear-elastic half-space (or, for the normal response, of a layer bonded to
a rigid backing) for uniform tractions on rectangular cells, and their zero-padded FFT convolution.

A cell of size ``dx x dy`` (mm) carries a uniform traction (MPa). The surface displacement (mm) it causes at
offset (X, Y) = (x - x_cell, y - y_cell) is the integral of the point-load solution over the cell:

* normal pressure -> normal displacement (Boussinesq, integrated by Love 1929):
  ``u_z = 1 / (pi E*) * S[F]``, ``F(X, Y) = X asinh(Y/|X|) + Y asinh(X/|Y|)`` (the primitive of 1/r);
* normal pressure -> in-plane displacement (radial, zero for nu = 0.5):
  ``u_x = -(1 - 2 nu) / (4 pi G) * S[Hr]``, ``Hr(X, Y) = X atan(Y/X) + Y/2 ln(X^2 + Y^2)`` (primitive of X/r^2);
* tangential traction along x -> in-plane displacement (Cerruti):
  ``u_x = 1 / (2 pi G) * S[(1 - nu) F + nu Hxx]``, ``Hxx(X, Y) = Y asinh(X/|Y|)`` (primitive of X^2/r^3),
  ``u_y = nu / (2 pi G) * S[-r]`` (primitive of XY/r^3), and symmetrically for a traction along y.

Finite gel layer (normal response only). A layer of thickness h bonded to a rigid backing, loaded by a
normal pressure on its free surface, has the surface compliance (2-D Fourier transform, wavenumber k)

    u_z~(k) / p~(k) = 2 / (E* k) * R(k h),
    R(s) = (kappa sinh 2s - 2s) / (kappa cosh 2s + 2 s^2 + (1 + kappa^2) / 2),   kappa = 3 - 4 nu,

from Navier's equations in plane strain (the surface problem depends on |k| only) with a traction-free,
pressure-loaded top and zero displacement at the base; the tests rederive it. R -> 1 for k h >> 1 (the
half-space, Boussinesq's 2 / (E* k)); for k h << 1 it gives the oedometric thin layer h (1 + nu)(1 - 2 nu) /
(E (1 - nu)), and for nu = 1/2 the squeeze-film law k^2 h^3 / (3 G). In space the layer's influence is the
half-space's plus a smooth correction,

    c(r) = 1 / (pi E* h) * D(r / h),   D(rho) = integral_0^inf (R(s) - 1) J0(s rho) ds,

which cancels the half-space's 1/r tail (D -> -1/rho): the layer's response dies off within a few
thicknesses instead of like 1/r, and it is negative (a pile-up) from about one thickness out. The correction
varies on the scale of h (2 to 4 mm), so it is sampled at cell centres (times the cell area) and added to the
cell-integrated half-space coefficients. The tangential (Cerruti) and radial coefficients stay half-space.

``S[f]`` is the four-corner sum ``f(X+a, Y+b) - f(X+a, Y-b) - f(X-a, Y+b) + f(X-a, Y-b)`` with ``a = dx/2``,
``b = dy/2``. The tangential -> normal coupling (proportional to 1 - 2 nu, small for silicone at nu ~ 0.48) is
neglected. E* = E / (1 - nu^2), G = E / (2 (1 + nu)).

Convolutions are circular FFTs over a grid padded to twice the field size in each direction, so a field of
(ny, nx) cells sees every other cell of the same grid exactly (no wrap-around). Kernel spectra are cached per
(shape, cell size, material).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import scipy.fft as sfft
from scipy.special import j0

__all__ = ["KernelSet", "convolve", "kernel_set", "layer_compliance_ratio", "layer_correction_profile"]

# D(rho) is tabulated on [0, LAYER_RHO_MAX] and taken as -1/rho beyond, where the two differ by < 1e-6
# (relative 1e-5); the integrand (R - 1) has decayed below 1e-25 at s = LAYER_S_MAX.
LAYER_RHO_MAX = 16.0
LAYER_S_MAX = 30.0
_LAYER_RHO_STEP = 0.01
_LAYER_S_STEP = 0.005


def layer_compliance_ratio(s: np.ndarray, nu: float) -> np.ndarray:
    """R(s), s = k h >= 0: the bonded layer's normal surface compliance over the half-space's (see the module
    docstring). Written with exp(-2 s) so that large s does not overflow."""
    s = np.asarray(s, dtype=np.float64)
    kappa = 3.0 - 4.0 * nu
    e2 = np.exp(-2.0 * s)
    sech = 2.0 * e2 / (1.0 + e2 * e2)
    tanh = (1.0 - e2 * e2) / (1.0 + e2 * e2)
    return (kappa * tanh - 2.0 * s * sech) / (kappa + (2.0 * s * s + 0.5 * (1.0 + kappa * kappa)) * sech)


@lru_cache(maxsize=8)
def _layer_table(nu: float) -> np.ndarray:
    s = np.arange(0.0, LAYER_S_MAX + _LAYER_S_STEP / 2, _LAYER_S_STEP)
    weights = np.full(s.size, _LAYER_S_STEP)
    weights[[0, -1]] = _LAYER_S_STEP / 2  # trapezoid: within 2e-7 of adaptive quadrature on this integrand
    weighted = (layer_compliance_ratio(s, nu) - 1.0) * weights
    rho = np.arange(0.0, LAYER_RHO_MAX + _LAYER_RHO_STEP / 2, _LAYER_RHO_STEP)
    return np.array([float(np.dot(weighted, j0(s * r))) for r in rho])


def layer_correction_profile(rho: np.ndarray, nu: float) -> np.ndarray:
    """D(rho) of the module docstring at rho = r / h >= 0 (dimensionless; the correction to the influence of a
    point load P is P / (pi E* h) D)."""
    rho = np.asarray(rho, dtype=np.float64)
    table = _layer_table(float(nu))
    inside = np.interp(rho, np.arange(table.size) * _LAYER_RHO_STEP, table)
    with np.errstate(divide="ignore"):
        return np.where(rho <= LAYER_RHO_MAX, inside, -1.0 / np.maximum(rho, LAYER_RHO_MAX))


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

    ``zz``: pressure -> u_z (mm per MPa; of the layer when ``thickness_mm`` is given);
    ``rx``/``ry``: pressure -> u_x / u_y (radial term);
    ``xx``, ``xy``, ``yy``: tangential traction -> in-plane displacement (``xy`` serves both couplings).
    Spatial kernels are built lazily, the normal one always.
    """

    def __init__(self, shape: tuple[int, int], dx: float, dy: float, e_mpa: float, nu: float,
                 thickness_mm: float | None = None) -> None:
        self.shape = shape
        self.thickness_mm = thickness_mm
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
            rho = np.hypot(self._x, self._y) / thickness_mm
            zz_spatial += layer_correction_profile(rho, nu) * (dx * dy / (np.pi * self.e_star * thickness_mm))
        self.zz = self._spectrum(zz_spatial)
        self._zz_single: np.ndarray | None = None
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

    def add_cells(self, field: np.ndarray, rows: np.ndarray, cols: np.ndarray, values: np.ndarray) -> None:
        """``field`` (ny, nx) += the normal displacement (mm) of pressures ``values`` (MPa) on cells
        (``rows``, ``cols``): the convolution of a few cells without a transform."""
        ny, nx = self.shape
        for r, c, v in zip(rows.tolist(), cols.tolist(), values.tolist(), strict=True):
            field += np.float32(v) * self.zz_centred[ny - 1 - r : 2 * ny - 1 - r, nx - 1 - c : 2 * nx - 1 - c]

    def _tangential_spatial(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        x, y, a, b, nu, g = self._x, self._y, self._a, self._b, self.nu, self.g
        f = _corner_sum(_f_inv_r, x, y, a, b)
        c = 1.0 / (2.0 * np.pi * g)
        return (c * ((1.0 - nu) * f + nu * _corner_sum(_h_xx, x, y, a, b)),
                c * nu * _corner_sum(_h_xy, x, y, a, b),
                c * ((1.0 - nu) * f + nu * _corner_sum(_h_xx, y, x, b, a)))

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
            self._radial = (
                self._spectrum(c * _corner_sum(_h_radial, x, y, a, b)),
                self._spectrum(c * _corner_sum(_h_radial, y, x, b, a)),
            )
        return self._radial


@lru_cache(maxsize=64)
def kernel_set(shape: tuple[int, int], dx: float, dy: float, e_mpa: float, nu: float,
               thickness_mm: float | None = None) -> KernelSet:
    """Cached :class:`KernelSet` for a field of ``shape`` (ny, nx) cells of ``dx x dy`` mm; ``thickness_mm``:
    the normal response is that of a bonded layer this thick (None: half-space)."""
    return KernelSet(shape, dx, dy, e_mpa, nu, thickness_mm)


def convolve(field: np.ndarray, spectrum: np.ndarray, pad_shape: tuple[int, int]) -> np.ndarray:
    """Linear (non-circular) convolution of ``field`` (ny, nx) with a kernel given by its padded spectrum."""
    ny, nx = field.shape
    out = sfft.irfft2(sfft.rfft2(field, s=pad_shape, workers=1) * spectrum, s=pad_shape, workers=1)
    return out[:ny, :nx]
