"""Physically shaded optical model: I_pure from the deformed gel surface.

The camera looks at the inside of the gel's reflective coating, lit by the profile's coloured LEDs at
grazing elevation. With the surface z = -D(x, y) (D: indentation, mm), the coating's normal seen from the
camera is ``n = (-dD/dx, -dD/dy, -1) / norm`` and a light at azimuth phi and elevation e (on the camera side)
has direction ``l = (cos e cos phi, cos e sin phi, -sin e)``. Lambert shading ``max(0, n . l)``; on the flat
gel every light gives sin e, so the image is

    I = background_rgb * vignette(x, y) + 255 * gain * sum_k rgb_k (max(0, n . l_k) - sin e_k)

which is exactly the profile's tinted, vignetted background wherever the gel is flat, and coloured shading on
the slopes of a contact (a slope facing a light brightens in that light's colour, the opposite slope darkens).
``vignette = 1 - vignetting * (r / r_corner)^2``. Optional seeded Gaussian noise (grey levels) is added
before quantisation. Only the bounding box of the deformation is shaded; the rest is the cached background.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from univtac_data.schema.sensors import SensorProfile

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
    d = depth.astype(np.float32, copy=False)
    gx = np.empty_like(d)
    gy = np.empty_like(d)
    # central differences inside, one-sided at the patch border (as numpy.gradient), in float32
    gx[:, 1:-1] = (d[:, 2:] - d[:, :-2]) * np.float32(0.5 / profile.mm_per_px_x)
    gx[:, 0] = (d[:, 1] - d[:, 0]) * np.float32(1.0 / profile.mm_per_px_x)
    gx[:, -1] = (d[:, -1] - d[:, -2]) * np.float32(1.0 / profile.mm_per_px_x)
    gy[1:-1] = (d[2:] - d[:-2]) * np.float32(0.5 / profile.mm_per_px_y)
    gy[0] = (d[1] - d[0]) * np.float32(1.0 / profile.mm_per_px_y)
    gy[-1] = (d[-1] - d[-2]) * np.float32(1.0 / profile.mm_per_px_y)
    inv = 1.0 / np.sqrt(1.0 + gx * gx + gy * gy)
    dirs, rgb = _lights(profile)
    # channel-first planes (3, h w) so that both products are single matrix products with a long inner
    # loop; the (h, w, 3) @ (3, K) form runs h small products and a broadcast over K, several times slower
    normals = np.empty((3, d.size), dtype=np.float32)
    np.multiply(gx, inv, out=normals[0].reshape(d.shape))
    np.multiply(gy, inv, out=normals[1].reshape(d.shape))
    normals[2] = inv.ravel()
    lam = (-dirs).astype(np.float32) @ normals  # (K, h w): n . l with n = (-gx, -gy, -1) / norm
    np.maximum(lam, 0.0, out=lam)
    lam += dirs[:, 2:3].astype(np.float32)  # subtract the flat level sin(e) (dirs z = -sin e)
    shade = (rgb.T * (255.0 * gain)).astype(np.float32) @ lam  # (3, h w)
    return shade.T.reshape(*d.shape, 3)


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
    depth_mm: np.ndarray, profile: SensorProfile, config: ShadingConfig = ShadingConfig(), noise_seed: int | None = None
) -> np.ndarray:
    """I_pure (H, W, 3) uint8 from the depth map (H, W) mm on the image grid."""
    deformed = depth_mm > config.depth_floor_mm
    rows = np.flatnonzero(deformed.any(axis=1))
    win: tuple[slice, slice] | None = None
    if rows.size:
        cols = np.flatnonzero(deformed[rows[0] : rows[-1] + 1].any(axis=0))
        h, w = depth_mm.shape
        win = (slice(max(rows[0] - 2, 0), min(rows[-1] + 3, h)), slice(max(cols[0] - 2, 0), min(cols[-1] + 3, w)))
    if noise_seed is None:
        # only the deformed window differs from the cached background
        out = _background_uint8(profile).copy()
        if win is not None:
            patch = _background_single(profile)[win] + _shade(depth_mm[win], profile, config.gain)
            np.rint(patch, out=patch)
            np.clip(patch, 0, 255, out=patch)
            out[win] = patch
        return out
    img = background_image(profile).copy()
    if win is not None:
        img[win] += _shade(depth_mm[win], profile, config.gain)
    img += np.random.default_rng(noise_seed).normal(0.0, config.noise_std, img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)
