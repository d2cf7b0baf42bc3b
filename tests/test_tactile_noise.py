"""Seeded sensor noise: counter-based, byte-identical for a seed in any process and any order, Gaussian."""

from __future__ import annotations

import hashlib
import subprocess
import sys

import numpy as np
import pytest

from univtac_data.generators.tactile import simulate_frame, sphere_gap
from univtac_data.generators.tactile.noise import gaussian_table, noise_field, noisy_image
from univtac_data.generators.tactile.optics import ShadingConfig, background_image, render_shaded
from univtac_data.schema.sensors import get_sensor

MINI = get_sensor("gelsight_mini")

# sha256 of noise_field(12345, (240, 320, 3), 1.5): pinned, so that a change of the generator (or a platform
# on which it computes other bytes) is seen, since datasets made with noise depend on it
PINNED_SHA256 = "e84439ee2e8d417b9ef83566219f160e781e75e01e93a6411435b702ed7d8860"


def test_noise_bytes_are_pinned_and_equal_in_a_fresh_process() -> None:
    here = hashlib.sha256(noise_field(12345, (240, 320, 3), 1.5).tobytes()).hexdigest()
    assert here == PINNED_SHA256
    code = ("import hashlib; from univtac_data.generators.tactile.noise import noise_field; "
            "print(hashlib.sha256(noise_field(12345, (240, 320, 3), 1.5).tobytes()).hexdigest())")
    other = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert other == PINNED_SHA256


def test_noise_is_gaussian_uncorrelated_and_differs_by_seed() -> None:
    a = noise_field(7, (240, 320, 3), 1.5).astype(np.float64)
    b = noise_field(8, (240, 320, 3), 1.5).astype(np.float64)
    assert abs(a.mean()) < 0.01 and a.std() == pytest.approx(1.5, rel=0.01)
    assert np.mean(np.abs(a) < 1.5) == pytest.approx(0.6827, abs=0.005)  # one sigma
    assert abs(np.corrcoef(a.ravel(), b.ravel())[0, 1]) < 0.01
    for axis in (0, 1, 2):  # neighbouring rows, columns and channels are independent
        lead, lag = np.moveaxis(a, axis, 0)[1:].ravel(), np.moveaxis(a, axis, 0)[:-1].ravel()
        assert abs(np.corrcoef(lead, lag)[0, 1]) < 0.01
    table = gaussian_table()
    assert table.dtype == np.float32 and float(np.mean(table.astype(np.float64) ** 2)) == pytest.approx(1.0, rel=1e-6)
    assert noise_field(0, (2, 2, 3), 1.0).std() > 0.1  # seed 0 is a stream like any other


def test_noisy_image_adds_exactly_the_noise_field() -> None:
    background = np.full((24, 30, 3), 100.25, np.float32)
    change = np.full((4, 5, 3), 20.0, np.float32)
    out = noisy_image(background, change, (slice(3, 7), slice(10, 15)), 99, 2.0, np.empty((24, 30, 3), np.uint8))
    expected = background + noise_field(99, (24, 30, 3), 2.0)
    expected[3:7, 10:15] += 20.0
    assert np.array_equal(out, np.clip(np.rint(expected), 0, 255).astype(np.uint8))
    # odd widths: the counters of a row do not start on a group of four
    odd = noisy_image(np.full((5, 7, 3), 50.0, np.float32), None, None, 3, 1.0, np.empty((5, 7, 3), np.uint8))
    assert np.array_equal(odd, np.rint(50.0 + noise_field(3, (5, 7, 3), 1.0)).astype(np.uint8))


@pytest.mark.parametrize("method", ["geometric", "elastic"])
def test_frame_noise_is_byte_identical_for_a_seed_in_any_order(method: str) -> None:
    gap = sphere_gap(MINI, 5.0, 0.4)
    seeds = [3, 11, 3, 2**40 + 5]
    frames = [simulate_frame(MINI, gap, method=method, noise_seed=s).marked_rgb for s in seeds]  # type: ignore[arg-type]
    assert np.array_equal(frames[0], frames[2])
    assert not np.array_equal(frames[0], frames[1]) and not np.array_equal(frames[0], frames[3])
    clean = simulate_frame(MINI, gap, method=method).pure_rgb  # type: ignore[arg-type]
    noisy = simulate_frame(MINI, gap, method=method, noise_seed=3).pure_rgb  # type: ignore[arg-type]
    assert (noisy.astype(float) - clean).std() == pytest.approx(ShadingConfig().noise_std, rel=0.05)


def test_noisy_render_is_the_clean_render_plus_the_noise() -> None:
    """Away from the contact the noisy image is the background plus exactly the seed's noise field."""
    depth = np.zeros((240, 320))
    out = render_shaded(depth, MINI, ShadingConfig(noise_std=1.5), noise_seed=21)
    want = background_image(MINI).astype(np.float32) + noise_field(21, (240, 320, 3), 1.5)
    assert np.array_equal(out, np.clip(np.rint(want), 0, 255).astype(np.uint8))
