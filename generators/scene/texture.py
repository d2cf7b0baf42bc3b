"""Surface textures that only touch can feel: grooves cut into an object's surface, added to the tactile gap
field, not to MuJoCo's collision geometry.

The cameras render the plain geom, so a grooved and a plain cylinder look the same, while the gel sees
the grooves as stripes without contact inside the contact patch (Grasp Classify). The grooves lie below
the nominal surface, so the rigid contact that MuJoCo computes (on the ridges) stays right.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
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
    Each touched cell gets ``grooves.groove_depth_mm`` at its surface point.
    """
    region = gap_mm[box]
    if region.size == 0:
        return
    _groove_cells(region, np.ascontiguousarray(grid.x_mm[box[1]], dtype=np.float64),
                  np.ascontiguousarray(grid.y_mm[box[0]], dtype=np.float64),
                  np.ascontiguousarray(pad.rotation, dtype=np.float64),
                  np.asarray(pad.origin_mm, dtype=np.float64) - np.asarray(cyl_pos_m, dtype=np.float64) * 1000.0,
                  np.ascontiguousarray(cyl_mat, dtype=np.float64), radius_m * 1000.0, float(reach_mm),
                  float(grooves.pitch_mm), float(grooves.depth_mm), float(grooves.duty), bool(grooves.axial),
                  float(GAP_FAR_MM))


@numba.njit(cache=True, nogil=True)
def _groove_cells(region: np.ndarray, x_mm: np.ndarray, y_mm: np.ndarray, pad_rot: np.ndarray,
                  pad_from_cyl_mm: np.ndarray, cyl_mat: np.ndarray, radius_mm: float, reach_mm: float,
                  pitch_mm: float, depth_mm: float, duty: float, axial: bool,
                  far_mm: float) -> None:  # pragma: no cover (compiled)
    # add_cylinder_grooves in one pass over the box: as array code it made a dozen box-sized temporaries and
    # cost 1 ms a pad on a cylinder that fills the pad (Grasp Classify)
    for i in range(region.shape[0]):
        y = y_mm[i]
        for j in range(region.shape[1]):
            z = region[i, j]
            if not z < reach_mm:
                continue
            x = x_mm[j]
            # the surface point the gap reached, (x, y, gap) in the pad frame, in the cylinder's frame (axis z)
            wx = pad_rot[0, 0] * x + pad_rot[0, 1] * y + pad_rot[0, 2] * z + pad_from_cyl_mm[0]
            wy = pad_rot[1, 0] * x + pad_rot[1, 1] * y + pad_rot[1, 2] * z + pad_from_cyl_mm[1]
            wz = pad_rot[2, 0] * x + pad_rot[2, 1] * y + pad_rot[2, 2] * z + pad_from_cyl_mm[2]
            lx = wx * cyl_mat[0, 0] + wy * cyl_mat[1, 0] + wz * cyl_mat[2, 0]
            ly = wx * cyl_mat[0, 1] + wy * cyl_mat[1, 1] + wz * cyl_mat[2, 1]
            if not abs(np.hypot(lx, ly) - radius_mm) < reach_mm:
                continue
            lz = wx * cyl_mat[0, 2] + wy * cyl_mat[1, 2] + wz * cyl_mat[2, 2]
            cut = (lz / pitch_mm) % 1.0 < duty
            if axial and not cut:
                cut = (np.arctan2(ly, lx) * radius_mm / pitch_mm) % 1.0 < duty
            if cut:
                region[i, j] = min(z + depth_mm, far_mm)


__all__ = ["CylinderGrooves", "add_cylinder_grooves"]
