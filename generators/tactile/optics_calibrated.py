"""Calibrated optical model in the Taxim format (Si & Yuan, "Taxim: An Example-based Simulation Model for
GelSight Tactile Sensors", RA-L 2022), implemented from the paper's description.

A calibration folder holds
* ``polycalib.npz``: ``bins`` (scalar, B = 125 in the published calibrations) and ``grad_r``, ``grad_g``,
  ``grad_b``, each (B, B, 6): for every bin of the surface normal's magnitude (slope angle in [0, pi/2]) and
  direction (in [-pi, pi]), a polynomial in the pixel position ``(x^2, y^2, x y, x, y, 1)`` giving the
  intensity change (grey levels) of one colour channel; x is the column and y the row in calibration pixels;
* ``dataPack.npz``: ``f0`` (h, w, 3) uint8, the real untouched-gel frame;
* optionally ``params.json`` with ``sensor.pixmm`` (mm per calibration pixel).

The files were written with OpenCV, so channels are in BGR order: ``f0`` is BGR and the table named
``grad_r`` drives the first (blue) channel. This reader returns RGB.

Rendering: the slope angle ``atan(|grad D|)`` and direction ``atan2(dD/drow, dD/dcol)`` of the depth map D
(mm, positive into the gel) are binned with widths ``(pi/2) / (B - 1)`` and ``2 pi / (B - 1)``, and the bin's
polynomials are evaluated at the pixel's position scaled to the calibration image (the image spans the
calibration's frame). Two departures from Taxim, both so that a contact changes only what it deforms:

* **a flat gel renders as f0.** Taxim adds the flat bin's polynomial to ``f0`` everywhere, and that polynomial,
  fitted on presses near the centre, is far from zero: on the GelSight Mini calibration it shifts the untouched
  gel by +10.8 / +15.6 / +22.2 grey levels (R, G, B means; -31 to +47 across the image). Here each pixel gets
  its bin's polynomial minus the flat bin's at that position, so an untouched pad is ``f0`` (resized) exactly;
* **slopes in the first magnitude bin (below 0.73 deg) are flat.** That bin's 125 direction polynomials differ
  from the flat one by up to 20 grey levels on the Mini calibration (fitting noise: the calibration cannot tell
  the direction of so small a slope), so in Taxim a sink-in of a micrometre repaints whole regions.

Fast path (``render``): the image starts as the precomputed ``f0`` and only pixels that are deformed (D above
``depth_floor_mm``) with a slope in the second magnitude bin or beyond are looked up (the first bin is flat, see
above; every later bin moves the colour by more than half a grey level somewhere on the Mini calibration: by
6.8 grey levels at the median already in the second), in one compiled pass, row by row: the gradient and fitted
slope angles of a row without branches, then the lookups, so a Mini frame (320 x 240) whose every pixel has a
slope costs about a millisecond. ``render_lookup`` is the plain per-pixel lookup of every pixel, which it equals
within one grey level, with the same bin for every pixel (tested). Taxim's own smoothing of the pressed
height map is the contact model's job here (:mod:`.contact_geometric`, :mod:`.contact_elastic`), so it is not
repeated. Shadows are not modelled.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numba
import numpy as np
from scipy.ndimage import zoom

from univtac_data.storage.errors import DatasetError

__all__ = ["TaximCalibration", "load_taxim_calibration", "taxim_calibration_dir"]


FLAT_MAGNITUDE_BINS = 1  # slopes in the first magnitude bin render as the flat gel (see the module docstring)


@dataclass(frozen=True)
class _Prepared:
    """Per image size: ``background`` (H, W, 3) float64 and ``background_u8`` uint8, ``f0`` resized;
    ``delta`` (B, B, 3, 6) float64, each bin's polynomials minus the flat bin's; ``min_slope``: slopes below it
    render as the flat gel. Float64, not float32: the lookup converts nothing then, a quarter faster."""

    background: np.ndarray
    background_u8: np.ndarray
    delta: np.ndarray
    min_slope: float


@dataclass(frozen=True, eq=False)
class TaximCalibration:
    """A loaded calibration. ``poly``: (3, B, B, 6) float64 RGB. ``f0``: (h, w, 3) float64 RGB grey levels.
    ``pixmm``: mm per calibration pixel, or None when the folder has no params.json."""

    poly: np.ndarray
    f0: np.ndarray
    pixmm: float | None
    _cache: dict[tuple[int, int], _Prepared] = field(default_factory=dict, repr=False)

    @property
    def bins(self) -> int:
        return int(self.poly.shape[1])

    @property
    def field_mm(self) -> tuple[float, float] | None:
        """(width, height) of the calibration's frame in mm, or None without ``pixmm``."""
        if self.pixmm is None:
            return None
        return (self.f0.shape[1] * self.pixmm, self.f0.shape[0] * self.pixmm)

    def _prepared(self, shape: tuple[int, int]) -> _Prepared:
        if shape not in self._cache:
            h, w = shape
            ch, cw = self.f0.shape[:2]
            bg = zoom(self.f0, (h / ch, w / cw, 1), order=1, grid_mode=True, mode="nearest")
            flat = self.poly[:, 0, (self.bins - 1) // 2]
            # (B, B, 3, 6): a bin's three polynomials side by side, one or two cache lines per lookup
            delta = np.ascontiguousarray((self.poly - flat[:, None, None, :]).transpose(1, 2, 0, 3), dtype=np.float64)
            background = np.ascontiguousarray(bg, dtype=np.float64)
            u8 = np.clip(np.rint(bg), 0, 255).astype(np.uint8)
            for array in (background, u8, delta):
                array.setflags(write=False)
            width = 0.5 * np.pi / (self.bins - 1)
            self._cache[shape] = _Prepared(background, u8, delta, float(np.tan(FLAT_MAGNITUDE_BINS * width)))
        return self._cache[shape]

    def background(self, shape: tuple[int, int]) -> np.ndarray:
        """(H, W, 3) uint8: the flat gel, ``f0`` resized to ``shape`` (read-only)."""
        return self._prepared(shape).background_u8

    def render(self, depth_mm: np.ndarray, mm_per_px: tuple[float, float], depth_floor_mm: float = 1e-5,
               out: np.ndarray | None = None) -> np.ndarray:
        """I_pure (H, W, 3) uint8 from the depth map (H, W) mm; ``mm_per_px`` = (x, y) pixel pitch, mm.
        ``out``: (H, W, 3) uint8 C-contiguous to write into. Only deformed pixels with a slope are looked up."""
        h, w = depth_mm.shape
        prep = self._prepared((h, w))
        if out is None:
            out = np.empty((h, w, 3), np.uint8)
        elif out.shape != (h, w, 3) or out.dtype != np.uint8 or not out.flags.c_contiguous:
            raise ValueError(f"out must be ({h}, {w}, 3) uint8 C-contiguous (got {out.shape} {out.dtype})")
        out[...] = prep.background_u8
        ch, cw = self.f0.shape[:2]
        _lookup(np.ascontiguousarray(depth_mm, dtype=np.float64), 1.0 / mm_per_px[1], 1.0 / mm_per_px[0],
                depth_floor_mm, prep.min_slope * prep.min_slope, self.bins, prep.delta, prep.background, ch / h,
                cw / w, out)
        return out

    def render_lookup(self, depth_mm: np.ndarray, mm_per_px: tuple[float, float],
                      depth_floor_mm: float = 1e-5) -> np.ndarray:
        """The plain per-pixel lookup (array code, float64) of every deformed pixel with a slope: the oracle
        that :meth:`render` equals within one grey level."""
        h, w = depth_mm.shape
        ch, cw = self.f0.shape[:2]
        bg = zoom(self.f0, (h / ch, w / cw, 1), order=1, grid_mode=True, mode="nearest")
        img = bg.copy()
        g_row, g_col = np.gradient(depth_mm, mm_per_px[1], mm_per_px[0])
        slope = np.hypot(g_row, g_col)
        sel = (slope > 0.0) & (depth_mm > depth_floor_mm)
        if sel.any():
            b = self.bins
            y, x = np.meshgrid(np.arange(h) * (ch / h), np.arange(w) * (cw / w), indexing="ij")
            feats = np.stack([x * x, y * y, x * y, x, y, np.ones_like(x)], axis=-1)[sel]
            i_mag = np.clip(np.floor(np.arctan(slope[sel]) / (0.5 * np.pi / (b - 1))).astype(np.intp), 0, b - 1)
            direction = np.arctan2(g_row[sel], g_col[sel])
            i_dir = np.clip(np.floor((direction + np.pi) / (2.0 * np.pi / (b - 1))).astype(np.intp), 0, b - 1)
            change = np.einsum("cnk,nk->nc", self.poly[:, i_mag, i_dir], feats) - \
                np.einsum("ck,nk->nc", self.poly[:, 0, (b - 1) // 2], feats)
            img[sel] = bg[sel] + np.where((i_mag < FLAT_MAGNITUDE_BINS)[:, None], 0.0, change)
        return np.clip(np.rint(img), 0, 255).astype(np.uint8)


# atan(t) = t P(t^2) on [0, 1]: a least-squares fit, at most ATAN_FIT_ERROR_RAD from atan (tested). The bins are
# 0.0127 rad (slope angle) and 0.0507 rad (direction) wide, so the fit can misplace a pixel only within
# BIN_EDGE_RAD of a bin edge; those few pixels are binned again with the exact libm arctan. The fitted angles
# of a whole row are computed without branches (the compiler vectorises them): two libm calls a pixel cost
# more than the rest of the lookup together.
ATAN_COEFFS = (0.9999966343, -0.3331830143, 0.1981319952, -0.132474675, 0.07981016611, -0.03372501481,
               0.006842312795)
ATAN_FIT_ERROR_RAD = 2.7e-7
BIN_EDGE_RAD = 1e-5
_A0, _A1, _A2, _A3, _A4, _A5, _A6 = ATAN_COEFFS


@numba.njit(cache=True, nogil=True, inline="always")
def _atan_unit(t: float) -> float:  # pragma: no cover (compiled)
    u = t * t
    return t * (_A0 + u * (_A1 + u * (_A2 + u * (_A3 + u * (_A4 + u * (_A5 + u * _A6))))))


@numba.njit(cache=True, nogil=True, error_model="numpy")
def fitted_angles(g_row: np.ndarray, g_col: np.ndarray, slope_angle: np.ndarray,
                  direction: np.ndarray) -> None:  # pragma: no cover (compiled)
    """Per element of the gradient (``g_row``, ``g_col``), ``slope_angle`` = atan(|g|) in [0, pi/2] and
    ``direction`` = atan2(g_row, g_col) in [-pi, pi] (rad), each within ``ATAN_FIT_ERROR_RAD``; a zero gradient
    gives NaN (the caller skips those)."""
    half_pi = 0.5 * np.pi
    for j in range(g_row.size):
        a, b = g_row[j], g_col[j]
        s = np.sqrt(a * a + b * b)
        big = s > 1.0
        t = _atan_unit(1.0 / s if big else s)
        slope_angle[j] = half_pi - t if big else t
        ay, ax = abs(a), abs(b)
        steep = ay > ax
        t = _atan_unit((ax / ay) if steep else (ay / ax))
        t = half_pi - t if steep else t
        t = np.pi - t if b < 0.0 else t
        direction[j] = -t if a < 0.0 else t


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _lookup(depth: np.ndarray, inv_dy: float, inv_dx: float, floor: float, min_slope2: float, bins: int,
            delta: np.ndarray, background: np.ndarray, scale_y: float, scale_x: float,
            out: np.ndarray) -> None:  # pragma: no cover (compiled)
    # out holds f0 already; each deformed pixel whose slope (numpy.gradient's differences: central inside the
    # image, one-sided on its edges) reaches min_slope gets f0 plus its bin's change at its calibration
    # position. Row by row, skipping rows with no deformed pixel (a pixel is looked up only if it is deformed
    # itself): the gradient and the fitted angles of the whole row (a span of it would not vectorise), then the
    # lookups over the row's deformed span.
    h, w = depth.shape
    inv_mag_width = (bins - 1) / (0.5 * np.pi)
    inv_dir_width = (bins - 1) / (2.0 * np.pi)
    mag_margin, dir_margin = BIN_EDGE_RAD * inv_mag_width, BIN_EDGE_RAD * inv_dir_width
    g_row, g_col = np.zeros(w), np.zeros(w)
    slope_angle, direction = np.empty(w), np.empty(w)
    half_dx = 0.5 * inv_dx
    for i in range(h):
        depth_row = depth[i]
        c0 = 0
        while c0 < w and depth_row[c0] <= floor:
            c0 += 1
        if c0 == w:
            continue
        c1 = w
        while depth_row[c1 - 1] <= floor:
            c1 -= 1
        up, down = max(i - 1, 0), min(i + 1, h - 1)
        sy = inv_dy / (down - up) if down > up else 0.0
        depth_up, depth_down = depth[up], depth[down]
        for j in range(w):
            g_row[j] = (depth_down[j] - depth_up[j]) * sy
        for j in range(1, w - 1):
            g_col[j] = (depth_row[j + 1] - depth_row[j - 1]) * half_dx
        if w > 1:
            g_col[0] = (depth_row[1] - depth_row[0]) * inv_dx
            g_col[w - 1] = (depth_row[w - 1] - depth_row[w - 2]) * inv_dx
        fitted_angles(g_row, g_col, slope_angle, direction)
        y = i * scale_y
        yy = y * y
        for j in range(c0, c1):
            if depth_row[j] <= floor:
                continue
            s2 = g_row[j] * g_row[j] + g_col[j] * g_col[j]
            if s2 < min_slope2 or s2 == 0.0:
                continue
            v = slope_angle[j] * inv_mag_width
            i_mag = int(v)
            if v - i_mag < mag_margin or v - i_mag > 1.0 - mag_margin:
                i_mag = int(np.arctan(np.sqrt(s2)) * inv_mag_width)
            v = (direction[j] + np.pi) * inv_dir_width
            i_dir = int(v)
            if v - i_dir < dir_margin or v - i_dir > 1.0 - dir_margin:
                i_dir = int((np.arctan2(g_row[j], g_col[j]) + np.pi) * inv_dir_width)
            i_mag = min(i_mag, bins - 1)
            i_dir = min(max(i_dir, 0), bins - 1)
            x = j * scale_x
            xx, xy = x * x, x * y
            q = delta[i_mag, i_dir]
            for c in range(3):
                v = background[i, j, c] + (q[c, 0] * xx + q[c, 1] * yy + q[c, 2] * xy + q[c, 3] * x
                                           + q[c, 4] * y + q[c, 5])
                out[i, j, c] = np.uint8(min(max(np.rint(v), 0.0), 255.0))


def load_taxim_calibration(folder: str | Path) -> TaximCalibration:
    """Read a Taxim-format calibration folder; a missing or malformed file raises ``DatasetError`` naming it."""
    folder = Path(folder)
    poly_path, pack_path = folder / "polycalib.npz", folder / "dataPack.npz"
    for path in (poly_path, pack_path):
        if not path.is_file():
            raise DatasetError(f"{path}: Taxim calibration file not found")
    try:
        with np.load(poly_path) as data:
            poly = np.stack([data["grad_b"], data["grad_g"], data["grad_r"]]).astype(np.float64)
        with np.load(pack_path) as data:
            f0 = np.asarray(data["f0"], dtype=np.float64)[..., ::-1].copy()
    except (KeyError, ValueError, OSError) as exc:
        raise DatasetError(f"{folder}: not a Taxim calibration ({exc})") from None
    if poly.ndim != 4 or poly.shape[1] != poly.shape[2] or poly.shape[3] != 6 or f0.ndim != 3 or f0.shape[2] != 3:
        raise DatasetError(
            f"{poly_path}: expected grad_* (B, B, 6) and f0 (h, w, 3) (got {poly.shape[1:]} and {f0.shape})"
        )
    pixmm = None
    params = folder / "params.json"
    if params.is_file():
        pixmm = float(json.loads(params.read_text())["sensor"]["pixmm"])
    return TaximCalibration(poly=poly, f0=f0, pixmm=pixmm)


def taxim_calibration_dir(name: str = "gelsight_mini") -> Path:
    """Folder of a calibration shipped with the optional ``taxim`` package (``pip install taxim``)."""
    try:
        import taxim  # noqa: F401  (optional extra)
    except ImportError:
        raise DatasetError("taxim calibration: the optional package 'taxim' is not installed (pip install taxim)") from None
    folder = Path(taxim.__file__).parent / "calib" / name
    if not folder.is_dir():
        raise DatasetError(f"{folder}: no Taxim calibration named {name!r}")
    return folder
