"""Grooves felt by touch only: the compiled pass of ``add_cylinder_grooves`` against the groove definition."""

from __future__ import annotations

import numpy as np
import pytest

from univtac_data.generators.scene.geometry import quat_to_mat
from univtac_data.generators.scene.texture import CylinderGrooves, add_cylinder_grooves
from univtac_data.generators.tactile import GAP_FAR_MM
from univtac_data.generators.tactile.gap_field import PadPose
from univtac_data.generators.tactile.sensor_model import sensor_grid
from univtac_data.schema.sensors import get_sensor


def _expected(gap: np.ndarray, box: tuple[slice, slice], grid, pad: PadPose, cyl_pos_m: np.ndarray,
              cyl_mat: np.ndarray, radius_m: float, grooves: CylinderGrooves, reach_mm: float) -> np.ndarray:
    # the definition, point by point: the surface point each gap reached, in the cylinder's frame
    out = gap.copy()
    rows, cols = np.nonzero(gap[box] < reach_mm)
    rows, cols = rows + box[0].start, cols + box[1].start
    z = gap[rows, cols]
    points = np.stack([grid.x_mm[cols], grid.y_mm[rows], z], axis=1) @ pad.rotation.T + pad.origin_mm
    local = (points - cyl_pos_m * 1000.0) @ cyl_mat
    on_side = np.abs(np.hypot(local[:, 0], local[:, 1]) - radius_m * 1000.0) < reach_mm
    arc = np.arctan2(local[:, 1], local[:, 0]) * radius_m * 1000.0
    extra = grooves.groove_depth_mm(local[:, 2], arc) * on_side
    out[rows, cols] = np.minimum(z + extra, GAP_FAR_MM)
    return out


@pytest.mark.parametrize("axial", [True, False])
def test_grooves_match_their_definition_on_a_pressed_cylinder(axial: bool) -> None:
    grid = sensor_grid(get_sensor("gelsight_mini"))
    rng = np.random.default_rng(7)
    radius_m = 0.02
    grooves = CylinderGrooves(pitch_mm=1.6, depth_mm=0.4, duty=0.5, axial=axial)
    for _ in range(5):
        # a pad facing down (-z) onto a cylinder lying along a random yaw, pressed by up to 0.5 mm
        yaw = rng.uniform(-np.pi, np.pi)
        pad = PadPose(np.diag([1.0, -1.0, -1.0]), np.array([rng.uniform(-3, 3), rng.uniform(-3, 3), 0.0]))
        cyl_mat = quat_to_mat(np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])) @ np.array(
            [[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # axis (local z) horizontal
        press_mm = rng.uniform(0.0, 0.5)
        cyl_pos_m = np.array([0.0, 0.0, -(radius_m * 1000.0 - press_mm) / 1000.0])
        # the gap from the pad (z = 0, looking down) to the cylinder's top, where it lies under the pad
        axis = cyl_mat[:, 2]
        x, y = grid.mesh()
        world = np.stack([pad.origin_mm[0] + x, pad.origin_mm[1] - y, np.zeros_like(x)], axis=-1)
        across = world - np.outer(world.reshape(-1, 3) @ axis, axis).reshape(world.shape)
        half_chord2 = (radius_m * 1000.0) ** 2 - across[..., 0] ** 2 - across[..., 1] ** 2
        top = np.where(half_chord2 > 0, cyl_pos_m[2] * 1000.0 + np.sqrt(np.maximum(half_chord2, 0.0)), -np.inf)
        gap = np.where(np.isfinite(top), -top, GAP_FAR_MM)
        box = (slice(10, 230), slice(5, 300))
        want = _expected(gap, box, grid, pad, cyl_pos_m, cyl_mat, radius_m, grooves, 2.0)
        got = gap.copy()
        add_cylinder_grooves(got, box, grid, pad, cyl_pos_m, cyl_mat, radius_m, grooves)
        deepened = want != gap
        assert deepened.sum() > 1000  # the grooves cut the contact
        assert not np.any((want != gap)[:10]) and not np.any((got != gap)[:10])  # outside the box: untouched
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
