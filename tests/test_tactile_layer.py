"""The bonded gel layer (ContactConfig.gel = "layer"): its compliance against Navier's equations and the
thin- and thick-layer limits, its kernel against the oedometric layer, and its contact against the half-space."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.special import j0

from univtac_data.generators.tactile import (
    ContactConfig,
    TactileConfig,
    sensor_grid,
    simulate_frame,
    solve_contact,
    sphere_gap,
)
from univtac_data.generators.tactile.frame import CONTACT_TOL_MM
from univtac_data.generators.tactile.kernels import (
    LAYER_RHO_MAX,
    convolve,
    kernel_set,
    layer_compliance_ratio,
    layer_correction_profile,
)
from univtac_data.schema.sensors import get_sensor

GF225 = get_sensor("gf225")
LAYER = TactileConfig(contact=ContactConfig(method="elastic", gel="layer"))
HALF_SPACE = TactileConfig(contact=ContactConfig(method="elastic", gel="half_space"))


def navier_layer_compliance(k: float, h: float, nu: float) -> float:
    """-u_z(0) / p for a pressure p cos(kx) on a layer -h <= z <= 0 bonded at z = -h (G = 1), solved from
    Navier's equations in plane strain with sympy: an oracle independent of the closed form."""
    sp = pytest.importorskip("sympy")
    z = sp.symbols("z", real=True)
    k, h, nu = sp.nsimplify(k), sp.nsimplify(h), sp.nsimplify(nu)
    lam = 2 * nu / (1 - 2 * nu)
    a = sp.symbols("a0:8")
    u = (a[0] + a[1] * z) * sp.exp(k * z) + (a[2] + a[3] * z) * sp.exp(-k * z)  # u_x = u(z) sin kx
    w = (a[4] + a[5] * z) * sp.exp(k * z) + (a[6] + a[7] * z) * sp.exp(-k * z)  # u_z = w(z) cos kx
    x_eq = sp.expand(sp.diff(u, z, 2) - k**2 * u - (lam + 1) * k * (k * u + sp.diff(w, z)))
    z_eq = sp.expand(sp.diff(w, z, 2) - k**2 * w + (lam + 1) * (k * sp.diff(u, z) + sp.diff(w, z, 2)))
    equations = []
    for eq in (x_eq, z_eq):
        for mode in (sp.exp(k * z), sp.exp(-k * z)):
            part = sp.expand(eq.coeff(mode))
            equations += [part.coeff(z, 0), part.coeff(z, 1)]
    sigma_zz = lam * (k * u + sp.diff(w, z)) + 2 * sp.diff(w, z)
    sigma_xz = sp.diff(u, z) - k * w
    equations += [sigma_zz.subs(z, 0) + 1, sigma_xz.subs(z, 0), u.subs(z, -h), w.subs(z, -h)]
    solution = sp.solve(equations, a, dict=True)[0]
    return float(-w.subs(z, 0).subs(solution))


@pytest.mark.parametrize("k, h, nu", [(1.0, 1.0, 0.3), (2.0, 0.5, 0.48), (0.7, 2.0, 0.45), (3.0, 0.2, 0.1)])
def test_layer_compliance_solves_navier_equations(k: float, h: float, nu: float) -> None:
    # half-space compliance 2 / (E* k) = (1 - nu) / (G k) with G = 1
    closed_form = (1.0 - nu) / k * float(layer_compliance_ratio(np.array(k * h), nu))
    assert closed_form == pytest.approx(navier_layer_compliance(k, h, nu), rel=1e-10)


@pytest.mark.parametrize("nu", [0.3, 0.45, 0.48])
def test_layer_compliance_limits(nu: float) -> None:
    e, h = 0.5, 2.0
    e_star = e / (1 - nu * nu)
    assert float(layer_compliance_ratio(np.array(40.0), nu)) == pytest.approx(1.0, abs=1e-12)  # thick: half-space
    k = 1e-4 / h  # thin: the oedometric layer, u = p h (1 + nu)(1 - 2 nu) / (E (1 - nu))
    thin = 2.0 / (e_star * k) * float(layer_compliance_ratio(np.array(k * h), nu))
    assert thin == pytest.approx(h * (1 + nu) * (1 - 2 * nu) / (e * (1 - nu)), rel=1e-3)
    assert np.isfinite(layer_compliance_ratio(np.array([0.0, 1e3, 1e6]), nu)).all()  # no overflow


def test_incompressible_thin_layer_is_the_squeeze_film() -> None:
    e, h, nu = 0.3, 1.0, 0.5
    g, e_star = e / 3.0, e / 0.75
    for k in (1e-2, 3e-2):
        compliance = 2.0 / (e_star * k) * float(layer_compliance_ratio(np.array(k * h), nu))
        assert compliance == pytest.approx(k * k * h**3 / (3.0 * g), rel=2e-3)


@pytest.mark.parametrize("rho", [0.0, 0.3, 1.0, 2.5, 6.0, 12.0])
def test_correction_profile_matches_adaptive_quadrature(rho: float) -> None:
    nu = 0.48
    expected = quad(lambda s: (layer_compliance_ratio(np.array(s), nu) - 1.0) * j0(s * rho), 0.0, 40.0,
                    limit=2000)[0]
    assert float(layer_correction_profile(np.array(rho), nu)) == pytest.approx(expected, abs=1e-6)


def test_correction_profile_cancels_the_half_space_tail() -> None:
    rho = np.array([LAYER_RHO_MAX - 0.01, LAYER_RHO_MAX + 0.01, 40.0])
    assert np.allclose(layer_correction_profile(rho, 0.48), -1.0 / rho, rtol=1e-4, atol=0)


def test_uniform_pressure_on_a_wide_patch_compresses_the_layer_oedometrically() -> None:
    e, nu, h, dx, n = 0.4, 0.48, 1.0, 0.25, 200
    pressure = np.zeros((n, n))
    pressure[20:140, 20:140] = 0.01  # MPa on a 30 mm square, 15 thicknesses from its centre to its edges
    layer = kernel_set((n, n), dx, dx, e, nu, h)
    u = convolve(pressure, layer.zz, layer.pad_shape)
    oedometric = 0.01 * h * (1 + nu) * (1 - 2 * nu) / (e * (1 - nu))
    assert u[80, 80] == pytest.approx(oedometric, rel=0.01)
    half = kernel_set((n, n), dx, dx, e, nu)
    assert convolve(pressure, half.zz, half.pad_shape)[80, 80] > 20 * oedometric  # a half-space is far softer
    assert u[80, 142] < -0.5 * oedometric  # the squeezed gel piles up beside the patch ...
    assert abs(u[80, 180]) < 2e-3 * oedometric  # ... and ten thicknesses away nothing moves


def test_a_thick_layer_is_the_half_space() -> None:
    half = kernel_set((64, 64), 0.1, 0.1, 0.5, 0.48)
    thick = kernel_set((64, 64), 0.1, 0.1, 0.5, 0.48, 1e4)
    assert np.max(np.abs(thick.zz_centred - half.zz_centred)) < 1e-4 * np.max(half.zz_centred)


def test_layer_contact_is_stiffer_and_stays_local() -> None:
    gap = sphere_gap(GF225, 5.0, 0.3)
    half = simulate_frame(GF225, gap, config=HALF_SPACE)
    layer = simulate_frame(GF225, gap, config=LAYER)
    assert layer.converged and half.converged
    assert float(layer.normal_force_n) > 1.5 * float(half.normal_force_n)  # a = 1.2 mm on a 2 mm gel
    x, y = sensor_grid(GF225, 1).mesh()
    far = np.hypot(x, y) > 4 * GF225.gel_thickness_mm
    assert (half.depth_um[far] > 0).all()  # the half-space sinks in everywhere (1 / r) ...
    assert not layer.depth_um[far].any()  # ... the bonded layer within a few thicknesses
    overlap = np.maximum(-gap, 0.0)
    assert np.all(layer.depth_mm >= overlap - 1e-6)  # the gel never passes through the object
    contact = layer.contact_mask
    assert np.allclose(layer.depth_mm[contact], overlap[contact], atol=CONTACT_TOL_MM)


def test_layer_stiffening_vanishes_as_the_contact_shrinks_against_the_thickness() -> None:
    mini = get_sensor("gelsight_mini")  # 4 mm of gel
    ratios = []
    for depth in (0.02, 0.05, 0.2):  # sphere of 5 mm: a / h = 0.08, 0.13, 0.25
        gap = sphere_gap(mini, 5.0, depth)
        ratios.append(float(simulate_frame(mini, gap, config=LAYER).normal_force_n)
                      / float(simulate_frame(mini, gap, config=HALF_SPACE).normal_force_n))
    assert 1.0 < ratios[0] < 1.12 and ratios[0] < ratios[1] < ratios[2] < 1.5


def test_layer_needs_a_thickness_and_a_known_gel_model() -> None:
    grid = sensor_grid(GF225, 3)
    gap = np.full(grid.shape, 1.0)
    with pytest.raises(ValueError, match="thickness"):
        solve_contact(gap, grid, GF225.material, ContactConfig(gel="layer"))
    with pytest.raises(ValueError, match="'layer' or 'half_space'"):
        solve_contact(gap, grid, GF225.material, ContactConfig(gel="plate"), thickness_mm=2.0)  # type: ignore[arg-type]
