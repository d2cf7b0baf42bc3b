"""The bonded gel layer (ContactConfig.gel = "layer"): its compliance against Navier's equations and the
thin- and thick-layer limits, its kernel against the oedometric layer, and its contact against the half-space."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.special import j0, jv

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
    layer_profile,
    layer_ratios,
)
from univtac_data.schema.sensors import get_sensor

GF225 = get_sensor("gf225")


def normal_ratio(s: np.ndarray, nu: float) -> np.ndarray:
    """R_N(s): the bonded layer's normal surface compliance over the half-space's."""
    return layer_ratios(s, nu)[0]
LAYER = TactileConfig(contact=ContactConfig(method="elastic", gel="layer"))
HALF_SPACE = TactileConfig(contact=ContactConfig(method="elastic", gel="half_space"))


def navier_layer_response(k: float, h: float, nu: float, load: str) -> tuple[float, float]:
    """(u_x(0), u_z(0)) amplitudes (u_x = u sin kx, u_z = w cos kx) for a unit pressure cos(kx) (``load`` =
    "normal") or a unit shear traction sin(kx) along x ("shear") on a layer -h <= z <= 0 bonded at z = -h
    (G = 1), solved from Navier's equations in plane strain with sympy: an oracle independent of the closed
    forms."""
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
    top = [sigma_zz.subs(z, 0) + 1, sigma_xz.subs(z, 0)] if load == "normal" else \
        [sigma_zz.subs(z, 0), sigma_xz.subs(z, 0) - 1]
    equations += [*top, u.subs(z, -h), w.subs(z, -h)]
    solution = sp.solve(equations, a, dict=True)[0]
    return float(u.subs(z, 0).subs(solution)), float(w.subs(z, 0).subs(solution))


@pytest.mark.parametrize("k, h, nu", [(1.0, 1.0, 0.3), (2.0, 0.5, 0.48), (0.7, 2.0, 0.45), (3.0, 0.2, 0.1)])
def test_layer_compliances_solve_navier_equations(k: float, h: float, nu: float) -> None:
    normal, along, across, coupling = (float(r) for r in layer_ratios(np.array(k * h), nu))
    u_pressed, w_pressed = navier_layer_response(k, h, nu, "normal")
    u_sheared, w_sheared = navier_layer_response(k, h, nu, "shear")
    # half-space compliances with G = 1: normal 2 / (E* k) = (1 - nu) / k, along k (1 - nu) / k
    assert (1.0 - nu) / k * normal == pytest.approx(-w_pressed, rel=1e-10)
    assert (1.0 - nu) / k * along == pytest.approx(u_sheared, rel=1e-10)
    assert coupling / k == pytest.approx(u_pressed, rel=1e-10)
    assert w_sheared == pytest.approx(-u_pressed, rel=1e-10)   # Maxwell-Betti reciprocity
    # across k, anti-plane shear: G u'' = G k^2 u, G u'(0) = 1, u(-h) = 0 gives u(0) = tanh(k h) / (G k)
    assert across == pytest.approx(np.tanh(k * h), rel=1e-12)
    _, _, _, far = layer_ratios(np.array(40.0), nu)
    assert float(far) == pytest.approx(-(1.0 - 2.0 * nu) / 2.0, rel=1e-9)   # half-space: toward the load


@pytest.mark.parametrize("nu", [0.3, 0.45, 0.48])
def test_layer_compliance_limits(nu: float) -> None:
    e, h = 0.5, 2.0
    e_star = e / (1 - nu * nu)
    assert float(normal_ratio(np.array(40.0), nu)) == pytest.approx(1.0, abs=1e-12)  # thick: half-space
    k = 1e-4 / h  # thin: the oedometric layer, u = p h (1 + nu)(1 - 2 nu) / (E (1 - nu))
    thin = 2.0 / (e_star * k) * float(normal_ratio(np.array(k * h), nu))
    assert thin == pytest.approx(h * (1 + nu) * (1 - 2 * nu) / (e * (1 - nu)), rel=1e-3)
    assert np.isfinite(normal_ratio(np.array([0.0, 1e3, 1e6]), nu)).all()  # no overflow


def test_incompressible_thin_layer_is_the_squeeze_film() -> None:
    e, h, nu = 0.3, 1.0, 0.5
    g, e_star = e / 3.0, e / 0.75
    for k in (1e-2, 3e-2):
        compliance = 2.0 / (e_star * k) * float(normal_ratio(np.array(k * h), nu))
        assert compliance == pytest.approx(k * k * h**3 / (3.0 * g), rel=2e-3)


@pytest.mark.parametrize("rho", [0.0, 0.3, 1.0, 2.5, 6.0, 12.0])
def test_correction_profile_matches_adaptive_quadrature(rho: float) -> None:
    nu = 0.48
    expected = quad(lambda s: (normal_ratio(np.array(s), nu) - 1.0) * j0(s * rho), 0.0, 40.0,
                    limit=2000)[0]
    assert float(layer_profile("normal", np.array(rho), nu)) == pytest.approx(expected, abs=1e-6)


def test_correction_profile_cancels_the_half_space_tail() -> None:
    rho = np.array([LAYER_RHO_MAX - 0.01, LAYER_RHO_MAX + 0.01, 40.0])
    assert np.allclose(layer_profile("normal", rho, 0.48), -1.0 / rho, rtol=1e-4, atol=0)


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


@pytest.mark.parametrize("term, order", [("tangential_a", 0), ("tangential_b0", 0), ("tangential_b2", 2),
                                         ("coupling", 1)])
def test_tangential_and_coupling_profiles_match_adaptive_quadrature(term: str, order: int) -> None:
    nu = 0.48
    along, across, coupling = (lambda s: layer_ratios(np.array(s), nu)[1], lambda s: np.tanh(s),
                               lambda s: layer_ratios(np.array(s), nu)[3])
    g = {"tangential_a": lambda s: across(s) - 1.0,
         "tangential_b0": lambda s: (1 - nu) * (along(s) - 1.0) - (across(s) - 1.0),
         "tangential_b2": lambda s: (1 - nu) * (along(s) - 1.0) - (across(s) - 1.0),
         "coupling": lambda s: coupling(s) + (1 - 2 * nu) / 2}[term]
    for rho in (0.0, 0.4, 1.5, 5.0, 12.0, 30.0):
        expected = quad(lambda s: float(g(s)) * jv(order, s * rho), 0.0, 40.0, limit=4000)[0]
        assert float(layer_profile(term, np.array(rho), nu)) == pytest.approx(expected, abs=2e-6)


def gaussian_field_oracle(q_hat, kernel, order: int, r: float) -> float:  # type: ignore[no-untyped-def]
    """(1 / 2 pi) integral_0^inf q_hat(k) kernel(k) Jn(k r) k dk: the inverse 2-D Fourier transform of a
    radial spectrum times cos(n theta)-type angular factor left to the caller."""
    return quad(lambda k: q_hat(k) * kernel(k) * jv(order, k * r) * k, 0.0, 60.0, limit=4000)[0] / (2 * np.pi)


def test_layer_kernels_reproduce_the_continuous_layer_under_a_gaussian_load() -> None:
    """Every coefficient of the layer (normal, tangential, pressure -> in-plane), applied by the solver's
    convolution to a Gaussian load on the grid, against the continuous layer's response from its Fourier
    compliances: checks the spatial corrections, their signs and the anisotropic terms."""
    e, nu, h, dx, n, sigma = 0.5, 0.48, 1.0, 0.1, 128, 0.4
    g_mod, e_star = e / (2 * (1 + nu)), e / (1 - nu * nu)
    ks = kernel_set((n, n), dx, dx, e, nu, h)
    y, x = (np.mgrid[0:n, 0:n] - n // 2) * dx
    load = np.exp(-(x * x + y * y) / (2 * sigma * sigma))
    q_hat = lambda k: 2 * np.pi * sigma**2 * np.exp(-(k * sigma) ** 2 / 2)  # noqa: E731
    ratio = lambda k, i: float(layer_ratios(np.array(k * h), nu)[i])  # noqa: E731
    u_z = convolve(load, ks.zz, ks.pad_shape)
    xx, xy, _ = ks.tangential()
    rx, _ = ks.radial()
    u_x, u_y = convolve(load, xx, ks.pad_shape), convolve(load, xy, ks.pad_shape)
    radial_x = convolve(load, rx, ks.pad_shape)
    iso = lambda k: (ratio(k, 2) + 0.5 * ((1 - nu) * ratio(k, 1) - ratio(k, 2))) / (g_mod * k)  # noqa: E731
    aniso = lambda k: 0.5 * ((1 - nu) * ratio(k, 1) - ratio(k, 2)) / (g_mod * k)  # noqa: E731
    c = n // 2
    for offset in (0, 4, 10, 20):   # cells from the load's centre: 0 to 2 thicknesses
        r = offset * dx
        normal = gaussian_field_oracle(q_hat, lambda k: 2 * ratio(k, 0) / (e_star * k), 0, r)
        assert u_z[c, c + offset] == pytest.approx(normal, abs=0.02 * u_z[c, c])
        along_x = gaussian_field_oracle(q_hat, iso, 0, r) - gaussian_field_oracle(q_hat, aniso, 2, r)  # theta 0
        across_x = gaussian_field_oracle(q_hat, iso, 0, r) + gaussian_field_oracle(q_hat, aniso, 2, r)  # 90 deg
        assert u_x[c, c + offset] == pytest.approx(along_x, abs=0.02 * u_x[c, c])
        assert u_x[c + offset, c] == pytest.approx(across_x, abs=0.02 * u_x[c, c])
        if offset:
            diagonal = -gaussian_field_oracle(q_hat, aniso, 2, r * np.sqrt(2))   # theta 45 deg: sin 2 theta = 1
            assert u_y[c + offset, c + offset] == pytest.approx(diagonal, abs=0.02 * u_x[c, c])
            outward = gaussian_field_oracle(q_hat, lambda k: ratio(k, 3) / (g_mod * k), 1, r)
            assert radial_x[c, c + offset] == pytest.approx(outward, abs=0.03 * abs(outward) + 1e-4 * u_z[c, c])
    assert radial_x[c, c + 10] > 0   # a pressed, nearly incompressible layer pushes its surface outward


def test_layer_markers_spread_under_a_press_and_its_shear_is_stiffer() -> None:
    mini = get_sensor("gelsight_mini")
    gap = sphere_gap(mini, 8.0, 0.6)
    centre = np.array([mini.image_width_px / 2, mini.image_height_px / 2])
    radial = {}
    for name, config in (("half", HALF_SPACE), ("layer", LAYER)):
        frame = simulate_frame(mini, gap, config=replace(config, perspective_markers=False))   # no parallax
        moved = frame.markers_px - frame.markers_ref_px
        outward = frame.markers_ref_px - centre
        distance = np.linalg.norm(outward, axis=1)
        near = (distance > 20) & (distance < 60)   # a ring of markers just outside the contact (a = 2.2 mm)
        radial[name] = float(np.mean(np.sum(moved[near] * outward[near], axis=1) / distance[near]))
    assert radial["half"] < 0.0 < radial["layer"]   # drawn toward the load / squeezed outward
    dragged = {name: simulate_frame(mini, gap, tangential_mm=(0.05, 0.0), config=config)
               for name, config in (("half", HALF_SPACE), ("layer", LAYER))}
    assert float(dragged["layer"].slip_mm) == float(dragged["half"].slip_mm) == 0.0   # both stuck
    assert float(dragged["layer"].shear_force_n[0]) > 1.2 * float(dragged["half"].shear_force_n[0]) > 0.0
