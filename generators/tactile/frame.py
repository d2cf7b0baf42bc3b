"""The public entry point: one pad, one frame, from a gap field to everything the format stores.

``simulate_frame(profile, gap_mm, ...)`` runs gap -> contact solve -> shear and markers -> optics and returns
a :class:`TactileFrame` whose arrays fill the format's per-pad fields exactly (dtypes, native H x W).
Stick/slip history travels in ``frame.state`` (a :class:`ContactState`), passed to the next call.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Literal

import numba
import numpy as np

from univtac_data.schema.sensors import SensorProfile

from .contact import GAP_FAR_MM, ContactConfig, ContactMethod, solve_contact
from .markers import draw_markers, sample_bilinear
from .noise import noisy_image
from .optics import ShadingConfig, render_shaded
from .optics_calibrated import TaximCalibration
from .sensor_model import (
    downsample_mean, downsample_overlap_or_mean, marker_reference_mm, project_to_px, sensor_grid, upsample_linear,
)
from .shear import ContactState, solve_shear

__all__ = ["PixelBuffers", "TactileConfig", "TactileFrame", "render_reference", "simulate_frame"]

CONTACT_TOL_MM = 1e-3
"""A pixel is in contact when the gel surface is within this distance of the object (1 um, the depth_um
quantum)."""


@dataclass(frozen=True)
class TactileConfig:
    """Everything about the simulation that is not sensor data or per-frame input."""

    contact: ContactConfig = field(default_factory=ContactConfig)
    shading: ShadingConfig = field(default_factory=ShadingConfig)
    shear_step: int = 4  # image pixels per cell of the tangential solve and in-plane displacement field
    perspective_markers: bool = True  # project markers at their pressed height z = -D (pinhole parallax)
    calibration: TaximCalibration | None = None  # Taxim-format calibrated optics instead of the shaded model
    optics: Literal["shaded", "calibrated"] = "shaded"


@dataclass(frozen=True, eq=False)
class TactileFrame:
    """One pad, one frame. Image-grid arrays are (H, W) at the sensor's native resolution, gel-pad frame.

    ``depth_mm``: (H, W) float64 indentation toward the camera, mm, >= 0. ``depth_um``: (H, W) uint16, the
    same in integer micrometres. ``pressure_mpa``: (H, W) float64 normal pressure, MPa. ``contact_mask``:
    (H, W) bool. ``normal_force_n``: float32 N. ``shear_force_n``: (2,) float32 N along pad x, y (force of the
    object on the gel). ``markers_ref_px``/``markers_px``: (N, 2) float32 (u = column, v = row) px.
    ``slip_mm``: float32, sliding since contact onset (0 while stuck). ``pure_rgb``/``marked_rgb``:
    (H, W, 3) uint8. ``state``: pass to the next frame's call. ``converged``/``iterations``: elastic solver.
    """

    depth_mm: np.ndarray
    depth_um: np.ndarray
    pressure_mpa: np.ndarray
    contact_mask: np.ndarray
    normal_force_n: np.float32
    shear_force_n: np.ndarray
    markers_ref_px: np.ndarray
    markers_px: np.ndarray
    slip_mm: np.float32
    pure_rgb: np.ndarray
    marked_rgb: np.ndarray
    state: ContactState
    converged: bool = True
    iterations: int = 0


@dataclass(frozen=True)
class PixelBuffers:
    """Arrays ``simulate_frame`` writes a frame's recorded per-pixel fields into, e.g. the rows of the
    episode's arrays (``FrameStack.next_row``), which saves a copy of each: ``marked_rgb`` and ``pure_rgb``
    (H, W, 3) uint8 (``marked_rgb`` C-contiguous), ``depth_um`` (H, W) uint16, ``contact_mask`` (H, W) bool."""

    marked_rgb: np.ndarray
    pure_rgb: np.ndarray
    depth_um: np.ndarray
    contact_mask: np.ndarray

    @staticmethod
    def layout(h: int, w: int) -> dict[str, tuple[tuple[int, ...], type]]:
        """(shape, dtype) of each buffer for an (h, w) sensor, by field name."""
        return {"marked_rgb": ((h, w, 3), np.uint8), "pure_rgb": ((h, w, 3), np.uint8),
                "depth_um": ((h, w), np.uint16), "contact_mask": ((h, w), np.bool_)}

    def check(self, h: int, w: int) -> None:
        """Raise ValueError unless every buffer has the shape and dtype of its field for an (h, w) sensor."""
        for name, (shape, dtype) in self.layout(h, w).items():
            array = getattr(self, name)
            if array.shape != shape or array.dtype != dtype:
                raise ValueError(f"PixelBuffers.{name} must be {shape} {np.dtype(dtype)} "
                                 f"(got {array.shape} {array.dtype})")


def _upsample_pressure(pressure: np.ndarray, step: int, fine_mask: np.ndarray) -> np.ndarray:
    """Solver-grid pressure (ny, nx) -> image grid (H, W), MPa.

    Near a contact edge the pressure goes like sqrt(distance), so p^2 is close to linear there: p^2 is
    extended one cell past the edge by linear extrapolation from the two inner neighbours (negative
    outside), interpolated bilinearly, clipped at 0 and rooted, and kept only on the image-grid contact mask.
    Interpolating p itself would halve the pressure in the last half cell of the contact.
    """
    if step == 1:
        return np.where(fine_mask, pressure, 0.0)
    q = pressure * pressure
    # only cells next to the load change: extrapolate on its box grown by two cells, whose zero border keeps the
    # rolls below from wrapping anything in (the same result as on the whole grid, where they wrap at its edges)
    box = _nonzero_box(pressure)
    if box is not None:
        grown = (slice(box[0].start - 2, box[0].stop + 2), slice(box[1].start - 2, box[1].stop + 2))
        if grown[0].start >= 0 and grown[1].start >= 0 and grown[0].stop <= q.shape[0] and grown[1].stop <= q.shape[1]:
            q[grown] = _extrapolated_squares(q[grown], pressure[grown] > 0.0)
        else:
            q = _extrapolated_squares(q, pressure > 0.0)
    out = np.zeros(fine_mask.shape)
    win = _nonzero_box(fine_mask)   # pressure is zero off the contact: upsample only its box
    if win is not None:
        fine = upsample_linear(q, step, fine_mask.shape, window=win)
        out[win] = np.where(fine_mask[win], np.sqrt(np.maximum(fine, 0.0)), 0.0)
    return out


def _extrapolated_squares(q: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """``q`` = p^2 (ny, nx) with each cell outside the load (``inside`` false) that has two loaded cells in a
    row along an axis set to the mean of their linear extrapolations, at most 0 (the field wraps at its
    edges, as numpy's roll does)."""
    out = np.empty_like(q)
    _extrapolate_squares_kernel(np.ascontiguousarray(q, dtype=np.float64), np.ascontiguousarray(inside), out)
    return out


@numba.njit(cache=True, nogil=True)
def _extrapolate_squares_kernel(q: np.ndarray, inside: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover
    # one pass, where array code made sixteen rolled copies of the box (1.5 ms of an elastic frame on a cylinder
    # across the pad); the directions are summed in the order the array code summed them (rows down, rows up,
    # columns right, columns left), so the result is the same to the bit
    ny, nx = q.shape
    for i in range(ny):
        for j in range(nx):
            if inside[i, j]:
                out[i, j] = q[i, j]
                continue
            total, count = 0.0, 0.0
            for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1)):
                i1, j1 = (i - di) % ny, (j - dj) % nx
                i2, j2 = (i - 2 * di) % ny, (j - 2 * dj) % nx
                if inside[i1, j1] and inside[i2, j2]:
                    total += 2.0 * q[i1, j1] - q[i2, j2]
                    count += 1.0
            # an unloaded cell is open at its centre, so the edge lies before it: its extrapolation is kept <= 0
            # (a positive one, from a pressure still rising at the edge, would carry the contact on to the next
            # cell)
            out[i, j] = min(total / count, 0.0) if count > 0.0 else q[i, j]


def _to_micrometres(depth_mm: np.ndarray, box: tuple[slice, slice] | None = None,
                    out: np.ndarray | None = None) -> np.ndarray:
    """(H, W) mm >= 0 -> uint16 um, rounded, saturating at 65535, into ``out`` (H, W) uint16 if given.
    ``box``: (rows, cols) outside which the depth is zero, if known."""
    if out is None:
        out = np.zeros(depth_mm.shape, np.uint16)
        fresh = True
    else:
        fresh = False
    # zero depth is 0 um: only the deformed box is converted, and only the rest of a given buffer zeroed
    win = _nonzero_box(depth_mm) if box is None else box
    if win is None:
        if not fresh:
            out[...] = 0
        return out
    (r0, r1), (c0, c1) = win[0].indices(depth_mm.shape[0])[:2], win[1].indices(depth_mm.shape[1])[:2]
    if not fresh:
        out[:r0], out[r1:], out[r0:r1, :c0], out[r0:r1, c1:] = 0, 0, 0, 0
    _micrometres_kernel(depth_mm, r0, r1, c0, c1, out)
    return out


@numba.njit(cache=True, nogil=True)
def _micrometres_kernel(depth_mm: np.ndarray, r0: int, r1: int, c0: int, c1: int,
                        out: np.ndarray) -> None:  # pragma: no cover (compiled)
    # one pass over the box, where array code makes four (and a float64 temporary); row slices, so that the
    # loop vectorises (element-wise 2-D indexing does not)
    for i in range(r0, r1):
        depth_row, out_row = depth_mm[i, c0:c1], out[i, c0:c1]
        for j in range(c1 - c0):
            out_row[j] = np.uint16(min(depth_row[j] * 1000.0 + 0.5, 65535.0))


def _aligned(box: tuple[slice, slice], align: int, h: int, w: int) -> tuple[slice, slice] | None:
    """``box`` widened outward to multiples of ``align`` (clipped at h and w); None when it is empty."""
    (r0, r1), (c0, c1) = (box[0].indices(h)[:2]), (box[1].indices(w)[:2])
    if r1 <= r0 or c1 <= c0:
        return None
    return (slice(r0 // align * align, min(-(-r1 // align) * align, h)),
            slice(c0 // align * align, min(-(-c1 // align) * align, w)))


def _nonzero_box(field: np.ndarray, align: int = 1) -> tuple[slice, slice] | None:
    """Bounding box (rows, cols) of the nonzero entries of ``field`` (H, W), widened outward to multiples of
    ``align`` (clipped at H and W); None when all are zero."""
    nonzero = field != 0
    rows = np.flatnonzero(nonzero.any(axis=1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero(nonzero[rows[0] : rows[-1] + 1].any(axis=0))
    return _aligned((slice(int(rows[0]), int(rows[-1]) + 1), slice(int(cols[0]), int(cols[-1]) + 1)), align,
                    *field.shape)


def _block_mean_of_load(pressure: np.ndarray, factor: int, box: tuple[slice, slice] | None = None) -> np.ndarray:
    """``downsample_mean(pressure, factor, "constant")``, bit for bit, summing only the blocks under the load.
    ``box``: (rows, cols) outside which the pressure is zero, if known."""
    if factor == 1:
        return pressure
    h, w = pressure.shape
    out = np.zeros((-(-h // factor), -(-w // factor)))
    win = _nonzero_box(pressure, factor) if box is None else _aligned(box, factor, h, w)
    if win is not None:
        coarse = (slice(win[0].start // factor, -(-win[0].stop // factor)),
                  slice(win[1].start // factor, -(-win[1].stop // factor)))
        out[coarse] = downsample_mean(pressure[win], factor, "constant")
    return out


def render_reference(profile: SensorProfile, config: TactileConfig = TactileConfig()) -> np.ndarray:
    """I_pure (H, W, 3) uint8 of the undeformed gel (no contact, no noise) with the optics ``simulate_frame``
    uses: the episode's ``pure_ref_rgb``, the sensor's background frame."""
    flat = np.zeros((profile.image_height_px, profile.image_width_px))
    if config.optics == "calibrated":
        if config.calibration is None:
            raise ValueError("optics='calibrated' needs TactileConfig.calibration (load_taxim_calibration(folder))")
        return config.calibration.render(flat, (profile.mm_per_px_x, profile.mm_per_px_y))
    return render_shaded(flat, profile, config.shading)


def simulate_frame(
    profile: SensorProfile,
    gap_mm: np.ndarray,
    *,
    method: ContactMethod | None = None,
    tangential_mm: tuple[float, float] = (0.0, 0.0),
    twist_rad: float = 0.0,
    state: ContactState | None = None,
    noise_seed: int | None = None,
    config: TactileConfig | None = None,
    out: PixelBuffers | None = None,
    gap_box: tuple[slice, slice] | None = None,
) -> TactileFrame:
    """Simulate one pad for one frame.

    ``gap_mm``: (H, W) signed distance along the pad normal from the undeformed gel to the object, mm,
    negative = overlap; +inf or any value >= ``GAP_FAR_MM`` means no object. ``method``: "geometric" or
    "elastic" (default: ``config.contact.method``). ``tangential_mm``: object displacement (x, y) in the pad
    frame, mm; ``twist_rad``: its rotation about the pad normal, rad; both relative to contact onset when
    ``state`` is None, else absolute (the state remembers the onset). ``noise_seed``: seeded sensor noise.
    ``out``: buffers the frame's images, ``depth_um`` and ``contact_mask`` are written into (the returned
    frame holds them); default: new arrays. ``gap_box``: (rows, cols) outside which ``gap_mm`` reads
    ``GAP_FAR_MM`` (no object), when the caller knows it (``GapFieldBuffer.box``): the checks and the
    geometric contact then read only that box.
    """
    config = config or TactileConfig()
    contact_cfg = config.contact
    if method is not None and method != contact_cfg.method:
        contact_cfg = ContactConfig(**{**contact_cfg.__dict__, "method": method})
    h, w = profile.image_height_px, profile.image_width_px
    gap = np.asarray(gap_mm, dtype=np.float64)
    if gap.shape != (h, w):
        raise ValueError(f"gap_mm must be (H, W) = ({h}, {w}) for sensor {profile.name!r} (got {gap.shape})")
    scanned = gap if gap_box is None else gap[gap_box]
    # one read: NaN propagates through the max, and most callers need no clamp
    top = float(scanned.max()) if scanned.size else GAP_FAR_MM
    if np.isnan(top):
        raise ValueError("gap_mm contains NaN")
    if top > GAP_FAR_MM:
        gap = np.minimum(gap, GAP_FAR_MM)
    if out is not None:
        out.check(h, w)
    material = profile.material

    step = contact_cfg.solver_step if contact_cfg.method == "elastic" else 1
    grid = sensor_grid(profile, step)
    previous = state.pressure_mpa if state is not None else None
    layer_mm = profile.gel_thickness_mm if contact_cfg.method == "elastic" and contact_cfg.gel == "layer" else None
    result = solve_contact(downsample_overlap_or_mean(gap, step), grid, material, contact_cfg, previous, layer_mm,
                           gap_box if step == 1 else None)
    box = result.box if step == 1 else None  # the solver's box, in image pixels
    if contact_cfg.method == "geometric":
        # on the image grid already: the depth holds the overlap and the pressure is zero off the mask
        depth, contact, pressure = result.depth_mm, result.contact_mask, result.pressure_mpa
    else:
        overlap = np.maximum(-gap, 0.0)
        surface = upsample_linear(result.depth_mm, step, (h, w))
        depth = np.maximum(surface, overlap)
        if step == 1:
            contact = result.contact_mask
            pressure = _upsample_pressure(result.pressure_mpa, step, contact)
        else:
            # the solver's mask is per solver cell. On the image grid, contact is where the gel meets the object
            # or the upsampled pressure is positive: p^2 is close to linear across the edge, so its zero crossing
            # places the edge within the cell, where the bilinear surface alone lost half a pixel of the rim
            # (an R = 3 mm sphere's radius 4 % short at step 2; within 1.5 % so)
            overlapped = overlap > 0.0
            pressure = _upsample_pressure(result.pressure_mpa, step, overlapped)
            contact = overlapped & ((pressure > 0.0) | (overlap >= surface - CONTACT_TOL_MM))
            np.copyto(depth, overlap, where=contact)  # in contact the gel meets the object

    shear_step = step * max(1, -(-config.shear_step // step))
    grid_sh = sensor_grid(profile, shear_step)
    factor = shear_step // step
    p_sh = _block_mean_of_load(result.pressure_mpa, factor, result.box)
    shear = solve_shear(
        p_sh, p_sh > 0.0, grid_sh.dx_mm, grid_sh.dy_mm, grid_sh.x_mm, grid_sh.y_mm, material,
        tangential_mm, twist_rad, state, thickness_mm=layer_mm,
    )

    ref_mm = marker_reference_mm(profile)
    ref_px = project_to_px(profile, ref_mm)
    if result.normal_force_n > 0.0:
        moved = ref_mm + sample_bilinear(shear.displacement_mm, grid_sh.x_mm, grid_sh.y_mm, ref_mm).T
        grid_img = sensor_grid(profile, 1)
        z = -sample_bilinear(depth, grid_img.x_mm, grid_img.y_mm, ref_mm) if config.perspective_markers else 0.0
        markers_px = project_to_px(profile, moved, z)
    else:
        markers_px = ref_px

    if config.optics == "calibrated":
        if config.calibration is None:
            raise ValueError("optics='calibrated' needs TactileConfig.calibration (load_taxim_calibration(folder))")
        pure = config.calibration.render(depth, (profile.mm_per_px_x, profile.mm_per_px_y))
        if noise_seed is not None:
            pure = noisy_image(pure.astype(np.float32), None, None, noise_seed, config.shading.noise_std,
                               np.empty_like(pure))
    else:
        pure = render_shaded(depth, profile, config.shading, noise_seed, deformed_box=box,
                             out=None if out is None else out.pure_rgb)
    marked = draw_markers(pure, markers_px, profile.marker_radius_px, profile.optics.marker_rgb,
                          out=None if out is None else out.marked_rgb)
    if out is not None:
        if config.optics == "calibrated":
            out.pure_rgb[...] = pure
            pure = out.pure_rgb
        out.contact_mask[...] = contact
        contact = out.contact_mask

    return TactileFrame(
        depth_mm=depth,
        depth_um=_to_micrometres(depth, box, None if out is None else out.depth_um),
        pressure_mpa=pressure,
        contact_mask=contact,
        normal_force_n=np.float32(result.normal_force_n),
        shear_force_n=shear.shear_force_n.astype(np.float32),
        markers_ref_px=ref_px.astype(np.float32),
        markers_px=np.asarray(markers_px, dtype=np.float32),
        slip_mm=np.float32(shear.slip_mm),
        pure_rgb=pure,
        marked_rgb=marked,
        state=replace(shear.state, pressure_mpa=result.pressure_mpa) if contact_cfg.method == "elastic"
        else shear.state,
        converged=result.converged,
        iterations=result.iterations,
    )
