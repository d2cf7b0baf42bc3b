"""The tactile package's public API is what ``__all__`` declares."""

from __future__ import annotations

import numpy as np
import pytest

import univtac_data.generators.tactile as tactile
from univtac_data import get_sensor


def test_all_names_exist_and_are_unique() -> None:
    assert len(set(tactile.__all__)) == len(tactile.__all__)
    for name in tactile.__all__:
        assert hasattr(tactile, name), name


def test_public_callables_are_exported() -> None:
    public = {n for n, v in vars(tactile).items() if not n.startswith("_") and callable(v) and
              getattr(v, "__module__", "").startswith("univtac_data.generators.tactile")}
    assert public <= set(tactile.__all__)


@pytest.mark.parametrize("shape", ["cross", "sphere"])
def test_elastic_warm_start_changes_iterations_not_the_answer(shape: str) -> None:
    """The previous frame's pressure starts the solve when it is the better start: on a cross it saves
    iterations; on a sphere the cold start (Hertz's pressure shape) is already close, and the warm start
    must not cost more."""
    from univtac_data.generators.tactile import ContactConfig, TactileConfig, cross_gap, simulate_frame, sphere_gap

    profile = get_sensor("gelsight_mini")
    config = TactileConfig(contact=ContactConfig(method="elastic", tol=1e-6))

    def gap(depth_mm: float) -> np.ndarray:
        if shape == "cross":
            return cross_gap(profile, 5.0, 2.0, depth_mm, edge_radius_mm=1.5)
        return sphere_gap(profile, radius_mm=5.0, depth_mm=depth_mm)

    first = simulate_frame(profile, gap(0.50), config=config)
    cold = simulate_frame(profile, gap(0.52), config=config)
    warm = simulate_frame(profile, gap(0.52), config=config, state=first.state)
    assert first.state.pressure_mpa is not None
    if shape == "cross":
        assert warm.iterations < cold.iterations
    else:
        assert warm.iterations <= cold.iterations
    assert float(warm.normal_force_n) == pytest.approx(float(cold.normal_force_n), rel=1e-4)
    assert np.abs(warm.depth_um.astype(int) - cold.depth_um.astype(int)).max() <= 1
