"""Markers: current positions from the in-plane surface displacement, and drawing them on the image.

Positions: reference grid (mm, :func:`.sensor_model.marker_reference_mm`) + in-plane displacement sampled
bilinearly at the reference points, then projected with the pinhole model at the marker's height z = -D
(a pressed marker is nearer the camera, so it also moves outward in the image, as on the real sensor).

Drawing: each marker is a dark disc of ``radius_px`` with a one-pixel anti-aliased rim (coverage
``clip(radius + 0.5 - distance, 0, 1)``), blended over the pure image. Pixels farther than
``radius + 0.5`` px from every marker centre are never written, so I_marked equals I_pure there bit for bit.
"""

from __future__ import annotations

import numpy as np

__all__ = ["draw_markers", "sample_bilinear"]


def sample_bilinear(field: np.ndarray, x_axis: np.ndarray, y_axis: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Sample (..., ny, nx) fields on a regular grid (centres ``x_axis`` (nx,), ``y_axis`` (ny,)) at
    ``points`` (N, 2) (x, y) -> (..., N). Points outside the grid take the nearest edge value."""
    fx = np.clip((points[:, 0] - x_axis[0]) / (x_axis[1] - x_axis[0]), 0.0, x_axis.size - 1.0)
    fy = np.clip((points[:, 1] - y_axis[0]) / (y_axis[1] - y_axis[0]), 0.0, y_axis.size - 1.0)
    x0 = np.minimum(fx.astype(np.intp), x_axis.size - 2)
    y0 = np.minimum(fy.astype(np.intp), y_axis.size - 2)
    tx, ty = fx - x0, fy - y0
    f00, f01 = field[..., y0, x0], field[..., y0, x0 + 1]
    f10, f11 = field[..., y0 + 1, x0], field[..., y0 + 1, x0 + 1]
    return (f00 * (1 - tx) + f01 * tx) * (1 - ty) + (f10 * (1 - tx) + f11 * tx) * ty


def draw_markers(
    pure_rgb: np.ndarray, markers_px: np.ndarray, radius_px: float, marker_rgb: tuple[int, int, int]
) -> np.ndarray:
    """I_marked (H, W, 3) uint8: ``pure_rgb`` with anti-aliased discs at ``markers_px`` (N, 2) (u, v) px."""
    h, w, _ = pure_rgb.shape
    half = int(np.ceil(radius_px + 1.5))
    offs = np.arange(-half, half + 1)
    centres = np.asarray(markers_px, dtype=np.float64)
    base = np.floor(centres).astype(np.intp)
    cols = base[:, 0, None, None] + offs[None, None, :]  # (N, 1, P)
    rows = base[:, 1, None, None] + offs[None, :, None]  # (N, P, 1)
    # float32 and a plain square root: the coverage is quantised to 1/255 anyway, and this runs every frame
    du = (cols - centres[:, 0, None, None]).astype(np.float32)
    dv = (rows - centres[:, 1, None, None]).astype(np.float32)
    alpha = np.float32(radius_px + 0.5) - np.sqrt(du * du + dv * dv)
    np.clip(alpha, 0.0, 1.0, out=alpha)
    keep = (alpha > 0.0) & (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    flat = (rows * w + cols)[keep]
    a = alpha[keep]
    if _may_overlap(centres, half):
        # several markers cover a pixel: keep the largest coverage
        order = np.argsort(flat, kind="stable")
        flat, a = flat[order], a[order]
        starts = np.flatnonzero(np.r_[True, flat[1:] != flat[:-1]])
        flat, a = flat[starts], np.maximum.reduceat(a, starts)
    out = pure_rgb.copy()
    # one flat index per channel value: 1-D take/put is several times faster than indexing (H W, 3) rows
    channels = (flat.astype(np.int32)[:, None] * 3 + np.arange(3, dtype=np.int32)).ravel()
    flat_out = out.reshape(-1)
    under = flat_out.take(channels).astype(np.float32).reshape(-1, 3)
    blended = under + (np.asarray(marker_rgb, dtype=np.float32) - under) * a[:, None]
    flat_out.put(channels, np.rint(blended).astype(np.uint8))
    return out


def _may_overlap(centres: np.ndarray, half: int) -> bool:
    """True when two markers' drawing patches (side 2 half + 1 px) can share a pixel."""
    if len(centres) < 2:
        return False
    du = np.abs(np.subtract.outer(centres[:, 0], centres[:, 0]))
    dv = np.abs(np.subtract.outer(centres[:, 1], centres[:, 1]))
    close = (du <= 2 * half + 1) & (dv <= 2 * half + 1)
    return int(np.count_nonzero(close)) > len(centres)
