"""Optical models: the shaded renderer and the Taxim-format calibrated renderer."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from univtac_data.generators.tactile import (
    TactileConfig, load_taxim_calibration, render_shaded, simulate_frame, sphere_gap,
)
from univtac_data.generators.tactile.optics import background_image
from univtac_data.schema.sensors import get_sensor
from univtac_data.storage.errors import DatasetError

MINI = get_sensor("gelsight_mini")
BINS = 9


def write_calibration(folder: Path, h: int = 48, w: int = 64) -> None:
    """A synthetic Taxim folder: each channel's constant term encodes its bin, f0 is flat BGR (40, 90, 160)."""
    folder.mkdir(parents=True, exist_ok=True)
    i_mag, i_dir = np.meshgrid(np.arange(BINS), np.arange(BINS), indexing="ij")
    tables = {}
    for k, name in enumerate(("grad_r", "grad_g", "grad_b")):
        t = np.zeros((BINS, BINS, 6))
        t[..., 5] = (k + 1) * i_mag + 0.5 * i_dir  # constant term
        tables[name] = t
    tables["grad_r"][..., 3] = 0.1  # an x term in the first stored (blue) channel: 0.1 * calibration column
    np.savez(folder / "polycalib.npz", bins=np.int32(BINS), **tables)
    f0 = np.zeros((h, w, 3), np.uint8)
    f0[:] = (40, 90, 160)
    np.savez(folder / "dataPack.npz", f0=f0)
    (folder / "params.json").write_text(json.dumps({"sensor": {"pixmm": 0.05, "num_bins": BINS, "h": h, "w": w}}))


def test_calibrated_flat_gel_is_f0(tmp_path: Path) -> None:
    """An untouched pad renders as the calibration's background frame: each pixel's bin polynomial minus the
    flat bin's (Taxim adds the flat bin's polynomial everywhere, which shifts the untouched gel)."""
    write_calibration(tmp_path / "calib")
    calib = load_taxim_calibration(tmp_path / "calib")
    assert calib.pixmm == 0.05 and calib.bins == BINS and calib.field_mm == pytest.approx((3.2, 2.4))
    img = calib.render(np.zeros((24, 32)), (0.1, 0.1))
    # stored BGR: f0 (40, 90, 160) is RGB (160, 90, 40)
    np.testing.assert_array_equal(img, np.broadcast_to(np.array([160, 90, 40], np.uint8), (24, 32, 3)))
    np.testing.assert_array_equal(calib.render_lookup(np.zeros((24, 32)), (0.1, 0.1)), img)
    np.testing.assert_array_equal(calib.background((24, 32)), img)


def test_calibrated_slopes_pick_their_bins(tmp_path: Path) -> None:
    write_calibration(tmp_path / "calib")
    calib = load_taxim_calibration(tmp_path / "calib")
    # a ramp rising along +column with slope 1 (45 deg): magnitude bin floor((pi/4) / ((pi/2) / 8)) = 4,
    # direction atan2(0, 1) = 0 -> bin floor(pi / (2 pi / 8)) = 4; the flat bin is (0, 4)
    depth = np.tile(np.arange(32) * 0.1, (24, 1)) + 1.0
    for img in (calib.render(depth, (0.1, 0.1)), calib.render_lookup(depth, (0.1, 0.1))):
        assert img[10, 10, 0] == np.rint(160 + 3 * 4 + 0.5 * 4 - 0.5 * 4)
        assert img[10, 10, 1] == np.rint(90 + 2 * 4 + 0.5 * 4 - 0.5 * 4)
        assert img[10, 10, 2] == np.rint(40 + 1 * 4 + 0.5 * 4 - 0.5 * 4)  # the x terms cancel
    # a slope in the first magnitude bin (below 0.73 deg at 125 bins; here (pi/2)/8 = 11 deg) is flat
    gentle = np.tile(np.arange(32) * 0.001, (24, 1)) + 1.0
    np.testing.assert_array_equal(calib.render(gentle, (0.1, 0.1)), calib.background((24, 32)))


def test_calibrated_mode_in_the_entry_point(tmp_path: Path) -> None:
    write_calibration(tmp_path / "calib")
    config = TactileConfig(optics="calibrated", calibration=load_taxim_calibration(tmp_path / "calib"))
    frame = simulate_frame(MINI, sphere_gap(MINI, 4.0, 0.5), config=config)
    assert frame.pure_rgb.shape == (240, 320, 3) and frame.pure_rgb.dtype == np.uint8
    flat = frame.pure_rgb[5, 5]
    assert np.array_equal(flat, [160, 90, 40])  # f0
    changed = (frame.pure_rgb != flat).any(axis=-1)
    assert changed[100:140, 140:180].any() and not changed[:40].any()  # at the contact, and only there


def test_calibrated_frame_written_into_buffers_equals_a_new_frame(tmp_path: Path) -> None:
    from univtac_data.generators.tactile import PixelBuffers

    write_calibration(tmp_path / "calib")
    config = TactileConfig(optics="calibrated", calibration=load_taxim_calibration(tmp_path / "calib"))
    gap = sphere_gap(MINI, 4.0, 0.5)
    fresh = simulate_frame(MINI, gap, config=config, noise_seed=2)
    buffers = PixelBuffers(**{name: np.full(shape, 77, dtype) for name, (shape, dtype)
                              in PixelBuffers.layout(MINI.image_height_px, MINI.image_width_px).items()})
    written = simulate_frame(MINI, gap, config=config, noise_seed=2, out=buffers)
    assert written.pure_rgb is buffers.pure_rgb and written.marked_rgb is buffers.marked_rgb
    for name in ("marked_rgb", "pure_rgb", "depth_um", "contact_mask"):
        np.testing.assert_array_equal(getattr(written, name), getattr(fresh, name), err_msg=name)


def test_missing_calibration_file_names_it(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="polycalib.npz"):
        load_taxim_calibration(tmp_path)


def test_real_taxim_calibration_when_installed() -> None:
    pytest.importorskip("taxim")
    from univtac_data.generators.tactile import taxim_calibration_dir

    calib = load_taxim_calibration(taxim_calibration_dir("gelsight_mini"))
    assert calib.poly.shape == (3, 125, 125, 6) and calib.f0.shape == (480, 640, 3)
    assert calib.field_mm == pytest.approx((640 * 0.0295, 480 * 0.0295))
    img = calib.render(np.zeros((240, 320)), (MINI.mm_per_px_x, MINI.mm_per_px_y))
    assert 20 < float(img.mean()) < 235
    # the untouched pad is f0 (resized) to within one grey level
    from scipy.ndimage import zoom

    f0 = zoom(calib.f0, (0.5, 0.5, 1), order=1, grid_mode=True, mode="nearest")
    assert np.abs(img.astype(float) - f0).max() <= 1.0


@pytest.mark.parametrize("method", ["geometric", "elastic"])
def test_calibrated_fast_path_equals_the_full_lookup(method: str) -> None:
    """The compiled render looks up only deformed pixels with a slope past the first magnitude bin; the plain
    lookup of every pixel gives the same image within one grey level (on the real Mini calibration when taxim is
    installed, else on a synthetic one with position terms)."""
    try:
        from univtac_data.generators.tactile import taxim_calibration_dir

        calib = load_taxim_calibration(taxim_calibration_dir("gelsight_mini"))
    except DatasetError:
        calib = synthetic_calibration()
    for gap in (sphere_gap(MINI, 5.0, 0.4), np.minimum(sphere_gap(MINI, 3.0, 0.8, (-6.0, 3.0)),
                                                        sphere_gap(MINI, 8.0, 0.2, (7.0, -4.0)))):
        frame = simulate_frame(MINI, gap, method=method, config=TactileConfig())  # type: ignore[arg-type]
        pitch = (MINI.mm_per_px_x, MINI.mm_per_px_y)
        fast = calib.render(frame.depth_mm, pitch)
        full = calib.render_lookup(frame.depth_mm, pitch)
        assert np.abs(fast.astype(int) - full).max() <= 1
        assert np.mean(fast != full) < 0.01
        assert (fast != calib.background((240, 320))).any()


def bin_coded_calibration():  # type: ignore[no-untyped-def]
    """125 bins whose colour change is their own index: R = slope-angle bin, G = direction bin - 62, B = both
    summed, on a flat grey f0, so an image reads back every pixel's bin exactly."""
    from univtac_data.generators.tactile import TaximCalibration

    bins = 125
    i_mag, i_dir = np.meshgrid(np.arange(bins), np.arange(bins), indexing="ij")
    poly = np.zeros((3, bins, bins, 6))
    poly[0, ..., 5], poly[1, ..., 5], poly[2, ..., 5] = i_mag, i_dir, i_mag + i_dir
    return TaximCalibration(poly=poly, f0=np.full((480, 640, 3), 100.0), pixmm=0.0295)


def test_fitted_angles_are_within_their_bound() -> None:
    """The branch-free arctangents of the fast path, on gradients of every direction and of slopes from
    0.01 to 100 (0.6 to 89.4 deg), against numpy's."""
    from univtac_data.generators.tactile.optics_calibrated import ATAN_FIT_ERROR_RAD, BIN_EDGE_RAD, fitted_angles

    rng = np.random.default_rng(0)
    slope = 10.0 ** rng.uniform(-2.0, 2.0, 200_000)
    direction = rng.uniform(-np.pi, np.pi, slope.size)
    g_row, g_col = slope * np.sin(direction), slope * np.cos(direction)
    g_row[:4], g_col[:4] = (1.0, -1.0, 0.0, 0.0), (0.0, 0.0, 1.0, -1.0)  # the axes
    angle, direction_fit = np.empty_like(slope), np.empty_like(slope)
    fitted_angles(g_row, g_col, angle, direction_fit)
    assert np.abs(angle - np.arctan(np.hypot(g_row, g_col))).max() <= ATAN_FIT_ERROR_RAD
    assert np.abs(direction_fit - np.arctan2(g_row, g_col)).max() <= ATAN_FIT_ERROR_RAD
    assert ATAN_FIT_ERROR_RAD < 0.1 * BIN_EDGE_RAD


@pytest.mark.parametrize("method", ["geometric", "elastic"])
def test_calibrated_fast_path_picks_the_full_lookups_bin_for_every_pixel(method: str) -> None:
    """With a calibration that paints each bin's index, the fast path (fitted angles, exact near bin edges)
    and the full lookup agree on every pixel: contacts whose slopes take every direction, a long cylinder that
    slopes the whole image, a steep dome, and slopes along the image's edges."""
    calib = bin_coded_calibration()
    pitch = (MINI.mm_per_px_x, MINI.mm_per_px_y)
    y, x = np.meshgrid((np.arange(240) - 119.5) * MINI.mm_per_px_y, (np.arange(320) - 159.5) * MINI.mm_per_px_x,
                       indexing="ij")
    across = -0.5 * x + np.sqrt(0.75) * y
    cylinder = np.where(np.abs(across) < 3.0, 3.0 - np.sqrt(np.maximum(9.0 - across**2, 0.0)), 50.0) - 0.8
    punch = np.where(np.hypot(x - 5.0, y + 3.0) < 2.0, -0.3, 50.0)
    depths = [simulate_frame(MINI, gap, method=method, config=TactileConfig()).depth_mm  # type: ignore[arg-type]
              for gap in (np.minimum(sphere_gap(MINI, 3.0, 0.8, (-6.0, 3.0)), punch), cylinder)]
    edges = np.zeros((240, 320))  # deformed along the image's top and left edges only: rows 120 on are skipped
    edges[:120, :40] += np.linspace(0.3, 0.0, 40)[None, :] * (1.0 + 0.5 * np.sin(np.arange(120) / 9.0))[:, None]
    edges[:30, :] += np.linspace(0.2, 0.0, 30)[:, None]
    depths.append(edges)
    depths.append(np.maximum(1.5 - 2.0 * (x * x + y * y), 0.0))  # a steep dome: slopes up to 74 deg
    images = [calib.render(depth, pitch) for depth in depths]
    for depth, fast in zip(depths, images):
        np.testing.assert_array_equal(fast, calib.render_lookup(depth, pitch))
    assert min(len(np.unique(fast[..., 1])) for fast in images[:2]) > 50  # many direction bins
    assert (images[2][120:] == 100).all()  # the undeformed rows keep f0
    dome = images[-1][..., 0]
    assert dome.max() >= 100 + 80 and len(np.unique(dome)) > 30  # slope-angle bins past 58 deg


def synthetic_calibration():  # type: ignore[no-untyped-def]
    """A 125-bin calibration with smooth, position-dependent polynomials (no real data needed)."""
    from univtac_data.generators.tactile import TaximCalibration

    rng = np.random.default_rng(4)
    bins = 125
    i_mag, i_dir = np.meshgrid(np.arange(bins), np.arange(bins), indexing="ij")
    poly = np.zeros((3, bins, bins, 6))
    for c in range(3):
        poly[c, ..., 5] = 30 * np.sin(i_dir * 2 * np.pi / bins + c) * i_mag / bins + rng.normal(0, 2, (bins, bins))
        poly[c, ..., 3] = 0.02 * np.cos(i_dir * 2 * np.pi / bins) * i_mag / bins
        poly[c, ..., 0] = 1e-4 * rng.normal(0, 1, (bins, bins))
    f0 = np.tile(np.linspace(60, 180, 640)[None, :, None], (480, 1, 3))
    return TaximCalibration(poly=poly, f0=f0, pixmm=0.0295)


def test_shaded_flat_gel_is_the_vignetted_background() -> None:
    img = render_shaded(np.zeros((240, 320)), MINI)
    bg = background_image(MINI)
    np.testing.assert_array_equal(img, np.clip(np.rint(bg), 0, 255).astype(np.uint8))
    assert img[120, 160].astype(int).sum() > img[0, 0].astype(int).sum()  # vignetting darkens corners


def test_shaded_slopes_take_the_light_colours() -> None:
    depth = np.maximum(-sphere_gap(MINI, 4.0, 0.8), 0.0)
    img = render_shaded(depth, MINI).astype(int)
    bg = np.clip(np.rint(background_image(MINI)), 0, 255).astype(int)
    # the red light sits at azimuth 90 deg (+y, down the image): the slope facing it is the lower rim
    lower, upper = img[120 + 20, 160] - bg[120 + 20, 160], img[120 - 20, 160] - bg[120 - 20, 160]
    assert lower[0] > 20 and lower[0] > upper[0]


def lambert_reference(depth: np.ndarray, profile) -> np.ndarray:  # type: ignore[no-untyped-def]
    """The module docstring's formula in float64 array code, over the whole image: the oracle for the compiled
    renderer (which shades only the deformed window, in float32)."""
    gy, gx = np.gradient(depth, profile.mm_per_px_y, profile.mm_per_px_x)
    norm = np.sqrt(1.0 + gx * gx + gy * gy)
    normal = np.stack([-gx, -gy, -np.ones_like(gx)], axis=-1) / norm[..., None]
    image = background_image(profile).copy()
    for light in profile.optics.lights:
        az, el = np.deg2rad(light.azimuth_deg), np.deg2rad(light.elevation_deg)
        direction = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), -np.sin(el)])
        change = np.maximum(normal @ direction, 0.0) - np.sin(el)
        image += 255.0 * 1.3 * change[..., None] * np.asarray(light.rgb, dtype=np.float64)
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("sensor", ["gelsight_mini", "gf225", "xense_ws"])
def test_compiled_shading_matches_the_lambert_formula(sensor: str) -> None:
    profile = get_sensor(sensor)
    h, w = profile.image_height_px, profile.image_width_px
    y, x = np.mgrid[:h, :w]
    r = np.hypot((x - w / 2) * profile.mm_per_px_x, (y - h / 2) * profile.mm_per_px_y)
    sink_in = 4.0 / (np.pi * np.maximum(r, 2.0))          # elastic: deformed everywhere
    sphere = np.maximum(0.8 - r**2 / 10.0, 0.0)           # geometric: a window; its rim is where slopes jump
    for depth in (sink_in, sphere):
        got, want = render_shaded(depth, profile).astype(int), lambert_reference(depth, profile).astype(int)
        assert np.abs(got - want).max() <= 1                      # float32 against float64
        assert np.count_nonzero(got != want) <= 1e-3 * got.size
    corner = np.zeros((h, w))
    corner[: 3, w - 2 :] = 0.05                                     # a window cut by two image borders
    assert np.abs(render_shaded(corner, profile).astype(int) - lambert_reference(corner, profile)).max() <= 1


def draw_markers_reference(image: np.ndarray, centres: np.ndarray, radius: float, rgb: tuple[int, int, int]) -> np.ndarray:
    """markers.py's rule pixel by pixel: float32 coverage clip(radius + 0.5 - distance, 0, 1), the largest over the
    markers, then rint(under + (marker - under) * coverage)."""
    h, w, _ = image.shape
    coverage = np.zeros((h, w), np.float32)
    half = int(np.ceil(radius + 1.5))
    for cu, cv in centres:
        for row in range(int(np.floor(cv)) - half, int(np.floor(cv)) + half + 1):
            for col in range(int(np.floor(cu)) - half, int(np.floor(cu)) + half + 1):
                if 0 <= row < h and 0 <= col < w:
                    du, dv = np.float32(col - cu), np.float32(row - cv)
                    alpha = np.clip(np.float32(radius + 0.5) - np.sqrt(du * du + dv * dv), 0.0, 1.0)
                    coverage[row, col] = max(coverage[row, col], alpha)
    under = image.astype(np.float32)
    blended = under + (np.asarray(rgb, np.float32) - under) * coverage[..., None]
    return np.where(coverage[..., None] > 0, np.rint(blended), image).astype(np.uint8)


def test_compiled_marker_drawing_matches_the_rule_bit_for_bit() -> None:
    from univtac_data.generators.tactile.markers import draw_markers

    rng = np.random.default_rng(4)
    for trial in range(6):
        image = rng.integers(0, 256, (60, 80, 3), dtype=np.uint8)
        centres = np.column_stack([rng.uniform(-8, 88, 12), rng.uniform(-8, 68, 12)])
        centres[6:] = centres[:6] + rng.normal(0, 2.0, (6, 2))           # overlapping pairs
        radius = [2.0, 3.3, 6.0][trial % 3]
        got = draw_markers(image, centres, radius, (20, 30, 40))
        np.testing.assert_array_equal(got, draw_markers_reference(image, centres, radius, (20, 30, 40)))
        assert not np.shares_memory(got, image)


def test_markers_apart_are_drawn_by_the_rule_bit_for_bit() -> None:
    """Markers no pixel sees twice (the usual gel) take the path without a coverage buffer: same pixels."""
    from univtac_data.generators.tactile.markers import _discs_apart, draw_markers

    rng = np.random.default_rng(5)
    for radius in (2.0, 3.3, 6.0):
        image = rng.integers(0, 256, (90, 120, 3), dtype=np.uint8)
        grid = np.stack(np.meshgrid(np.arange(-5.0, 130.0, 2 * radius + 4.0), np.arange(-5.0, 100.0, 2 * radius + 4.0)),
                        axis=-1).reshape(-1, 2)
        centres = grid + rng.uniform(-1.0, 1.0, grid.shape)   # some off the image edges
        assert _discs_apart(centres, np.float32(radius + 0.5))
        got = draw_markers(image, centres, radius, (20, 30, 40))
        np.testing.assert_array_equal(got, draw_markers_reference(image, centres, radius, (20, 30, 40)))
        touching = centres.copy()
        touching[1] = touching[0] + (2 * radius + 0.5, 0.0)   # within reach of each other: the other path
        assert not _discs_apart(touching, np.float32(radius + 0.5))
        np.testing.assert_array_equal(draw_markers(image, touching, radius, (20, 30, 40)),
                                      draw_markers_reference(image, touching, radius, (20, 30, 40)))
