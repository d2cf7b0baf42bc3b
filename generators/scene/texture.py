"""Surface textures that only touch can feel: grooves cut into an object's surface, added to the tactile gap
field, not to MuJoCo's collision geometry.

The cameras render the plain geom, so a grooved and a plain cylinder look the same, while the gel sees
the grooves as stripes without contact inside the contact patch (Grasp Classify). The grooves lie below
the nominal surface, so the rigid contact that MuJoCo computes (on the ridges) stays right.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from univtac_data.generators.tactile import GAP_FAR_MM, PadPose, SensorGrid


@dataclass(frozen=True)
class CylinderGrooves:
    """Grooves on a cylinder geom: rings around its axis and, for a knurl, grooves along it.

    ``pitch_mm``: distance between grooves, mm; ``depth_mm``: how deep each is cut, mm (the ridges between
    them are the nominal surface); ``duty``: fraction of each pitch that is groove; ``axial``: also cut
    grooves along the axis (a diamond-like knurl, so the pattern shows whatever the cylinder's yaw in the pad).
    """

    pitch_mm: float = 1.6
    depth_mm: float = 0.4
    duty: float = 0.5
    axial: bool = True

    def groove_depth_mm(self, axial_mm: np.ndarray, arc_mm: np.ndarray) -> np.ndarray:
        """Depth below the nominal surface, mm, at cylinder coordinates: ``axial_mm`` along the axis and
        ``arc_mm`` around it (radius x angle), both mm."""
        def grooved(u: np.ndarray) -> np.ndarray:
            phase = np.mod(u / self.pitch_mm, 1.0)
            return phase < self.duty
        cut = grooved(axial_mm)
        if self.axial:
            cut |= grooved(arc_mm)
        return np.where(cut, self.depth_mm, 0.0)


def add_cylinder_grooves(gap_mm: np.ndarray, box: tuple[slice, slice], grid: SensorGrid, pad: PadPose,
                         cyl_pos_m: np.ndarray, cyl_mat: np.ndarray, radius_m: float, grooves: CylinderGrooves,
                         reach_mm: float = 2.0) -> None:
    """Deepen ``gap_mm`` (ny, nx) mm, in place, by the grooves of the cylinder at world pose (``cyl_pos_m``
    (3,) m, ``cyl_mat`` (3, 3)) of radius ``radius_m``, where the cylinder is the surface the cell sees.

    Only cells of ``box`` whose gap is below ``reach_mm`` are touched (the rest cannot come into contact),
    and only those whose surface point lies on the cylinder's side within ``radius + reach`` of its axis.
    """
    region = gap_mm[box]
    near = region < reach_mm
    if not near.any():
        return
    rows, cols = np.nonzero(near)
    x = grid.x_mm[box[1]][cols]
    y = grid.y_mm[box[0]][rows]
    z = region[rows, cols]  # the surface point the gap reached: (x, y, gap) in the pad frame, mm
    points_pad = np.stack([x, y, z], axis=1)
    points_world = points_pad @ pad.rotation.T + pad.origin_mm
    local = (points_world - cyl_pos_m * 1000.0) @ cyl_mat  # cylinder frame, mm; axis = local z
    radial = np.hypot(local[:, 0], local[:, 1])
    on_side = np.abs(radial - radius_m * 1000.0) < reach_mm
    if not on_side.any():
        return
    arc = np.arctan2(local[:, 1], local[:, 0]) * radius_m * 1000.0
    extra = grooves.groove_depth_mm(local[:, 2], arc) * on_side
    region[rows, cols] = np.minimum(region[rows, cols] + extra, GAP_FAR_MM)


__all__ = ["CylinderGrooves", "add_cylinder_grooves"]
