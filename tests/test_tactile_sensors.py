"""One contract suite run against every sensor profile: shapes, dtypes, determinism, no-contact frames."""

from __future__ import annotations

import numpy as np
import pytest

from univtac_data.generators.tactile import GAP_FAR_MM, TactileFrame, demo_gap, simulate_frame
from univtac_data.generators.tactile.optics import background_image
from univtac_data.schema.sensors import SENSOR_VARIANTS, SENSORS, SensorProfile, get_sensor

PROFILES = list(SENSORS.values()) + list(SENSOR_VARIANTS.values())


def far_from_markers(profile: SensorProfile, markers: np.ndarray) -> np.ndarray:
    rows, cols = np.mgrid[0 : profile.image_height_px, 0 : profile.image_width_px]
    near = np.zeros(rows.shape, dtype=bool)
    for u, v in markers:
        near |= np.hypot(cols - u, rows - v) <= profile.marker_radius_px + 1.5
    return ~near


@pytest.fixture(params=PROFILES, ids=[p.name for p in PROFILES])
def profile(request: pytest.FixtureRequest) -> SensorProfile:
    return request.param  # type: ignore[no-any-return]


@pytest.mark.parametrize("method", ["geometric", "elastic"])
def test_frame_fills_the_format(profile: SensorProfile, method: str) -> None:
    frame = simulate_frame(profile, demo_gap(profile, "sphere"), method=method,  # type: ignore[arg-type]
                           tangential_mm=(0.1, -0.05), twist_rad=0.01, noise_seed=1)
    h, w, n = profile.image_height_px, profile.image_width_px, profile.n_markers
    expected = {
        "marked_rgb": ((h, w, 3), np.uint8), "pure_rgb": ((h, w, 3), np.uint8), "depth_um": ((h, w), np.uint16),
        # depth_mm and pressure_mpa are the solver's float64 fields (the format stores depth_um)
        "depth_mm": ((h, w), np.float64), "pressure_mpa": ((h, w), np.float64), "contact_mask": ((h, w), np.bool_),
        "markers_ref_px": ((n, 2), np.float32), "markers_px": ((n, 2), np.float32),
        "shear_force_n": ((2,), np.float32),
    }
    for name, (shape, dtype) in expected.items():
        value = getattr(frame, name)
        assert value.shape == shape, name
        assert value.dtype == dtype, name
    for name in ("normal_force_n", "slip_mm"):
        assert isinstance(getattr(frame, name), np.float32)
    assert frame.normal_force_n > 0.0 and frame.contact_mask.any()
    assert frame.depth_um.max() == pytest.approx(frame.depth_mm.max() * 1000.0, abs=1.0)
    assert np.all(frame.depth_mm >= 0.0)


def test_marked_equals_pure_away_from_markers(profile: SensorProfile) -> None:
    frame = simulate_frame(profile, demo_gap(profile, "cross"), tangential_mm=(0.15, 0.0), noise_seed=3)
    away = far_from_markers(profile, frame.markers_px)
    assert np.array_equal(frame.marked_rgb[away], frame.pure_rgb[away])
    near = ~away
    assert not np.array_equal(frame.marked_rgb[near], frame.pure_rgb[near])
    inside = np.rint(frame.markers_px).astype(int)
    ok = (inside[:, 0] >= 0) & (inside[:, 0] < profile.image_width_px) & (inside[:, 1] >= 0) & (
        inside[:, 1] < profile.image_height_px)
    dots = frame.marked_rgb[inside[ok, 1], inside[ok, 0]].astype(int)
    assert np.all(np.abs(dots - np.asarray(profile.optics.marker_rgb)) <= 2)


def test_no_contact(profile: SensorProfile) -> None:
    h, w = profile.image_height_px, profile.image_width_px
    for gap in (np.full((h, w), GAP_FAR_MM), np.full((h, w), np.inf), np.full((h, w), 0.2)):
        frame: TactileFrame = simulate_frame(profile, gap, tangential_mm=(0.3, 0.2))
        assert not frame.depth_mm.any() and not frame.depth_um.any() and not frame.contact_mask.any()
        assert frame.normal_force_n == 0.0 and not frame.shear_force_n.any() and frame.slip_mm == 0.0
        assert np.array_equal(frame.markers_px, frame.markers_ref_px)
        expected_bg = np.clip(np.rint(background_image(profile)), 0, 255).astype(np.uint8)
        assert np.array_equal(frame.pure_rgb, expected_bg)
        away = far_from_markers(profile, frame.markers_px)
        assert np.array_equal(frame.marked_rgb[away], frame.pure_rgb[away])


def test_reference_markers_follow_the_pinhole_model(profile: SensorProfile) -> None:
    frame = simulate_frame(profile, np.full((profile.image_height_px, profile.image_width_px), GAP_FAR_MM))
    ref = frame.markers_ref_px
    assert ref.shape == (profile.n_markers, 2)
    pitch_u = ref[1, 0] - ref[0, 0]
    assert pitch_u == pytest.approx(profile.fx_px * profile.marker_pitch_x_mm / profile.camera_to_surface_mm, rel=1e-5)
    assert ref[:, 0].mean() == pytest.approx(profile.cx_px, abs=1e-3)
    assert ref[:, 1].mean() == pytest.approx(profile.cy_px, abs=1e-3)


@pytest.mark.parametrize("method", ["geometric", "elastic"])
def test_determinism(profile: SensorProfile, method: str) -> None:
    gap = demo_gap(profile, "two_spheres")
    a = simulate_frame(profile, gap, method=method, noise_seed=7, tangential_mm=(0.05, 0.0))  # type: ignore[arg-type]
    b = simulate_frame(profile, gap, method=method, noise_seed=7, tangential_mm=(0.05, 0.0))  # type: ignore[arg-type]
    c = simulate_frame(profile, gap, method=method, noise_seed=8, tangential_mm=(0.05, 0.0))  # type: ignore[arg-type]
    for name in ("marked_rgb", "pure_rgb", "depth_um", "depth_mm", "markers_px", "contact_mask", "pressure_mpa"):
        assert getattr(a, name).tobytes() == getattr(b, name).tobytes(), name
    assert a.marked_rgb.tobytes() != c.marked_rgb.tobytes()


def test_bad_gap_shape_is_rejected(profile: SensorProfile) -> None:
    with pytest.raises(ValueError, match="gap_mm must be"):
        simulate_frame(profile, np.zeros((10, 10)))


def test_calibrated_field_variant_images_the_calibration_field() -> None:
    """``gelsight_mini_calibrated_field``: Taxim's real-Mini calibration field (640 x 480 at 0.0295 mm/px) at
    320 x 240, square pixels, every marker inside the image; a named variant, not one of the format's sensors."""
    variant = get_sensor("gelsight_mini_calibrated_field")
    mini = get_sensor("gelsight_mini")
    assert variant.name not in SENSORS
    assert variant.imaged_width_mm == pytest.approx(640 * 0.0295, abs=0.005)
    assert variant.imaged_height_mm == pytest.approx(480 * 0.0295, abs=0.005)
    assert variant.mm_per_px_x == pytest.approx(variant.mm_per_px_y, rel=1e-3)
    assert (variant.image_width_px, variant.image_height_px) == (mini.image_width_px, mini.image_height_px)
    # the same physical marker dots, at the finer pitch
    assert variant.marker_radius_px * variant.mm_per_px_x == pytest.approx(mini.marker_radius_px * mini.mm_per_px_x,
                                                                          rel=0.01)
    frame = simulate_frame(variant, demo_gap(variant, "sphere"))
    ref = frame.markers_ref_px
    assert ((ref[:, 0] > variant.marker_radius_px) & (ref[:, 0] < variant.image_width_px - variant.marker_radius_px)).all()
    assert ((ref[:, 1] > variant.marker_radius_px) & (ref[:, 1] < variant.image_height_px - variant.marker_radius_px)).all()
    with pytest.raises(KeyError, match="gelsight_mini_calibrated_field"):
        get_sensor("no_such_sensor")
