"""Physically shaded optical model: I_pure from the deformed gel surface.

The camera looks at the inside of the gel's reflective coating, lit by the profile's coloured LEDs at
grazing elevation. With the surface z = -D(x, y) (D: indentation, mm), the coating's normal seen from the
camera is ``n = (-dD/dx, -dD/dy, -1) / norm`` and a light at azimuth phi and elevation e (on the camera side)
has direction ``l = (cos e cos phi, cos e sin phi, -sin e)``. Lambert shading ``max(0, n . l)``; on the flat
gel every light gives sin e, so the image is

    I = background_rgb * vignette(x, y) + 255 * gain * sum_k rgb_k (max(0, n . l_k) - sin e_k)

which is exactly the profile's tinted, vignetted background wherever the gel is flat, and coloured shading on
the slopes of a contact (a slope facing a light brightens in that light's colour, the opposite slope darkens).
``vignette = 1 - vignetting * (r / r_corner)^2``. Optional seeded Gaussian noise (grey levels, :mod:`.noise`:
counter-based, a fraction of a millisecond a frame) is added before quantisation. Only the bounding box of the deformation is shaded; the rest is the cached background.
The shading runs compiled (numba), in float32, one pass per pixel row.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numba
import numpy as np

from univtac_data.schema.sensors import SensorProfile

from .noise import noisy_image

__all__ = ["ShadingConfig", "background_image", "render_shaded"]


@dataclass(frozen=True)
class ShadingConfig:
    """Renderer settings that are not sensor data."""

    gain: float = 1.3  # shading contrast, fraction of 255 grey levels per unit of Lambert change
    noise_std: float = 1.5  # sensor noise, grey levels (applied only when a noise seed is given)
    depth_floor_mm: float = 1e-5  # depths below this are flat for the purpose of windowing the shading


@lru_cache(maxsize=16)
def background_image(profile: SensorProfile) -> np.ndarray:
    """(H, W, 3) float64 untouched-gel image: background tint times vignetting, grey levels."""
    h, w = profile.image_height_px, profile.image_width_px
    v = (np.arange(h) - profile.cy_px) / max(profile.cy_px, 1.0)
    u = (np.arange(w) - profile.cx_px) / max(profile.cx_px, 1.0)
    r2 = (u[None, :] ** 2 + v[:, None] ** 2) / 2.0
    vignette = 1.0 - profile.optics.vignetting * r2
    img = vignette[:, :, None] * np.asarray(profile.optics.background_rgb, dtype=np.float64)
    img.setflags(write=False)
    return img


@lru_cache(maxsize=16)
def _lights(profile: SensorProfile) -> tuple[np.ndarray, np.ndarray]:
    az = np.deg2rad([lt.azimuth_deg for lt in profile.optics.lights])
    el = np.deg2rad([lt.elevation_deg for lt in profile.optics.lights])
    dirs = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), -np.sin(el)], axis=1)  # (K, 3)
    rgb = np.asarray([lt.rgb for lt in profile.optics.lights], dtype=np.float64)  # (K, 3)
    return dirs, rgb


def _shade(depth: np.ndarray, profile: SensorProfile, gain: float) -> np.ndarray:
    """(h, w, 3) float32 shading change (grey levels) of a depth patch (h, w) mm."""
    shade = np.empty((*depth.shape, 3), dtype=np.float32)
    _shade_window(depth, (slice(0, depth.shape[0]), slice(0, depth.shape[1])), profile, gain,
                  np.zeros((0, 0, 3), np.float32), shade, np.zeros((0, 0, 3), np.uint8))
    return shade


def _shade_window(depth: np.ndarray, win: tuple[slice, slice], profile: SensorProfile, gain: float,
                  background: np.ndarray, shade: np.ndarray, image: np.ndarray) -> None:
    dirs, rgb = _lights(profile)
    # n . l_k = sum_j n_j (-l_k)_j with n = (-gx, -gy, -1) / norm; the flat gel gives sin(e_k) = -(l_k)_z
    _shade_kernel(depth, win[0].start, win[0].stop, win[1].start, win[1].stop,
                  np.float32(1.0 / profile.mm_per_px_x), np.float32(1.0 / profile.mm_per_px_y),
                  (-dirs).astype(np.float32), dirs[:, 2].astype(np.float32),
                  np.ascontiguousarray((rgb.T * (255.0 * gain)).astype(np.float32)), background, shade, image)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _shade_kernel(depth: np.ndarray, r0: int, r1: int, c0: int, c1: int, inv_dx: np.float32, inv_dy: np.float32,
                  neg_dirs: np.ndarray, flat_level: np.ndarray, rgb_gain: np.ndarray, background: np.ndarray,
                  shade: np.ndarray, image: np.ndarray) -> None:  # pragma: no cover (compiled)
    """Shading of the window rows r0:r1, cols c0:c1 of ``depth`` (H, W) mm, in float32. With an empty ``image``:
    the change in grey levels into ``shade`` (r1 - r0, c1 - c0, 3). Otherwise ``image`` (H, W, 3) uint8 =
    clip(rint(``background`` (H, W, 3) float32 + change), 0, 255) in the window, and ``shade`` is unused.
    Slopes are central differences inside the window and one-sided at its border (as numpy.gradient on the
    window). Row by row, in branch-free loops the compiler vectorises (array code would make a dozen passes)."""
    w = c1 - c0
    half_dx, half_dy = np.float32(0.5) * inv_dx, np.float32(0.5) * inv_dy
    write_image = image.shape[0] > 0
    here, above, below = np.empty(w, np.float32), np.empty(w, np.float32), np.empty(w, np.float32)
    gx, gy = np.zeros(w, np.float32), np.empty(w, np.float32)
    inv, nx, ny = np.empty(w, np.float32), np.empty(w, np.float32), np.empty(w, np.float32)
    s0, s1, s2 = np.empty(w, np.float32), np.empty(w, np.float32), np.empty(w, np.float32)
    mixed = np.empty(3 * w, np.float32)
    for i in range(r0, r1):
        up, down = max(i - 1, r0), min(i + 1, r1 - 1)
        scale_y = half_dy if down - up == 2 else (inv_dy if down > up else np.float32(0.0))
        # row slices, not element-wise 2-D indexing: only loops over contiguous rows vectorise
        depth_here, depth_above, depth_below = depth[i, c0:c1], depth[up, c0:c1], depth[down, c0:c1]
        for j in range(w):
            here[j] = depth_here[j]
            above[j] = depth_above[j]
            below[j] = depth_below[j]
        for j in range(1, w - 1):
            gx[j] = (here[j + 1] - here[j - 1]) * half_dx
        if w > 1:
            gx[0] = (here[1] - here[0]) * inv_dx
            gx[w - 1] = (here[w - 1] - here[w - 2]) * inv_dx
        for j in range(w):
            gy[j] = (below[j] - above[j]) * scale_y
            inv[j] = np.float32(1.0) / np.sqrt(np.float32(1.0) + gx[j] * gx[j] + gy[j] * gy[j])
            nx[j] = gx[j] * inv[j]
            ny[j] = gy[j] * inv[j]
            s0[j] = s1[j] = s2[j] = np.float32(0.0)
        for k in range(neg_dirs.shape[0]):
            l0, l1, l2, flat = neg_dirs[k, 0], neg_dirs[k, 1], neg_dirs[k, 2], flat_level[k]
            g0, g1, g2 = rgb_gain[0, k], rgb_gain[1, k], rgb_gain[2, k]
            for j in range(w):
                lam = max(l0 * nx[j] + l1 * ny[j] + l2 * inv[j], np.float32(0.0)) + flat
                s0[j] += g0 * lam
                s1[j] += g1 * lam
                s2[j] += g2 * lam
        if write_image:
            # interleave the three channels, then one contiguous pass over the row's 3 w values (the channel-
            # strided pass did not vectorise)
            for j in range(w):
                mixed[3 * j] = s0[j]
                mixed[3 * j + 1] = s1[j]
                mixed[3 * j + 2] = s2[j]
            image_flat, background_flat = image[i, c0:c1].reshape(3 * w), background[i, c0:c1].reshape(3 * w)
            for m in range(3 * w):
                image_flat[m] = np.uint8(min(max(np.rint(background_flat[m] + mixed[m]), np.float32(0.0)), np.float32(255.0)))
        else:
            shade_row = shade[i - r0]
            for j in range(w):
                shade_row[j, 0], shade_row[j, 1], shade_row[j, 2] = s0[j], s1[j], s2[j]


@lru_cache(maxsize=16)
def _background_single(profile: SensorProfile) -> np.ndarray:
    img = background_image(profile).astype(np.float32)
    img.setflags(write=False)
    return img


@lru_cache(maxsize=16)
def _background_uint8(profile: SensorProfile) -> np.ndarray:
    img = np.clip(np.rint(background_image(profile)), 0, 255).astype(np.uint8)
    img.setflags(write=False)
    return img


def render_shaded(
    depth_mm: np.ndarray, profile: SensorProfile, config: ShadingConfig = ShadingConfig(), noise_seed: int | None = None,
    *, deformed_box: tuple[slice, slice] | None = None, out: np.ndarray | None = None,
) -> np.ndarray:
    """I_pure (H, W, 3) uint8 from the depth map (H, W) mm on the image grid.

    ``deformed_box``: (rows, cols) outside which ``depth_mm`` is zero, when the caller knows it (the shading
    then searches only that box for the deformed pixels). ``out``: (H, W, 3) uint8 to write into and return.
    """
    h, w = depth_mm.shape
    (s0, s1), (t0, t1) = ((0, h), (0, w)) if deformed_box is None else \
        (deformed_box[0].indices(h)[:2], deformed_box[1].indices(w)[:2])
    found = _deformed_span(depth_mm, s0, s1, t0, t1, config.depth_floor_mm)
    win: tuple[slice, slice] | None = None
    if found[0] >= 0:
        win = (slice(max(found[0] - 2, 0), min(found[1] + 3, h)), slice(max(found[2] - 2, 0), min(found[3] + 3, w)))
    if out is None:
        out = np.empty((h, w, 3), np.uint8)
    elif out.shape != (h, w, 3) or out.dtype != np.uint8:
        raise ValueError(f"out must be ({h}, {w}, 3) uint8 (got {out.shape} {out.dtype})")
    if noise_seed is None:
        if not out.flags.c_contiguous:  # the compiled shading writes whole contiguous rows
            return _copied_into(out, render_shaded(depth_mm, profile, config, deformed_box=deformed_box))
        # only the deformed window differs from the cached background: the shading writes the window, the
        # background the rest (copying it everywhere first wrote the window twice)
        background = _background_uint8(profile)
        if win is None:
            out[...] = background
            return out
        (r0, r1), (c0, c1) = (win[0].start, win[0].stop), (win[1].start, win[1].stop)
        out[:r0], out[r1:] = background[:r0], background[r1:]
        out[r0:r1, :c0], out[r0:r1, c1:] = background[r0:r1, :c0], background[r0:r1, c1:]
        _shade_window(depth_mm, win, profile, config.gain, _background_single(profile),
                      np.zeros((0, 0, 3), np.float32), out)
        return out
    change = _shade(depth_mm[win], profile, config.gain) if win is not None else None
    if not out.flags.c_contiguous:
        return _copied_into(out, noisy_image(_background_single(profile), change, win, noise_seed, config.noise_std,
                                             np.empty((h, w, 3), np.uint8)))
    return noisy_image(_background_single(profile), change, win, noise_seed, config.noise_std, out)


@numba.njit(cache=True, nogil=True)
def _deformed_span(depth: np.ndarray, s0: int, s1: int, t0: int, t1: int,
                   floor: float) -> tuple[int, int, int, int]:  # pragma: no cover (compiled)
    # first and last row, first and last column of the pixels deeper than ``floor`` in rows s0:s1, cols t0:t1
    # (-1s when there are none): one pass, where array code made a boolean image and three reductions
    first_row, last_row, first_col, last_col = -1, -1, t1, -1
    for i in range(s0, s1):
        row = depth[i]
        lo = -1
        for j in range(t0, t1):
            if row[j] > floor:
                lo = j
                break
        if lo < 0:
            continue
        hi = lo
        for j in range(t1 - 1, lo, -1):
            if row[j] > floor:
                hi = j
                break
        if first_row < 0:
            first_row = i
        last_row = i
        first_col, last_col = min(first_col, lo), max(last_col, hi)
    if first_row < 0:
        return -1, -1, -1, -1
    return first_row, last_row, first_col, last_col


def _copied_into(out: np.ndarray, image: np.ndarray) -> np.ndarray:
    out[...] = image
    return out
