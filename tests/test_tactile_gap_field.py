"""Gap field from small inline MJCF scenes against analytic distances."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from univtac_data.generators.tactile import GAP_FAR_MM, gap_field, pad_pose, sensor_grid
from univtac_data.generators.tactile import gap_primitives as gp
from univtac_data.generators.tactile.sensor_model import SensorGrid

from univtac_data.schema.sensors import get_sensor

MINI = get_sensor("gelsight_mini")


# The closed-form entries in array code, as the module computed them before it was compiled: an independent
# oracle for the compiled kernels (gap_primitives.lower_to_entry).
def _ref_origin(x: np.ndarray, y: np.ndarray, rot: np.ndarray, pos: np.ndarray, k: int) -> np.ndarray:
    """Component ``k`` (ny, nx) of the line origins in the object's frame: (rot.T @ (x - px, y - py, -pz))[k].

    An outer sum of a row and a column term, so the box and cylinder read one component at a time and build
    no (ny, nx, 3) array (the same operations in the same order as the 3-vector form: bit-identical).
    """
    return ((x - pos[0]) * rot[0, k])[None, :] + ((y - pos[1]) * rot[1, k])[:, None] - pos[2] * rot[2, k]


def ref_quadratic_entry(a: float | np.ndarray, b: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Roots (t_in, t_out) of a t^2 + b t + c = 0 (a > 0), +inf/-inf where there is none."""
    disc = b * b - 4.0 * a * c
    ok = disc >= 0.0
    sq = np.sqrt(np.where(ok, disc, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        t_in = np.where(ok, (-b - sq) / (2.0 * a), np.inf)
        t_out = np.where(ok, (-b + sq) / (2.0 * a), -np.inf)
    return t_in, t_out


def ref_quadratic_first_root(a: float, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """t_in of :func:`ref_quadratic_entry` alone (the same arithmetic), for callers that need no exit."""
    disc = b * b - 4.0 * a * c
    ok = disc >= 0.0
    np.sqrt(disc, out=disc, where=ok)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_in = (-b - disc) / (2.0 * a)
    t_in[~ok] = np.inf
    return t_in


def ref_ellipsoid_entry(x: np.ndarray, y: np.ndarray, rot: np.ndarray, pos: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Ellipsoid with semi-axes ``radii`` (3,) mm (a sphere when equal)."""
    o = np.empty((y.size, x.size, 3))
    for k in range(3):  # scaled to the unit sphere as they are written, one pass over (ny, nx, 3) fewer
        np.divide(_ref_origin(x, y, rot, pos, k), radii[k], out=o[..., k])
    d = rot[2] / radii
    return ref_quadratic_first_root(float(d @ d), 2.0 * (o @ d), np.einsum("ijk,ijk->ij", o, o) - 1.0)


def ref_slab(o: np.ndarray, d: float, lo: float, hi: float) -> tuple[np.ndarray, np.ndarray]:
    if abs(d) < 1e-12:
        inside = (o >= lo) & (o <= hi)
        return np.where(inside, -np.inf, np.inf), np.where(inside, np.inf, -np.inf)
    t1, t2 = (lo - o) / d, (hi - o) / d
    return np.minimum(t1, t2), np.maximum(t1, t2)


def ref_box_entry(x: np.ndarray, y: np.ndarray, rot: np.ndarray, pos: np.ndarray, half: np.ndarray) -> np.ndarray:
    """Box with half-sizes ``half`` (3,) mm."""
    d = rot[2]
    # max(-inf, a) is a: the first slab is the running interval, the other two narrow it in place
    t_in, t_out = ref_slab(_ref_origin(x, y, rot, pos, 0), float(d[0]), -half[0], half[0])
    for k in (1, 2):
        a, b = ref_slab(_ref_origin(x, y, rot, pos, k), float(d[k]), -half[k], half[k])
        np.maximum(t_in, a, out=t_in)
        np.minimum(t_out, b, out=t_out)
    t_in[t_in > t_out] = np.inf
    return t_in


def ref_tube(o0: np.ndarray, o1: np.ndarray, d: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """Infinite cylinder about the local z axis; ``o0``, ``o1`` (ny, nx) local x and y of the line origins."""
    a = float(d[0] ** 2 + d[1] ** 2)
    c = o0**2 + o1**2 - radius * radius
    if a < 1e-12:
        inside = c <= 0.0
        return np.where(inside, -np.inf, np.inf), np.where(inside, np.inf, -np.inf)
    return ref_quadratic_entry(a, 2.0 * (o0 * d[0] + o1 * d[1]), c)


def ref_cylinder_entry(
    x: np.ndarray, y: np.ndarray, rot: np.ndarray, pos: np.ndarray, radius: float, half_height: float
) -> np.ndarray:
    """Solid cylinder along the local z axis (MuJoCo's convention)."""
    d = rot[2]
    a_in, a_out = ref_tube(_ref_origin(x, y, rot, pos, 0), _ref_origin(x, y, rot, pos, 1), d, radius)
    b_in, b_out = ref_slab(_ref_origin(x, y, rot, pos, 2), float(d[2]), -half_height, half_height)
    t_in, t_out = np.maximum(a_in, b_in), np.minimum(a_out, b_out)
    t_in[t_in > t_out] = np.inf
    return t_in


def ref_capsule_entry(x: np.ndarray, y: np.ndarray, rot: np.ndarray, pos: np.ndarray, radius: float,
                      half_length: float) -> np.ndarray:
    caps = [ref_ellipsoid_entry(x, y, rot, pos + rot[:, 2] * s * half_length, np.full(3, radius)) for s in (-1.0, 1.0)]
    return np.minimum(ref_cylinder_entry(x, y, rot, pos, radius, half_length), np.minimum(*caps))


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


# --- windows and cuts: the fast paths agree with a brute-force evaluation of every cell ----------------------

CUTOFF_MM = 2.0


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, q / np.linalg.norm(q))
    return mat.reshape(3, 3)


def _random_pose(rng: np.random.Generator, grid: SensorGrid) -> tuple[np.ndarray, np.ndarray]:
    """A rotation and a centre (mm, pad frame) near the cutoff height, some straddling the grid's edge."""
    x = rng.uniform(grid.x_mm[0] - 4.0, grid.x_mm[-1] + 4.0)
    y = rng.uniform(grid.y_mm[0] - 4.0, grid.y_mm[-1] + 4.0)
    return _random_rotation(rng), np.array([x, y, rng.uniform(-2.0, 6.0)])


def _inside(extent: tuple[float, float, float, float] | None, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    if extent is None:
        return np.zeros(np.broadcast(y[:, None], x[None, :]).shape, bool)
    return (x[None, :] >= extent[0]) & (x[None, :] <= extent[1]) & (y[:, None] >= extent[2]) & (y[:, None] <= extent[3])


PRIMITIVES = {
    # name: (entry on a grid, extent below z_max), sizes in mm drawn per pose
    "sphere": (lambda x, y, r, p, s: gp.ellipsoid_entry(x, y, r, p, np.full(3, s[0])),
               lambda r, p, s, z: gp.ellipsoid_extent(r, p, np.full(3, s[0]), z)),
    "ellipsoid": (lambda x, y, r, p, s: gp.ellipsoid_entry(x, y, r, p, s),
                  lambda r, p, s, z: gp.ellipsoid_extent(r, p, s, z)),
    "box": (lambda x, y, r, p, s: gp.box_entry(x, y, r, p, s), lambda r, p, s, z: gp.box_extent(r, p, s, z)),
    "cylinder": (lambda x, y, r, p, s: gp.cylinder_entry(x, y, r, p, s[0], s[1]),
                 lambda r, p, s, z: gp.cylinder_extent(r, p, s[0], s[1], z)),
}


@pytest.mark.parametrize("kind", sorted(PRIMITIVES))
def test_extents_hold_every_cell_entered_below_the_cut(kind: str) -> None:
    rng = np.random.default_rng(7)
    grid = sensor_grid(MINI, 2)
    entry_of, extent_of = PRIMITIVES[kind]
    below_seen = 0
    for _ in range(60):
        rot, pos = _random_pose(rng, grid)
        size = rng.uniform(0.5, 4.0, size=3)
        entry = entry_of(grid.x_mm, grid.y_mm, rot, pos, size)
        below = entry <= CUTOFF_MM
        extent = extent_of(rot, pos, size, CUTOFF_MM)
        assert not np.any(below & ~_inside(extent, grid.x_mm, grid.y_mm))
        below_seen += int(below.any())
        if extent is not None and kind in ("sphere", "ellipsoid", "box"):
            # exact for these: a fine grid over the box finds entries below the cut within a cell of each side
            fx = np.linspace(extent[0], extent[1], 401)
            fy = np.linspace(extent[2], extent[3], 401)
            hit = entry_of(fx, fy, rot, pos, size) <= CUTOFF_MM + 1e-4
            if hit.any():
                cols, rows = np.flatnonzero(hit.any(axis=0)), np.flatnonzero(hit.any(axis=1))
                assert cols[0] <= 1 and cols[-1] >= 399 and rows[0] <= 1 and rows[-1] >= 399
    assert below_seen > 10  # the poses do exercise the cut


def test_capsule_extent_holds_its_cylinder_and_caps() -> None:
    rng = np.random.default_rng(3)
    grid = sensor_grid(MINI, 2)
    for _ in range(60):
        rot, pos = _random_pose(rng, grid)
        radius, half = rng.uniform(0.5, 3.0), rng.uniform(0.5, 5.0)
        entry = gp.capsule_entry(grid.x_mm, grid.y_mm, rot, pos, radius, half)
        extent = gp.capsule_extent(rot, pos, radius, half, CUTOFF_MM)
        assert not np.any((entry <= CUTOFF_MM) & ~_inside(extent, grid.x_mm, grid.y_mm))


def _reference_raster(x: np.ndarray, y: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Lowest height (ny, nx) mm of triangles ``tri`` (F, 3, 3) over every cell, testing every cell."""
    out = np.full((y.size, x.size), np.inf)
    gx, gy = np.meshgrid(x, y)
    for a, b, c in tri:
        det = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
        if abs(det) <= 1e-12:
            continue
        b1 = ((gx - a[0]) * (c[1] - a[1]) - (gy - a[1]) * (c[0] - a[0])) / det
        b2 = ((b[0] - a[0]) * (gy - a[1]) - (b[1] - a[1]) * (gx - a[0])) / det
        inside = (b1 >= -1e-9) & (b2 >= -1e-9) & (b1 + b2 <= 1.0 + 1e-9)
        z = a[2] + b1 * (b[2] - a[2]) + b2 * (c[2] - a[2])
        out = np.where(inside, np.minimum(out, z), out)
    return out


def test_mesh_scan_below_the_cut_matches_testing_every_cell() -> None:
    rng = np.random.default_rng(11)
    grid = sensor_grid(MINI, 2)
    cube = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
    faces = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    for _ in range(40):
        rot, pos = _random_pose(rng, grid)
        verts = cube * rng.uniform(0.5, 5.0, size=3) + rng.normal(scale=0.3, size=cube.shape)  # not a box
        entry = gp.mesh_entry(grid.x_mm, grid.y_mm, rot, pos, verts, faces, cutoff=CUTOFF_MM)
        ref = _reference_raster(grid.x_mm, grid.y_mm, gp.mesh_triangles(rot, pos, verts, faces))
        below = ref <= CUTOFF_MM
        np.testing.assert_allclose(entry[below], ref[below], rtol=0, atol=1e-9)
        assert np.all(entry[~below] > CUTOFF_MM)
        # without a cut the scan covers the whole mesh
        full = gp.mesh_entry(grid.x_mm, grid.y_mm, rot, pos, verts, faces)
        np.testing.assert_allclose(full[np.isfinite(ref)], ref[np.isfinite(ref)], rtol=0, atol=1e-9)
        assert np.all(np.isinf(full[np.isinf(ref)]))


def _random_scene(rng: np.random.Generator, grid: SensorGrid) -> tuple[mujoco.MjModel, list[str]]:
    """One geom of every supported type, plus a mesh, at random poses about the pad (flipped, as above)."""
    spec = mujoco.MjSpec()
    verts = rng.normal(size=(12, 3)) * 0.003
    spec.add_mesh(name="blob", uservert=verts.ravel().tolist())
    spec.worldbody.add_site(name="pad", pos=[0.001, 0.002, 0.05], euler=[np.pi, 0.0, 0.0])
    kinds = {
        "sphere": (mujoco.mjtGeom.mjGEOM_SPHERE, 1), "ellipsoid": (mujoco.mjtGeom.mjGEOM_ELLIPSOID, 3),
        "box": (mujoco.mjtGeom.mjGEOM_BOX, 3), "cylinder": (mujoco.mjtGeom.mjGEOM_CYLINDER, 2),
        "capsule": (mujoco.mjtGeom.mjGEOM_CAPSULE, 2), "mesh": (mujoco.mjtGeom.mjGEOM_MESH, 0),
    }
    names = []
    for name, (gtype, nsize) in kinds.items():
        for k in range(3):
            rot, pos = _random_pose(rng, grid)
            quat = np.zeros(4)
            mujoco.mju_mat2Quat(quat, rot.ravel())
            # pad frame -> world: the pad is flipped about x and sits at (1, 2, 50) mm
            world = np.array([pos[0] + 1.0, 2.0 - pos[1], 50.0 - pos[2]]) / 1000.0
            flip = np.array([0.0, 1.0, 0.0, 0.0])
            q = np.zeros(4)
            mujoco.mju_mulQuat(q, flip, quat)
            size = np.zeros(3)
            size[:nsize] = rng.uniform(0.5, 4.0, size=nsize) / 1000.0
            geom = spec.worldbody.add_geom(name=f"{name}{k}", type=gtype, pos=world, quat=q, size=size)
            if gtype == mujoco.mjtGeom.mjGEOM_MESH:
                geom.meshname = "blob"
            names.append(f"{name}{k}")
    return spec.compile(), names


def _brute_force_gap(model: mujoco.MjModel, data: mujoco.MjData, names: list[str], grid: SensorGrid) -> np.ndarray:
    """The gap with no windows or cuts: every geom's entry on every cell, then the cutoff."""
    pad = pad_pose(model, data, "pad")
    gap = np.full(grid.shape, np.inf)
    x, y = grid.x_mm, grid.y_mm
    for name in names:
        g = model.geom(name)
        rot = pad.rotation.T @ data.geom_xmat[g.id].reshape(3, 3)
        pos = pad.rotation.T @ (data.geom_xpos[g.id] * 1000.0 - pad.origin_mm)
        size = model.geom_size[g.id] * 1000.0
        gtype = model.geom_type[g.id]
        if gtype == mujoco.mjtGeom.mjGEOM_SPHERE:
            entry = ref_ellipsoid_entry(x, y, rot, pos, np.full(3, size[0]))
        elif gtype == mujoco.mjtGeom.mjGEOM_ELLIPSOID:
            entry = ref_ellipsoid_entry(x, y, rot, pos, size)
        elif gtype == mujoco.mjtGeom.mjGEOM_BOX:
            entry = ref_box_entry(x, y, rot, pos, size)
        elif gtype == mujoco.mjtGeom.mjGEOM_CYLINDER:
            entry = ref_cylinder_entry(x, y, rot, pos, size[0], size[1])
        elif gtype == mujoco.mjtGeom.mjGEOM_CAPSULE:
            entry = ref_capsule_entry(x, y, rot, pos, size[0], size[1])
        else:
            mid = model.geom_dataid[g.id]
            va, vn = model.mesh_vertadr[mid], model.mesh_vertnum[mid]
            fa, fn = model.mesh_faceadr[mid], model.mesh_facenum[mid]
            verts = model.mesh_vert[va : va + vn].astype(np.float64) * 1000.0
            entry = _reference_raster(x, y, gp.mesh_triangles(rot, pos, verts, model.mesh_face[fa : fa + fn]))
        gap = np.minimum(gap, entry)
    return np.where(gap > CUTOFF_MM, GAP_FAR_MM, gap)


@pytest.mark.parametrize("seed", range(4))
def test_gap_field_matches_brute_force_on_random_scenes(seed: int) -> None:
    rng = np.random.default_rng(seed)
    grid = sensor_grid(MINI, 1)
    model, names = _random_scene(rng, grid)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    gap = gap_field(model, data, pad_pose(model, data, "pad"), names, grid, cutoff_mm=CUTOFF_MM)
    ref = _brute_force_gap(model, data, names, grid)
    near = ref < GAP_FAR_MM
    assert near.sum() > 1000  # the scene does reach below the cut
    np.testing.assert_array_equal(gap < GAP_FAR_MM, near)
    np.testing.assert_allclose(gap[near], ref[near], rtol=0, atol=1e-9)


@pytest.mark.parametrize("seed", range(3))
def test_compiled_convex_entries_match_the_array_code(seed: int) -> None:
    """Random poses, including axis-aligned ones (the degenerate slab and tube branches)."""
    rng = np.random.default_rng(seed)
    grid = sensor_grid(MINI, 2)
    x, y = grid.x_mm, grid.y_mm
    for k in range(12):
        if k % 4 == 0:
            rot = np.eye(3)[[1, 2, 0]] if k % 8 else np.eye(3)   # an axis along the line: a != 0 or a == 0
        else:
            q = rng.normal(size=4)
            rot = np.zeros(9)
            mujoco.mju_quat2Mat(rot, q / np.linalg.norm(q))
            rot = rot.reshape(3, 3)
        pos = np.array([rng.uniform(-4, 4), rng.uniform(-4, 4), rng.uniform(-2, 5)])
        size = rng.uniform(0.5, 5.0, 3)
        pairs = [(gp.ellipsoid_entry(x, y, rot, pos, size), ref_ellipsoid_entry(x, y, rot, pos, size)),
                 (gp.box_entry(x, y, rot, pos, size), ref_box_entry(x, y, rot, pos, size)),
                 (gp.cylinder_entry(x, y, rot, pos, size[0], size[1]), ref_cylinder_entry(x, y, rot, pos, size[0], size[1])),
                 (gp.capsule_entry(x, y, rot, pos, size[0], size[1]), ref_capsule_entry(x, y, rot, pos, size[0], size[1]))]
        for got, want in pairs:
            np.testing.assert_array_equal(np.isfinite(got), np.isfinite(want))
            hit = np.isfinite(want)
            assert hit.any() or k % 4 == 0
            np.testing.assert_allclose(got[hit], want[hit], rtol=0, atol=1e-9)


@pytest.mark.parametrize("seed", range(3))
def test_a_gap_field_cut_at_the_gel_keeps_every_overlap(seed: int) -> None:
    """The geometric contact reads only the overlap, so the generator cuts its gap field at the gel surface
    (cutoff 0): every negative gap is exactly what a field cut higher holds, and nothing else is near."""
    rng = np.random.default_rng(10 + seed)
    grid = sensor_grid(MINI, 1)
    model, names = _random_scene(rng, grid)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    pad = pad_pose(model, data, "pad")
    at_gel = gap_field(model, data, pad, names, grid, cutoff_mm=0.0)
    higher = gap_field(model, data, pad, names, grid, cutoff_mm=CUTOFF_MM)
    overlap = higher < 0.0
    assert overlap.sum() > 100
    np.testing.assert_array_equal(at_gel < 0.0, overlap)
    np.testing.assert_array_equal(at_gel[overlap], higher[overlap])
    assert np.all((at_gel[~overlap] == GAP_FAR_MM) | (at_gel[~overlap] <= gp.SLACK_MM))


def test_convex_entries_in_a_window_touch_nothing_outside_it() -> None:
    grid = sensor_grid(MINI, 1)
    x, y = grid.x_mm, grid.y_mm
    rot, pos, size = np.eye(3), np.array([0.5, -0.3, 3.0]), np.array([4.0, 3.0, 3.5])
    win = (slice(60, 170), slice(90, 250))
    for kind in (gp.ELLIPSOID, gp.BOX, gp.CYLINDER):
        whole = np.full(grid.shape, GAP_FAR_MM)
        gp.lower_to_entry(whole, x, y, kind, rot, pos, size)
        part = np.full(grid.shape, GAP_FAR_MM)
        gp.lower_to_entry(part, x, y, kind, rot, pos, size, window=win)
        assert (whole[win] < GAP_FAR_MM).any()
        np.testing.assert_array_equal(part[win], whole[win])
        outside = np.ones(grid.shape, bool)
        outside[win] = False
        assert np.all(part[outside] == GAP_FAR_MM)


@pytest.mark.parametrize("cutoff_mm", [0.0, CUTOFF_MM])
def test_a_reused_gap_field_buffer_gives_the_fresh_field_and_its_box(cutoff_mm: float) -> None:
    """Frame after frame (the pad moving across and away from the objects), the buffer resets only what the
    previous frame wrote, yet holds exactly a fresh field; outside its box everything reads GAP_FAR_MM."""
    from univtac_data.generators.tactile import GapFieldBuffer

    rng = np.random.default_rng(21)
    grid = sensor_grid(MINI, 1)
    model, names = _random_scene(rng, grid)
    names = ["sphere0", "box1", "mesh2"]   # a few parts, so that the written box moves and changes size
    data = mujoco.MjData(model)
    site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "pad")
    start = model.site_pos[site].copy()
    buffer = GapFieldBuffer(grid.shape)
    boxes = []
    for dx_m, dz_m in [(0.0, 0.0), (0.004, 0.0), (-0.003, 0.002), (0.2, 0.0), (0.001, -0.001), (0.0, 0.0)]:
        model.site_pos[site] = start + [dx_m, 0.0, dz_m]
        mujoco.mj_forward(model, data)
        pad = pad_pose(model, data, "pad")
        got = gap_field(model, data, pad, names, grid, cutoff_mm=cutoff_mm, out=buffer)
        assert got is buffer.gap_mm
        np.testing.assert_array_equal(got, gap_field(model, data, pad, names, grid, cutoff_mm=cutoff_mm))
        outside = np.ones(grid.shape, dtype=bool)
        outside[buffer.box] = False
        assert np.all(got[outside] == GAP_FAR_MM)
        boxes.append(((buffer.box[0].start, buffer.box[0].stop, buffer.box[1].start, buffer.box[1].stop),
                      int((got < GAP_FAR_MM).sum())))
    assert len({box for box, _ in boxes}) >= 4
    assert boxes[3][1] == 0 and min(near for _, near in boxes[:3]) > 100   # moved 200 mm aside: nothing near
    with pytest.raises(ValueError, match="GapFieldBuffer of shape"):
        gap_field(model, data, pad, names, sensor_grid(MINI, 2), out=buffer)
