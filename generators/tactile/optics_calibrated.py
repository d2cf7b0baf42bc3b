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
(mm, positive into the gel) are binned with widths ``(pi/2) / (B - 1)`` and ``2 pi / (B - 1)``; the bin's
polynomials are evaluated at the pixel's position scaled to the calibration image, and added to ``f0``
resized to the sensor image. Flat pixels fall in bin (0, (B - 1) / 2) and are precomputed once. Taxim's own
smoothing of the pressed height map is the contact model's job here (:mod:`.contact_geometric`,
:mod:`.contact_elastic`), so it is not repeated. Shadows are not modelled.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.ndimage import zoom

from univtac_data.storage.errors import DatasetError

__all__ = ["TaximCalibration", "load_taxim_calibration", "taxim_calibration_dir"]


@dataclass(frozen=True, eq=False)
class TaximCalibration:
    """A loaded calibration. ``poly``: (3, B, B, 6) float64 RGB. ``f0``: (h, w, 3) float64 RGB grey levels.
    ``pixmm``: mm per calibration pixel, or None when the folder has no params.json."""

    poly: np.ndarray
    f0: np.ndarray
    pixmm: float | None
    _cache: dict[tuple[int, int], tuple[np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=dict, repr=False)

    @property
    def bins(self) -> int:
        return int(self.poly.shape[1])

    def _prepared(self, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(features (H, W, 6), background (H, W, 3), flat image (H, W, 3)) for an image size, cached."""
        if shape not in self._cache:
            h, w = shape
            ch, cw = self.f0.shape[:2]
            y, x = np.meshgrid(np.arange(h) * (ch / h), np.arange(w) * (cw / w), indexing="ij")
            feats = np.stack([x * x, y * y, x * y, x, y, np.ones_like(x)], axis=-1)
            bg = zoom(self.f0, (h / ch, w / cw, 1), order=1, grid_mode=True, mode="nearest")
            flat = bg + feats @ self.poly[:, 0, (self.bins - 1) // 2].T
            self._cache[shape] = (feats, bg, flat)
        return self._cache[shape]

    def render(self, depth_mm: np.ndarray, mm_per_px: tuple[float, float], depth_floor_mm: float = 1e-5) -> np.ndarray:
        """I_pure (H, W, 3) uint8 from the depth map (H, W) mm; ``mm_per_px`` = (x, y) pixel pitch, mm."""
        feats, bg, flat = self._prepared(depth_mm.shape)
        img = flat.copy()
        g_row, g_col = np.gradient(depth_mm, mm_per_px[1], mm_per_px[0])
        slope = np.hypot(g_row, g_col)
        sel = (slope > 0.0) & (depth_mm > depth_floor_mm)
        if sel.any():
            b = self.bins
            mag = np.arctan(slope[sel])
            direction = np.arctan2(g_row[sel], g_col[sel])
            i_mag = np.clip(np.floor(mag / (0.5 * np.pi / (b - 1))).astype(np.intp), 0, b - 1)
            i_dir = np.clip(np.floor((direction + np.pi) / (2.0 * np.pi / (b - 1))).astype(np.intp), 0, b - 1)
            coeffs = self.poly[:, i_mag, i_dir]  # (3, n, 6)
            img[sel] = bg[sel] + np.einsum("cnk,nk->nc", coeffs, feats[sel])
        return np.clip(np.rint(img), 0, 255).astype(np.uint8)


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
