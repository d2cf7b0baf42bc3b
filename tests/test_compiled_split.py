"""benchmarks/compiled_split.py: the clock behind the benchmarks' ceiling rate (frames / CPU seconds inside
compiled code). Its numbers are timings, so these tests check what it wraps and how it files the seconds,
not how many there are."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))

import compiled_split  # noqa: E402
import mujoco  # noqa: E402
import numcodecs.blosc  # noqa: E402
import scipy.fft  # noqa: E402
from numba.core.registry import CPUDispatcher  # noqa: E402

from univtac_data.generators.tactile import optics  # noqa: E402
from univtac_data.generators.tactile import simulate_frame  # noqa: E402
from univtac_data.schema.sensors import SENSORS  # noqa: E402


def test_a_call_inside_a_timed_call_is_not_counted_again_and_goes_under_the_key_of_its_time() -> None:
    stage = ["tactile"]
    clock = compiled_split.CompiledClock(key=lambda: stage[0])
    inner_calls = []
    inner = clock.wrap(lambda x: inner_calls.append(clock._inside) or x + 1)
    outer = clock.wrap(lambda x: inner(x) * 2)
    assert outer(1) == 4 and inner_calls == [True]  # the inner call ran inside the outer one's timing
    assert set(clock.seconds) == {"tactile"}
    stage[0] = "writing"
    assert inner(1) == 2
    assert set(clock.seconds) == {"tactile", "writing"}
    assert all(s >= 0.0 for s in clock.seconds.values())


def test_install_wraps_every_compiled_entry_point_keeps_results_and_uninstall_puts_the_originals_back() -> None:
    profile = SENSORS["gelsight_mini"]
    h, w = profile.image_height_px, profile.image_width_px
    y, x = np.mgrid[:h, :w]
    gap = np.hypot(x - w / 2, y - h / 2) ** 2 * 1e-4 - 0.3  # a sphere-like press, 0.3 mm deep at the centre
    before = simulate_frame(profile, gap, tangential_mm=(0.01, 0.0))
    kernel = optics._shade_kernel
    blosc, step, model_compiler = numcodecs.blosc.compress, mujoco.mj_step, mujoco.MjModel.from_xml_string
    clock = compiled_split.CompiledClock()
    wrapped = clock.install()
    try:
        assert wrapped > 100
        assert not isinstance(optics._shade_kernel, CPUDispatcher)
        assert numcodecs.blosc.compress is not blosc and mujoco.mj_step is not step
        assert scipy.fft.rfft.__wrapped__ is not None
        assert mujoco.MjModel.from_xml_string("<mujoco/>").nbody == 1  # still a static method
        after = simulate_frame(profile, gap, tangential_mm=(0.01, 0.0))
        assert clock.seconds["all"] > 0.0
    finally:
        clock.uninstall()
    for name in ("pure_rgb", "marked_rgb", "depth_um", "markers_px", "shear_force_n"):
        np.testing.assert_array_equal(getattr(after, name), getattr(before, name))
    assert optics._shade_kernel is kernel
    assert numcodecs.blosc.compress is blosc and mujoco.mj_step is step
    assert mujoco.MjModel.from_xml_string is model_compiler
