"""Markers: current positions from the in-plane surface displacement, and drawing them on the image.

Positions: reference grid (mm, :func:`.sensor_model.marker_reference_mm`) + in-plane displacement sampled
bilinearly at the reference points, then projected with the pinhole model at the marker's height z = -D
(a pressed marker is nearer the camera, so it also moves outward in the image, as on the real sensor).

Drawing: each marker is a dark disc of ``radius_px`` with a one-pixel anti-aliased rim (coverage
``clip(radius + 0.5 - distance, 0, 1)``), blended over the pure image. Pixels farther than
``radius + 0.5`` px from every marker centre are never written, so I_marked equals I_pure there bit for bit.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["draw_markers", "sample_bilinear"]


def sample_bilinear(field: np.ndarray, x_axis: np.ndarray, y_axis: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Sample (..., ny, nx) fields on a regular grid (centres ``x_axis`` (nx,), ``y_axis`` (ny,)) at
    ``points`` (N, 2) (x, y) -> (..., N) float64. Points outside the grid take the nearest edge value."""
    # float64 whatever the field (the kernel reads float64 anyway): one compiled signature, not one per dtype
    stack = np.ascontiguousarray(field, dtype=np.float64).reshape(-1, *field.shape[-2:])
    points = np.ascontiguousarray(points, dtype=np.float64)
    out = _sample_bilinear(stack, float(x_axis[0]), float(x_axis[1] - x_axis[0]), x_axis.size,
                           float(y_axis[0]), float(y_axis[1] - y_axis[0]), y_axis.size, points)
    return out.reshape(*field.shape[:-2], points.shape[0])


@numba.njit(cache=True, nogil=True)
def _sample_bilinear(stack: np.ndarray, x0: float, dx: float, nx: int, y0: float, dy: float, ny: int,
                     points: np.ndarray) -> np.ndarray:  # pragma: no cover (compiled)
    # compiled: a hundred markers on two or three fields, where array code paid a dozen calls for each
    out = np.empty((stack.shape[0], points.shape[0]))
    for n in range(points.shape[0]):
        fx = min(max((points[n, 0] - x0) / dx, 0.0), nx - 1.0)
        fy = min(max((points[n, 1] - y0) / dy, 0.0), ny - 1.0)
        i, j = min(int(fy), ny - 2), min(int(fx), nx - 2)
        tx, ty = fx - j, fy - i
        for k in range(stack.shape[0]):
            f00, f01 = np.float64(stack[k, i, j]), np.float64(stack[k, i, j + 1])
            f10, f11 = np.float64(stack[k, i + 1, j]), np.float64(stack[k, i + 1, j + 1])
            out[k, n] = (f00 * (1 - tx) + f01 * tx) * (1 - ty) + (f10 * (1 - tx) + f11 * tx) * ty
    return out


def draw_markers(
    pure_rgb: np.ndarray, markers_px: np.ndarray, radius_px: float, marker_rgb: tuple[int, int, int],
    out: np.ndarray | None = None,
) -> np.ndarray:
    """I_marked (H, W, 3) uint8: ``pure_rgb`` with anti-aliased discs at ``markers_px`` (N, 2) (u, v) px.

    Each pixel within a disc's reach takes coverage ``a = clip(radius + 0.5 - distance, 0, 1)`` in float32 (the
    largest over the markers that reach it) and becomes ``rint(under + (marker - under) * a)``. ``out``: a
    C-contiguous (H, W, 3) uint8 array to write into and return (not ``pure_rgb`` itself)."""
    if out is None:
        out = np.array(pure_rgb, dtype=np.uint8, order="C", copy=True)
    else:
        if out.shape != pure_rgb.shape or out.dtype != np.uint8 or not out.flags.c_contiguous:
            raise ValueError(f"out must be C-contiguous {pure_rgb.shape} uint8 (got {out.shape} {out.dtype})")
        if np.may_share_memory(out, pure_rgb):
            raise ValueError("out must not share memory with pure_rgb (I_pure stays unmarked)")
        out[...] = pure_rgb
    h, w, _ = out.shape
    centres = np.ascontiguousarray(markers_px, dtype=np.float64).reshape(-1, 2)
    _draw_discs(out.reshape(-1), h, w, centres, np.float32(radius_px + 0.5), int(np.ceil(radius_px + 1.5)),
                np.asarray(marker_rgb, dtype=np.float32))
    return out


@numba.njit(cache=True, nogil=True)
def _draw_discs(out: np.ndarray, h: int, w: int, centres: np.ndarray, reach: np.float32, half: int,
                marker_rgb: np.ndarray) -> None:  # pragma: no cover (compiled)
    # one compiled pass: a marker touches about a hundred pixels, where array code pays per call, not per pixel.
    if _discs_apart(centres, reach):
        # no pixel is within reach of two markers (so on any gel not sheared by a marker spacing): each pixel
        # is blended once, from its marker's coverage, with no image-sized coverage buffer to clear and fill
        for k in range(centres.shape[0]):
            cu, cv = centres[k, 0], centres[k, 1]
            base_u, base_v = int(np.floor(cu)), int(np.floor(cv))
            for row in range(max(base_v - half, 0), min(base_v + half + 1, h)):
                dv = np.float32(row - cv)
                for col in range(max(base_u - half, 0), min(base_u + half + 1, w)):
                    du = np.float32(col - cu)
                    alpha = reach - np.sqrt(du * du + dv * dv)
                    if alpha > np.float32(0.0):
                        _blend(out, row * w + col, min(alpha, np.float32(1.0)), marker_rgb)
        return
    # pass 1 keeps each touched pixel's largest coverage (markers overlap); pass 2 blends every pixel once
    coverage = np.zeros(h * w, dtype=np.float32)
    touched = np.empty(centres.shape[0] * (2 * half + 1) * (2 * half + 1), dtype=np.int64)
    n_touched = 0
    for k in range(centres.shape[0]):
        cu, cv = centres[k, 0], centres[k, 1]
        base_u, base_v = int(np.floor(cu)), int(np.floor(cv))
        for row in range(base_v - half, base_v + half + 1):
            if row < 0 or row >= h:
                continue
            dv = np.float32(row - cv)
            for col in range(base_u - half, base_u + half + 1):
                if col < 0 or col >= w:
                    continue
                du = np.float32(col - cu)
                alpha = reach - np.sqrt(du * du + dv * dv)
                if alpha <= np.float32(0.0):
                    continue
                alpha = min(alpha, np.float32(1.0))
                pixel = row * w + col
                if coverage[pixel] == np.float32(0.0):
                    touched[n_touched] = pixel
                    n_touched += 1
                coverage[pixel] = max(coverage[pixel], alpha)
    for i in range(n_touched):
        _blend(out, touched[i], coverage[touched[i]], marker_rgb)


@numba.njit(cache=True, nogil=True, inline="always")
def _blend(out: np.ndarray, pixel: int, a: np.float32, marker_rgb: np.ndarray) -> None:  # pragma: no cover
    for c in range(3):
        under = np.float32(out[3 * pixel + c])
        out[3 * pixel + c] = np.uint8(np.rint(under + (marker_rgb[c] - under) * a))


@numba.njit(cache=True, nogil=True)
def _discs_apart(centres: np.ndarray, reach: np.float32) -> bool:  # pragma: no cover (compiled)
    # a pixel within reach of two centres puts them closer than 2 reach; markers are few (tens to a hundred)
    limit = 4.0 * np.float64(reach) * np.float64(reach)
    for a in range(centres.shape[0]):
        for b in range(a + 1, centres.shape[0]):
            du, dv = centres[a, 0] - centres[b, 0], centres[a, 1] - centres[b, 1]
            if du * du + dv * dv < limit:
                return False
    return True
