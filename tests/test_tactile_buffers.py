"""Frames written in place: ``simulate_frame(out=PixelBuffers)`` and ``FrameStack`` rows, and the windows the
geometric contact hands on (its box), which must change nothing but where the work is done."""

from __future__ import annotations

import numpy as np
import pytest

from univtac_data.generators.scene.frame_stack import PIXEL_FIELDS, BufferPool, FrameStack
from univtac_data.generators.tactile import (
    ContactConfig, PixelBuffers, demo_gap, render_shaded, sensor_grid, simulate_frame, solve_contact,
)
from univtac_data.generators.tactile.frame import _to_micrometres
from univtac_data.generators.tactile.markers import draw_markers
from univtac_data.schema.sensors import get_sensor

GF225 = get_sensor("gf225")
MINI = get_sensor("gelsight_mini")


def garbage_buffers(h: int, w: int) -> PixelBuffers:
    """Buffers filled with a value no output has everywhere, so a pixel left unwritten shows."""
    return PixelBuffers(**{name: np.full(shape, 77 if dtype is not np.bool_ else True, dtype)
                           for name, (shape, dtype) in PixelBuffers.layout(h, w).items()})


@pytest.mark.parametrize("method", ["geometric", "elastic"])
@pytest.mark.parametrize("shape", ["sphere", "cross"])
@pytest.mark.parametrize("noise_seed", [None, 3])
def test_a_frame_written_into_buffers_equals_a_new_frame(method: str, shape: str, noise_seed: int | None) -> None:
    gap = demo_gap(MINI, shape)
    kwargs = dict(method=method, tangential_mm=(0.08, -0.03), twist_rad=0.01, noise_seed=noise_seed)
    fresh = simulate_frame(MINI, gap, **kwargs)  # type: ignore[arg-type]
    buffers = garbage_buffers(MINI.image_height_px, MINI.image_width_px)
    written = simulate_frame(MINI, gap, out=buffers, **kwargs)  # type: ignore[arg-type]
    assert fresh.contact_mask.any()
    for name in PIXEL_FIELDS:
        assert getattr(written, name) is getattr(buffers, name), name   # the frame holds the buffers
        np.testing.assert_array_equal(getattr(written, name), getattr(fresh, name), err_msg=name)
    np.testing.assert_array_equal(written.markers_px, fresh.markers_px)
    assert written.normal_force_n == fresh.normal_force_n


def test_a_contactless_frame_clears_its_buffers() -> None:
    gap = np.full((MINI.image_height_px, MINI.image_width_px), 5.0)
    buffers = garbage_buffers(MINI.image_height_px, MINI.image_width_px)
    frame = simulate_frame(MINI, gap, out=buffers)
    assert not frame.depth_um.any() and not frame.contact_mask.any()
    np.testing.assert_array_equal(frame.pure_rgb, simulate_frame(MINI, gap).pure_rgb)


@pytest.mark.parametrize("field, shape, dtype", [("depth_um", (240, 320), np.float32),
                                                 ("pure_rgb", (240, 320), np.uint8),
                                                 ("contact_mask", (320, 240), np.bool_)])
def test_buffers_of_the_wrong_shape_or_dtype_are_refused(field: str, shape: tuple[int, ...], dtype: type) -> None:
    layout = PixelBuffers.layout(240, 320)
    arrays = {name: np.zeros(s, d) for name, (s, d) in layout.items()}
    arrays[field] = np.zeros(shape, dtype)
    with pytest.raises(ValueError, match=f"PixelBuffers.{field} must be"):
        simulate_frame(MINI, demo_gap(MINI, "sphere"), out=PixelBuffers(**arrays))


def test_markers_are_never_drawn_onto_the_pure_image() -> None:
    pure = np.zeros((240, 320, 3), np.uint8)
    with pytest.raises(ValueError, match="share memory"):
        draw_markers(pure, np.array([[10.0, 10.0]]), 3.0, (0, 0, 0), out=pure)
    with pytest.raises(ValueError, match="C-contiguous"):
        draw_markers(pure, np.array([[10.0, 10.0]]), 3.0, (0, 0, 0), out=np.zeros((240, 320, 4), np.uint8)[..., :3])


def test_frame_stack_rows_filled_in_place_survive_growth() -> None:
    stack = FrameStack(capacity=2)
    for k in range(5):   # grows twice
        row = stack.next_row((3, 4), np.uint16)
        row[...] = k
        stack.commit()
    stack.append(np.full((3, 4), 9, np.uint16))
    frames = stack.array()
    assert frames.shape == (6, 3, 4)
    np.testing.assert_array_equal(frames[:, 0, 0], [0, 1, 2, 3, 4, 9])


def address(array: np.ndarray) -> int:
    return int(array.__array_interface__["data"][0])


def test_frame_buffers_are_reused_only_when_nothing_refers_to_them() -> None:
    """An episode's frames stay intact while anything holds them; once released, the next episode of the same
    shape records into the same memory (no fresh pages)."""
    shape = (3, 5, 7)   # a shape no other test records, so the shared pool holds nothing of it yet
    first = FrameStack(capacity=4)
    for k in range(4):
        first.append(np.full(shape, k, np.uint8))
    held = first.array()
    first_memory = address(held)
    del first
    second = FrameStack(capacity=4)
    for k in range(4):
        second.append(np.full(shape, 100 + k, np.uint8))
    assert address(second.array()) != first_memory   # ``held`` still refers to the first buffer
    np.testing.assert_array_equal(held[:, 0, 0, 0], [0, 1, 2, 3])
    del held
    third = FrameStack(capacity=4)
    third.append(np.zeros(shape, np.uint8))
    assert address(third.array()) == first_memory
    np.testing.assert_array_equal(second.array()[:, 0, 0, 0], [100, 101, 102, 103])


def test_buffer_pool_keeps_at_most_its_limits_and_clear_forgets() -> None:
    pool = BufferPool(max_per_shape=2, max_bytes=1000)
    first = [pool.take((10, 10), np.uint8) for _ in range(3)]   # the third is over max_per_shape: not kept
    kept = {address(a) for a in first[:2]}
    assert pool.kept_bytes == 200
    del first
    again = [pool.take((10, 10), np.uint8) for _ in range(3)]
    assert {address(a) for a in again[:2]} == kept   # the two kept buffers come back
    pool.take((40, 40), np.uint8)   # 1,600 bytes: over max_bytes even alone, not kept
    assert pool.kept_bytes == 200
    pool.take((20, 20), np.uint8)   # 400 bytes fit beside the two held (10, 10) buffers
    assert pool.kept_bytes == 600
    del again
    pool.take((30, 20), np.uint8)   # 600 bytes: the free (10, 10) buffers, asked for longest ago, make room
    assert pool.kept_bytes == 1000
    held = pool.take((30, 30), np.uint8)   # 900 bytes: every free buffer of another shape is let go
    assert pool.kept_bytes == 900
    assert address(pool.take((30, 30), np.uint8)) != address(held)   # held: a new buffer, not kept (limit)
    pool.clear()
    assert pool.kept_bytes == 0


def test_frame_stack_refuses_a_commit_without_a_row_and_a_frame_of_another_shape() -> None:
    stack = FrameStack(capacity=4)
    with pytest.raises(ValueError, match="commit without a row"):
        stack.commit()
    stack.next_row((2, 2), np.uint8)
    stack.commit()
    with pytest.raises(ValueError, match="commit without a row"):
        stack.commit()   # one commit per row
    with pytest.raises(ValueError, match="in a stack of"):
        stack.next_row((2, 3), np.uint8)
    with pytest.raises(ValueError, match="in a stack of"):
        stack.append(np.zeros((2, 2), np.uint16))
    assert stack.frames == 1


@pytest.mark.parametrize("shape", ["sphere", "cross", "two_spheres", "punch"])
def test_the_geometric_box_holds_the_whole_deformation(shape: str) -> None:
    """Outside the box the geometric contact reports, the depth and pressure are zero and nothing touches; the
    shading and the micrometres computed inside it alone equal those of the whole image."""
    grid = sensor_grid(GF225, 1)
    result = solve_contact(demo_gap(GF225, shape), grid, GF225.material, ContactConfig(method="geometric"))
    assert result.box is not None and result.contact_mask.any()
    outside = np.ones(grid.shape, bool)
    outside[result.box] = False
    assert not result.depth_mm[outside].any() and not result.pressure_mpa[outside].any()
    assert not result.contact_mask[outside].any()
    assert result.normal_force_n == pytest.approx(result.pressure_mpa.sum() * grid.cell_area_mm2, rel=1e-12)
    np.testing.assert_array_equal(render_shaded(result.depth_mm, GF225, deformed_box=result.box),
                                  render_shaded(result.depth_mm, GF225))
    np.testing.assert_array_equal(_to_micrometres(result.depth_mm, result.box), _to_micrometres(result.depth_mm))


@pytest.mark.parametrize("shape", ["sphere", "cross", "punch"])
def test_images_and_micrometres_written_into_a_used_buffer_equal_fresh_ones(shape: str) -> None:
    """A buffer that held another frame (here: noise) is overwritten everywhere: inside the deformed window by
    the shading and the conversion, outside it by the background and zeros; a strided image buffer too."""
    grid = sensor_grid(GF225, 1)
    result = solve_contact(demo_gap(GF225, shape), grid, GF225.material, ContactConfig(method="geometric"))
    flat = np.zeros(grid.shape)
    rng = np.random.default_rng(0)
    for depth, box in ((result.depth_mm, result.box), (flat, None)):
        used_rgb = rng.integers(0, 256, (*grid.shape, 3), dtype=np.uint8)
        used_um = rng.integers(0, 65536, grid.shape, dtype=np.uint16)
        np.testing.assert_array_equal(render_shaded(depth, GF225, deformed_box=box, out=used_rgb),
                                      render_shaded(depth, GF225))
        np.testing.assert_array_equal(_to_micrometres(depth, box, used_um), _to_micrometres(depth))
        strided = rng.integers(0, 256, (*grid.shape, 4), dtype=np.uint8)[..., :3]  # not C-contiguous
        np.testing.assert_array_equal(render_shaded(depth, GF225, deformed_box=box, out=strided),
                                      render_shaded(depth, GF225))


def test_no_geometric_contact_gives_an_empty_box() -> None:
    grid = sensor_grid(GF225, 1)
    result = solve_contact(np.full(grid.shape, 1.0), grid, GF225.material, ContactConfig(method="geometric"))
    assert result.box is not None and result.depth_mm[result.box].size == 0
    assert result.normal_force_n == 0.0 and not result.contact_mask.any()
    np.testing.assert_array_equal(render_shaded(result.depth_mm, GF225, deformed_box=result.box),
                                  render_shaded(result.depth_mm, GF225))


def far_outside(gap: np.ndarray, box: tuple[slice, slice]) -> np.ndarray:
    """``gap`` with every cell outside ``box`` set to GAP_FAR_MM, as the generator's gap field reads there."""
    from univtac_data.generators.tactile import GAP_FAR_MM

    out = np.full_like(gap, GAP_FAR_MM)
    out[box] = gap[box]
    return out


@pytest.mark.parametrize("method", ["geometric", "elastic"])
@pytest.mark.parametrize("shape", ["sphere", "cross"])
def test_a_frame_told_its_gap_box_equals_one_that_scans_the_field(method: str, shape: str) -> None:
    """``gap_box`` only says where to look: the same frame, array for array, including a box that holds no
    overlap and an empty box (no object)."""
    gap = demo_gap(MINI, shape)
    rows, cols = np.nonzero(gap < 0.0)
    around = (slice(rows.min() - 9, rows.max() + 7), slice(cols.min() - 5, cols.max() + 11))
    aside = (slice(0, 20), slice(0, 30))
    empty = (slice(0, 0), slice(0, 0))
    for box in (around, aside, empty):
        field = far_outside(gap, box)
        kwargs = dict(method=method, tangential_mm=(0.08, -0.03), twist_rad=0.01)
        scanned = simulate_frame(MINI, field, **kwargs)  # type: ignore[arg-type]
        told = simulate_frame(MINI, field, gap_box=box, **kwargs)  # type: ignore[arg-type]
        assert scanned.contact_mask.any() == (box == around)
        for name in ("depth_mm", "depth_um", "pressure_mpa", "contact_mask", "pure_rgb", "marked_rgb",
                     "markers_px", "shear_force_n"):
            np.testing.assert_array_equal(getattr(told, name), getattr(scanned, name), err_msg=f"{box}: {name}")
        assert told.normal_force_n == scanned.normal_force_n


def test_nan_inside_the_gap_box_is_refused() -> None:
    gap = demo_gap(MINI, "sphere")
    gap[100, 150] = np.nan
    with pytest.raises(ValueError, match="gap_mm contains NaN"):
        simulate_frame(MINI, gap, gap_box=(slice(90, 110), slice(140, 160)))


def test_buffer_pool_keeps_nothing_without_exact_reference_counts(monkeypatch: pytest.MonkeyPatch) -> None:
    """On a free-threaded Python a free buffer cannot be told from a held one: the pool hands out new ones."""
    from univtac_data.generators.scene import frame_stack

    monkeypatch.setattr(frame_stack, "_EXACT_REFCOUNTS", False)
    pool = BufferPool()
    pool.take((8, 8), np.uint8)
    assert pool.kept_bytes == 0
