"""Gap field from small inline MJCF scenes against analytic distances."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from univtac_data.generators.tactile import GAP_FAR_MM, gap_field, pad_pose, sensor_grid
from univtac_data.schema.sensors import get_sensor

MINI = get_sensor("gelsight_mini")

# The pad site is flipped (pad normal = world -z) and shifted, so the frame transform is exercised.
# An L-shaped (non-convex) mesh: a 6 x 6 x 2 mm slab with a 2 mm step on its lower face.
SCENE = """
<mujoco>
  <asset>
    <mesh name="cube" vertex="-.003 -.003 -.003  .003 -.003 -.003  -.003 .003 -.003  .003 .003 -.003
                              -.003 -.003 .003  .003 -.003 .003  -.003 .003 .003  .003 .003 .003"/>
  </asset>
  <worldbody>
    <site name="pad" pos="0.001 0.002 0.05" euler="180 0 0"/>
    <geom name="ball" type="sphere" size="0.005" pos="0.001 -0.002 0.0455"/>
    <geom name="box" type="box" size="0.003 0.002 0.002" pos="0.009 -0.008 0.047" euler="0 0 30"/>
    <geom name="cube" type="mesh" mesh="cube" pos="-0.007 -0.007 0.0465"/>
  </worldbody>
</mujoco>
"""


@pytest.fixture(scope="module")
def scene() -> tuple[mujoco.MjModel, mujoco.MjData]:
    model = mujoco.MjModel.from_xml_string(SCENE)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    return model, data


def pad_xy() -> tuple[np.ndarray, np.ndarray]:
    return sensor_grid(MINI, 1).mesh()


def test_sphere_matches_the_analytic_cap(scene: tuple[mujoco.MjModel, mujoco.MjData]) -> None:
    model, data = scene
    gap = gap_field(model, data, pad_pose(model, data, "pad"), ["ball"], sensor_grid(MINI, 1))
    x, y = pad_xy()
    # pad frame flipped about x: the ball centre (0, -4 mm) from the pad origin becomes (0, +4) mm, 4.5 mm away
    rho2 = x**2 + (y - 4.0) ** 2
    expected = np.where(rho2 < 25.0, 4.5 - np.sqrt(np.maximum(25.0 - rho2, 0.0)), np.inf)
    hit = np.isfinite(expected) & (expected < 10.0)
    np.testing.assert_allclose(gap[hit], expected[hit], atol=1e-9)
    assert np.all(gap[~hit] == GAP_FAR_MM)
    assert gap.min() == pytest.approx(-0.5, abs=1e-3)  # overlap is negative


def test_rotated_box_and_mesh_cube(scene: tuple[mujoco.MjModel, mujoco.MjData]) -> None:
    model, data = scene
    gap = gap_field(model, data, pad_pose(model, data, "pad"), ["box", "cube"], sensor_grid(MINI, 1))
    x, y = pad_xy()
    # box: bottom face 3 mm - 2 mm = 1 mm from the gel, centre (8, 10) mm in the pad frame, yawed -30 deg
    c, s = np.cos(np.deg2rad(-30.0)), np.sin(np.deg2rad(-30.0))
    u, v = c * (x - 8.0) + s * (y - 10.0), -s * (x - 8.0) + c * (y - 10.0)
    inner_box = (np.abs(u) < 2.9) & (np.abs(v) < 1.9)
    np.testing.assert_allclose(gap[inner_box], 1.0, atol=1e-9)
    outside_box = (np.abs(u) > 3.1) | (np.abs(v) > 2.1)
    # mesh cube: 6 mm cube centred 3.5 mm from the gel at (-8, 9) mm -> its near face is 0.5 mm away
    inner_cube = (np.abs(x + 8.0) < 2.9) & (np.abs(y - 9.0) < 2.9)
    np.testing.assert_allclose(gap[inner_cube], 0.5, atol=1e-5)  # MuJoCo stores mesh vertices in float32
    outside = outside_box & ((np.abs(x + 8.0) > 3.1) | (np.abs(y - 9.0) > 3.1))
    assert np.all(gap[outside] == GAP_FAR_MM)


def test_non_convex_mesh_is_rasterised_exactly() -> None:
    # an L-profile prism: lower face at z = 1 mm for x < 0 and z = 3 mm for x > 0 (a step, non-convex)
    verts = np.array([
        [-4, -3, 1], [0, -3, 1], [0, -3, 3], [4, -3, 3], [4, -3, 6], [-4, -3, 6],
        [-4, 3, 1], [0, 3, 1], [0, 3, 3], [4, 3, 3], [4, 3, 6], [-4, 3, 6],
    ], dtype=float) / 1000.0
    quads = [(0, 1, 7, 6), (1, 2, 8, 7), (2, 3, 9, 8), (3, 4, 10, 9), (4, 5, 11, 10), (5, 0, 6, 11)]
    faces = [f for a, b, c, d in quads for f in ((a, b, c), (a, c, d))]
    faces += [(0, 2, 1), (0, 5, 2), (5, 3, 2), (5, 4, 3), (6, 7, 8), (6, 8, 11), (11, 8, 9), (11, 9, 10)]
    spec = mujoco.MjSpec()
    mesh = spec.add_mesh(name="step")
    mesh.uservert = verts.ravel().tolist()
    mesh.userface = np.asarray(faces).ravel().tolist()
    spec.worldbody.add_site(name="pad")
    body = spec.worldbody.add_body(name="obj")
    body.add_geom(name="step", type=mujoco.mjtGeom.mjGEOM_MESH, meshname="step")
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    gap = gap_field(model, data, pad_pose(model, data, "pad"), ["step"], sensor_grid(MINI, 1))
    x, y = pad_xy()
    low = (x > -3.9) & (x < -0.1) & (np.abs(y) < 2.9)
    high = (x > 0.1) & (x < 3.9) & (np.abs(y) < 2.9)
    np.testing.assert_allclose(gap[low], 1.0, atol=1e-5)  # float32 mesh vertices
    np.testing.assert_allclose(gap[high], 3.0, atol=1e-5)


def test_unknown_names_are_reported(scene: tuple[mujoco.MjModel, mujoco.MjData]) -> None:
    model, data = scene
    with pytest.raises(KeyError, match="no site named 'nope'"):
        pad_pose(model, data, "nope")
    with pytest.raises(KeyError, match="no geom named 'nope'"):
        gap_field(model, data, pad_pose(model, data, "pad"), ["nope"], sensor_grid(MINI, 1))
