"""What a pad feels, summarised for a scripted expert: the contact patch of a gap field.

``read_touch`` turns one pad's gap field (mm, negative = the object is pressed into the gel) into a
``TouchReading``: whether anything touches, the patch area, its centroid and principal direction in the
gel-pad-centre frame, the deepest indentation, and how completely the patch fills its own oriented bounding
box (a grooved surface leaves stripes without contact inside the patch; a plain one fills it). Experts
decide from these values, never from the simulator's object poses, wherever the decision is one a real
sensor could make. Pure function of the field: the same field gives the same reading.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from univtac_data.generators.tactile import SensorGrid


@dataclass(frozen=True)
class TouchReading:
    """One pad's contact patch. Frame: gel-pad-centre (x along the pad's width, y up the finger), mm, rad."""

    touching: bool
    area_mm2: float
    centroid_mm: tuple[float, float]
    axis_angle_rad: float  # direction of the patch's long axis from the pad's +x, in (-pi/2, pi/2]
    elongation: float  # long-axis over short-axis spread (1: round patch), dimensionless
    max_depth_mm: float
    fill: float  # contact cells over the cells of the patch's oriented bounding box, 0..1
    length_mm: float  # extent of the patch along its long axis, mm
    span_x_mm: float  # extent of the patch along the pad's x, mm

    @staticmethod
    def none() -> TouchReading:
        return TouchReading(False, 0.0, (0.0, 0.0), 0.0, 1.0, 0.0, 0.0, 0.0, 0.0)


def read_touch(gap_mm: np.ndarray, grid: SensorGrid, box: tuple[slice, slice] | None = None) -> TouchReading:
    """The contact patch of ``gap_mm`` (ny, nx) mm on ``grid``; ``box``: where the field may be below far."""
    window = gap_mm if box is None else gap_mm[box]
    inside = window < 0.0
    count = int(inside.sum())
    if count < 3:
        return TouchReading.none()
    rows, cols = np.nonzero(inside)
    xs = (grid.x_mm if box is None else grid.x_mm[box[1]])[cols]
    ys = (grid.y_mm if box is None else grid.y_mm[box[0]])[rows]
    cx, cy = float(xs.mean()), float(ys.mean())
    dx, dy = xs - cx, ys - cy
    cov = np.array([[np.mean(dx * dx), np.mean(dx * dy)], [np.mean(dx * dy), np.mean(dy * dy)]])
    values, vectors = np.linalg.eigh(cov)
    major = vectors[:, 1]
    angle = math.atan2(major[1], major[0])
    if angle <= -math.pi / 2:
        angle += math.pi
    elif angle > math.pi / 2:
        angle -= math.pi
    along = dx * major[0] + dy * major[1]
    across = -dx * major[1] + dy * major[0]
    cell = grid.cell_area_mm2
    length = float(along.max() - along.min()) + math.sqrt(cell)
    width = float(across.max() - across.min()) + math.sqrt(cell)
    fill = min(1.0, count * cell / (length * width))
    elongation = math.sqrt(max(values[1], 1e-12) / max(values[0], 1e-12))
    span_x = float(xs.max() - xs.min()) + grid.dx_mm
    return TouchReading(True, count * cell, (cx, cy), angle, elongation, float(-window[inside].min()), fill, length,
                        span_x)


__all__ = ["TouchReading", "read_touch"]
