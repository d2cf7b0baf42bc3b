"""The elastic normal solve itself: its compiled convolution, its preconditioner, and that what it returns solves
the contact problem (r = K p + g >= 0, p >= 0, r p = 0), whatever it starts from.

The accuracy against closed forms (Hertz, flat punch, Cerruti) is in test_tactile_mechanics.py."""

from __future__ import annotations

import numpy as np
import pytest

from univtac_data.generators.tactile import (
    ContactConfig, cylinder_gap, punch_gap, sensor_grid, solve_contact, sphere_gap,
)
from univtac_data.generators.tactile.contact_elastic import _convolve_rows, pk_solve
from univtac_data.generators.tactile.kernels import convolve, kernel_set
from univtac_data.generators.tactile.sensor_model import downsample_overlap_or_mean
from univtac_data.schema.sensors import get_sensor

MINI = get_sensor("gelsight_mini")
STEP = ContactConfig().solver_step


def _solver_gap(gap: np.ndarray) -> np.ndarray:
    return downsample_overlap_or_mean(gap, STEP)


def _gaps() -> dict[str, np.ndarray]:
    """Solver-grid gaps (mm): a sphere, a punch, and a cylinder across the whole pad (the long contact whose
    window is the grid)."""
    return {
        "sphere": _solver_gap(sphere_gap(MINI, 4.0, 0.6, (0.7, -0.4))),
        "punch": _solver_gap(punch_gap(MINI, 2.0, 0.3, (0.031, -0.017))),
        "cylinder": _solver_gap(cylinder_gap(MINI, 3.0, 1.0, angle_rad=np.deg2rad(30.0))),
    }


def _residual(gap: np.ndarray, pressure: np.ndarray) -> np.ndarray:
    """r = K p + g (mm) over the grid in double precision, with the half-space kernel of the solver's grid."""
    grid = sensor_grid(MINI, STEP)
    m = MINI.material
    ks = kernel_set(gap.shape, grid.dx_mm, grid.dy_mm, m.youngs_modulus_mpa, m.poisson_ratio)
    return convolve(pressure, ks.zz, ks.pad_shape) + gap


@pytest.mark.parametrize("name", ["sphere", "punch", "cylinder"])
def test_solution_meets_the_complementarity_conditions(name: str) -> None:
    gap = _gaps()[name]
    result = solve_contact(gap, sensor_grid(MINI, STEP), MINI.material, ContactConfig())
    assert result.converged
    p = result.pressure_mpa
    r = _residual(gap, p)
    depth = float(np.max(-gap))
    assert p.min() >= 0.0
    # in contact the gel meets the object (to the solver's tolerance); elsewhere it does not reach it
    assert np.abs(r[p > 0.0]).max() < 1e-5 * depth
    assert r[p == 0.0].min() > -1e-4 * depth


@pytest.mark.parametrize("name", ["sphere", "cylinder"])
def test_depth_is_the_displacement_of_the_pressure(name: str) -> None:
    """Off the contact the surface is K p, whether the window is a part of the grid (sphere: a separate
    convolution) or all of it (cylinder: the iteration's own K p)."""
    gap = _gaps()[name]
    result = solve_contact(gap, sensor_grid(MINI, STEP), MINI.material, ContactConfig())
    free = ~result.contact_mask
    displacement = _residual(gap, result.pressure_mpa) - gap
    np.testing.assert_allclose(result.depth_mm[free], np.maximum(displacement[free], 0.0), rtol=0, atol=2e-6)
    np.testing.assert_array_equal(result.depth_mm[result.contact_mask], -gap[result.contact_mask])


def test_long_contact_converges_in_few_iterations() -> None:
    """The circulant preconditioner: a cylinder across the pad took 46 iterations without it, 15 with it."""
    result = solve_contact(_gaps()["cylinder"], sensor_grid(MINI, STEP), MINI.material, ContactConfig())
    assert result.converged
    assert result.iterations <= 25


@pytest.mark.parametrize("start", ["uniform", "shifted", "tiny"])
def test_the_start_changes_iterations_not_the_answer(start: str) -> None:
    gap = _gaps()["sphere"]
    grid = sensor_grid(MINI, STEP)
    cold, _, _ = pk_solve(gap, grid.dx_mm, grid.dy_mm, MINI.material, 1e-6, 300)
    p_init = {"uniform": np.where(gap < 0.0, 0.05, 0.0), "shifted": np.roll(cold, (3, -2), axis=(0, 1)),
              "tiny": 1e-9 * cold}[start]
    warm, _, converged = pk_solve(gap, grid.dx_mm, grid.dy_mm, MINI.material, 1e-6, 300, p_init)
    assert converged
    assert warm.sum() == pytest.approx(cold.sum(), rel=1e-5)
    np.testing.assert_allclose(warm, cold, rtol=0, atol=1e-4 * cold.max())


def test_preconditioner_is_positive_and_inverts_the_operator_on_smooth_loads() -> None:
    """Strang's circulant of the normal influence coefficients, inverted frequency by frequency: positive, and
    K p multiplied by it gives p back, away from the window's edges, for a smooth p well inside it."""
    grid = sensor_grid(MINI, STEP)
    m = MINI.material
    shape = (48, 64)
    ks = kernel_set(shape, grid.dx_mm, grid.dy_mm, m.youngs_modulus_mpa, m.poisson_ratio)
    inverse = ks.zz_preconditioner
    assert inverse.shape == (shape[0], shape[1] // 2 + 1) and inverse.dtype == np.float32
    assert inverse.min() > 0.0
    y, x = np.mgrid[: shape[0], : shape[1]]
    p = np.exp(-(((y - 24.0) / 5.0) ** 2 + ((x - 32.0) / 6.0) ** 2))
    u = convolve(p, ks.zz, ks.pad_shape)
    back = np.fft.irfft2(np.fft.rfft2(u) * inverse, s=shape)
    inner = (slice(12, 36), slice(16, 48))
    assert np.abs(back[inner] - p[inner]).max() < 0.01 * p.max()


@pytest.mark.parametrize("rows", [(0, 17), (3, 9)])
def test_compiled_convolution_equals_the_array_code(rows: tuple[int, int]) -> None:
    shape = (17, 12)
    ks = kernel_set(shape, 0.12, 0.11, 0.3, 0.48)
    field = np.random.default_rng(7).random(shape).astype(np.float32)
    field[: rows[0]] = 0.0
    field[rows[1] :] = 0.0
    got = _convolve_rows(field, ks.zz_single, ks.pad_shape, *rows)
    want = convolve(field.astype(np.float64), ks.zz, ks.pad_shape)
    assert got.dtype == np.float32
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-5 * np.abs(want).max())
