"""Demo indenters: analytic gap fields (H, W) mm on a sensor's image grid, for previews, tests and charts.

Each indenter's lowest point touches the undeformed gel at the pad origin plus ``centre_mm`` when
``depth_mm = 0`` and is pressed ``depth_mm`` into it otherwise; the gap is the height of the indenter's
lower surface above the gel minus the depth (negative = overlap, ``GAP_FAR_MM`` where it is absent).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from univtac_data.schema.sensors import SensorProfile

from .contact import GAP_FAR_MM
from .sensor_model import sensor_grid

__all__ = ["DEMO_INDENTERS", "cross_gap", "cylinder_gap", "demo_gap", "punch_gap", "sphere_gap"]


def _xy(profile: SensorProfile, centre_mm: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    x, y = sensor_grid(profile, 1).mesh()
    return x - centre_mm[0], y - centre_mm[1]


def sphere_gap(
    profile: SensorProfile, radius_mm: float, depth_mm: float, centre_mm: tuple[float, float] = (0.0, 0.0)
) -> np.ndarray:
    """Rigid sphere of ``radius_mm`` pressed ``depth_mm`` at ``centre_mm``."""
    x, y = _xy(profile, centre_mm)
    rho2 = x * x + y * y
    inside = rho2 < radius_mm * radius_mm
    h = radius_mm - np.sqrt(np.where(inside, radius_mm * radius_mm - rho2, 0.0))
    return np.where(inside, h - depth_mm, GAP_FAR_MM)


def cylinder_gap(
    profile: SensorProfile, radius_mm: float, depth_mm: float, angle_rad: float = 0.0,
    centre_mm: tuple[float, float] = (0.0, 0.0),
) -> np.ndarray:
    """Rigid cylinder lying on the gel, axis at ``angle_rad`` from +x, pressed ``depth_mm``."""
    x, y = _xy(profile, centre_mm)
    across = -np.sin(angle_rad) * x + np.cos(angle_rad) * y
    inside = np.abs(across) < radius_mm
    h = radius_mm - np.sqrt(np.where(inside, radius_mm * radius_mm - across * across, 0.0))
    return np.where(inside, h - depth_mm, GAP_FAR_MM)


def punch_gap(
    profile: SensorProfile, radius_mm: float, depth_mm: float, centre_mm: tuple[float, float] = (0.0, 0.0)
) -> np.ndarray:
    """Flat-ended cylindrical punch of ``radius_mm`` (sharp edge) pressed ``depth_mm``."""
    x, y = _xy(profile, centre_mm)
    return np.where(x * x + y * y < radius_mm * radius_mm, -depth_mm, GAP_FAR_MM)


def cross_gap(
    profile: SensorProfile, arm_mm: float, width_mm: float, depth_mm: float, edge_radius_mm: float = 1.0,
    centre_mm: tuple[float, float] = (0.0, 0.0),
) -> np.ndarray:
    """Flat-topped cross (two bars ``2 arm_mm`` long, ``width_mm`` wide) with edges rounded by ``edge_radius_mm``."""
    x, y = _xy(profile, centre_mm)
    ax, ay = np.abs(x), np.abs(y)

    def outside_bar(half_l: float, half_w: float, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        return np.hypot(np.maximum(u - half_l, 0.0), np.maximum(v - half_w, 0.0))

    dist = np.minimum(outside_bar(arm_mm, width_mm / 2, ax, ay), outside_bar(width_mm / 2, arm_mm, ax, ay))
    r = edge_radius_mm
    inside = dist < r
    h = r - np.sqrt(np.where(inside, r * r - dist * dist, 0.0))
    return np.where(inside, h - depth_mm, GAP_FAR_MM)


DEMO_INDENTERS: dict[str, Callable[[SensorProfile, float], np.ndarray]] = {
    "sphere": lambda p, d: sphere_gap(p, 4.0, d),
    "cylinder": lambda p, d: cylinder_gap(p, 3.0, d, angle_rad=np.deg2rad(30.0)),
    "punch": lambda p, d: punch_gap(p, 3.0, min(d, 0.3)),
    "cross": lambda p, d: cross_gap(p, 5.0, 2.0, d, edge_radius_mm=1.5),
    "two_spheres": lambda p, d: np.minimum(sphere_gap(p, 3.0, d, (-4.0, 0.0)), sphere_gap(p, 3.0, d, (4.0, 1.0))),
}
"""Demo indenter name -> f(profile, depth_mm) -> gap (H, W) mm."""


def demo_gap(profile: SensorProfile, name: str, depth_mm: float | None = None) -> np.ndarray:
    """Gap field of a named demo indenter (``DEMO_INDENTERS``) pressed ``depth_mm`` (default: the profile's
    grasp threshold plus half the remaining safe range)."""
    if name not in DEMO_INDENTERS:
        raise KeyError(f"unknown demo indenter {name!r}; known: {', '.join(DEMO_INDENTERS)}")
    if depth_mm is None:
        depth_mm = 0.5 * (profile.grasp_threshold_mm + profile.safe_indentation_mm)
    return DEMO_INDENTERS[name](profile, depth_mm)
