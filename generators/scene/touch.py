"""What a pad feels, summarised for a scripted expert: the contact patch of a gap field.

``read_touch`` turns one pad's gap field (mm, negative = the object is pressed into the gel) into a
``TouchReading``: whether anything touches, the patch area, its centroid and principal direction in the
gel-pad-centre frame, the deepest indentation, and how completely the patch fills its own oriented bounding
box (a grooved surface leaves stripes without contact inside the patch; a plain one fills it). For a strip
(a cylinder pressed on the pad) it also gives the line through the midpoints of the patch's chords across
it: the cylinder's axis however the press varies along the strip and however much of it the image cuts off.
The principal direction is not: a bottle's strips, pressed deeper at one end and cut by the image's border,
read 2-17 deg off it on the GF225 (a 23.5 mm image of a 27 mm gel) and 3-4 deg on the Mini. Experts
decide from these values, never from the simulator's object poses, wherever the decision is one a real
sensor could make. Pure function of the field: the same field gives the same reading.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from univtac_data.generators.tactile import SensorGrid

SHORT_CHORD = 0.75  # chords shorter than this fraction of the median are a patch's ends (``_chord_line_angle``)


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
    # direction of the line through the midpoints of the patch's chords across that line, from the pad's +x,
    # in (-pi/2, pi/2]; chords the grid's border cuts are left out; None with fewer than 3 left
    chord_line_angle_rad: float | None = None

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
    origin = (0, 0) if box is None else (box[0].start or 0, box[1].start or 0)
    line = _chord_line_angle(inside, grid, origin, angle)
    return TouchReading(True, count * cell, (cx, cy), angle, elongation, float(-window[inside].min()), fill, length,
                        span_x, line)


def _chord_line_angle(inside: np.ndarray, grid: SensorGrid, origin: tuple[int, int], guess_rad: float,
                      passes: int = 2) -> float | None:
    """Angle (rad, from the pad's +x, in (-pi/2, pi/2]) of the least-squares line through the midpoints of the
    patch's chords across the line (each pass cuts the patch into slabs 1.5 cells thick across the previous
    pass's line, starting from ``guess_rad``). ``inside`` is the patch's window of the grid, whose first cell
    is grid cell ``origin`` (row, column). Chords are taken from the patch's outline only (its ends in each
    slab), and a slab that holds a cell on the grid's border is left out: the image cut it short."""
    padded = np.pad(inside, 1)
    outline = inside & ~(padded[:-2, 1:-1] & padded[2:, 1:-1] & padded[1:-1, :-2] & padded[1:-1, 2:])
    rows, cols = np.nonzero(outline)
    rows, cols = rows + origin[0], cols + origin[1]
    ny, nx = grid.shape
    on_border = (rows == 0) | (rows == ny - 1) | (cols == 0) | (cols == nx - 1)
    x, y = grid.x_mm[cols], grid.y_mm[rows]
    slab_mm = 1.5 * max(grid.dx_mm, grid.dy_mm)  # the outline steps at most one cell: each side crosses every slab
    angle = guess_rad
    for _ in range(passes):
        ux, uy = math.cos(angle), math.sin(angle)
        along, across = x * ux + y * uy, y * ux - x * uy
        slab = np.floor(along / slab_mm).astype(np.int64)
        order = np.argsort(slab, kind="stable")
        slab, across_sorted, cut = slab[order], across[order], on_border[order]
        starts = np.flatnonzero(np.r_[True, slab[1:] != slab[:-1]])
        low, high = np.minimum.reduceat(across_sorted, starts), np.maximum.reduceat(across_sorted, starts)
        whole = ~np.maximum.reduceat(cut, starts)
        if int(whole.sum()) < 3:
            return None
        # a slab that crosses an end of the patch (a strip's end, or its narrow tip) holds a short, lopsided
        # chord whenever the line is still off: keep the chords at least SHORT_CHORD of the median's length
        length = high - low
        whole &= length >= SHORT_CHORD * float(np.median(length[whole]))
        if int(whole.sum()) < 3:
            return None
        at = (slab[starts][whole] + 0.5) * slab_mm
        mid = 0.5 * (low + high)[whole]
        angle += math.atan(float(np.polyfit(at, mid, 1)[0]))  # mid = a + slope * along: the line turns by atan
    angle = (angle + math.pi / 2) % math.pi - math.pi / 2  # into [-pi/2, pi/2)
    return math.pi / 2 if angle == -math.pi / 2 else angle


__all__ = ["TouchReading", "read_touch"]
