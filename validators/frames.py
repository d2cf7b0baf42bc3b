"""Streaming the image and depth arrays in frame blocks and reducing them to per-frame summaries.

Summaries (each a float64 array of length T, NaN at frames that could not be read):

* ``{pad}/depth_max_um``: deepest indentation of the frame, um;
* ``{pad}/contact_px``: number of contact pixels;
* ``{pad}/marked_pure_diff_levels``: largest |I_marked - I_pure| over the pixels away from every current
  marker (farther than marker_radius_px + marker_clearance_px), uint8 levels;
* ``{pad}/marked_pure_diff_px``: how many of those pixels differ by more than the tolerance;
* ``{pad}/reference_diff_levels``: at frames with no indentation, mean |I_pure - pure_ref_rgb| over the
  image, uint8 levels (NaN at indented frames and when the episode holds no ``pure_ref_rgb``);
* ``camera/{name}/depth_nonfinite_px``: non-finite pixels of a scene camera's depth;
* ``camera/{name}/rgb_std_levels``: spread (standard deviation) of a scene camera frame's pixel values, on
  every 4th pixel of every 4th row, uint8 levels (a blank frame reads about 0).

A block that fails to decode is retried frame by frame, so a damaged chunk is reported with its frames.
"""

from __future__ import annotations

import numpy as np

from univtac_data.storage.backend import EpisodeHandle
from univtac_data.storage.errors import CorruptFileError
from univtac_data.validators.context import EpisodeContext, one_line
from univtac_data.validators.report import Finding


class _BlockReader:
    """Reads one streamed array block by block and remembers the frames it could not decode."""

    def __init__(self, ctx: EpisodeContext, handle: EpisodeHandle, path: str) -> None:
        self.ctx, self.handle, self.path = ctx, handle, path
        self.bad_frames: list[int] = []
        self.first_error = ""

    def read(self, start: int, stop: int) -> tuple[np.ndarray | None, np.ndarray]:
        """``(block, valid)``: the frames ``start:stop`` (zeros where unreadable) and which are valid."""
        try:
            return self.handle.read(self.path, slice(start, stop)), np.ones(stop - start, bool)
        except CorruptFileError as error:
            self.first_error = self.first_error or one_line(error)
        frames: list[np.ndarray | None] = []
        for t in range(start, stop):
            try:
                frames.append(self.handle.read(self.path, slice(t, t + 1))[0])
            except CorruptFileError as error:
                self.first_error = self.first_error or one_line(error)
                self.bad_frames.append(t)
                frames.append(None)
        valid = np.array([f is not None for f in frames])
        good = next((f for f in frames if f is not None), None)
        if good is None:
            return None, valid
        block = np.zeros((stop - start, *good.shape), good.dtype)
        for k, frame in enumerate(frames):
            if frame is not None:
                block[k] = frame
        return block, valid

    def finding(self) -> Finding | None:
        if not self.bad_frames:
            return None
        listed = self.bad_frames[: self.ctx.config.max_listed_frames]
        return Finding(message=f"{self.path}: {len(self.bad_frames)} frame(s) cannot be read; first at frame "
                               f"{self.bad_frames[0]} ({self.first_error})",
                       field=self.path, frames=listed, n_frames=len(self.bad_frames))


def near_marker_mask(markers_px: np.ndarray, height: int, width: int, radius_px: float) -> np.ndarray:
    """(B, H, W) bool: pixels within ``radius_px`` of any marker centre of (B, N, 2) ``markers_px`` (u, v),
    pixel centres at integer coordinates. Markers outside the image mark nothing."""
    n_frames = markers_px.shape[0]
    mask = np.zeros((n_frames, height, width), bool)
    reach = int(np.ceil(radius_px)) + 1
    offsets = np.arange(-reach, reach + 1)
    du, dv = (a.ravel() for a in np.meshgrid(offsets, offsets))
    centres = np.clip(markers_px.astype(np.float64), -4.0 * reach, max(height, width) + 4.0 * reach)
    base = np.rint(centres).astype(np.int64)
    u = base[..., 0, None] + du  # (B, N, K)
    v = base[..., 1, None] + dv
    near = (u - centres[..., 0, None]) ** 2 + (v - centres[..., 1, None]) ** 2 <= radius_px ** 2
    near &= (u >= 0) & (u < width) & (v >= 0) & (v < height)
    frame_index = np.broadcast_to(np.arange(n_frames)[:, None, None], u.shape)
    mask[frame_index[near], v[near], u[near]] = True
    return mask


def _new(ctx: EpisodeContext, key: str) -> np.ndarray:
    ctx.summaries[key] = np.full(ctx.n_frames, np.nan)
    return ctx.summaries[key]


def _pad_block(ctx: EpisodeContext, pad: str, start: int, stop: int,
               blocks: dict[str, tuple[np.ndarray | None, np.ndarray]]) -> None:
    depth = blocks.get(f"tactile/{pad}/depth_um")
    if depth is not None and depth[0] is not None:
        out = ctx.summaries.get(f"{pad}/depth_max_um")
        out = _new(ctx, f"{pad}/depth_max_um") if out is None else out
        values = depth[0].reshape(stop - start, -1).max(axis=1).astype(np.float64)
        out[start:stop] = np.where(depth[1], values, np.nan)
    mask = blocks.get(f"tactile/{pad}/contact_mask")
    if mask is not None and mask[0] is not None:
        out = ctx.summaries.get(f"{pad}/contact_px")
        out = _new(ctx, f"{pad}/contact_px") if out is None else out
        counts = np.count_nonzero(mask[0].reshape(stop - start, -1), axis=1).astype(np.float64)
        out[start:stop] = np.where(mask[1], counts, np.nan)
    _marked_pure_block(ctx, pad, start, stop, blocks)
    _reference_block(ctx, pad, start, stop, blocks)


def _reference_block(ctx: EpisodeContext, pad: str, start: int, stop: int,
                     blocks: dict[str, tuple[np.ndarray | None, np.ndarray]]) -> None:
    reference = ctx.arrays.get(f"tactile/{pad}/pure_ref_rgb")
    pure = blocks.get(f"tactile/{pad}/pure_rgb")
    depth = blocks.get(f"tactile/{pad}/depth_um")
    if reference is None or pure is None or depth is None or pure[0] is None or depth[0] is None \
            or reference.shape != pure[0].shape[1:]:
        return
    out = ctx.summaries.get(f"{pad}/reference_diff_levels")
    out = _new(ctx, f"{pad}/reference_diff_levels") if out is None else out
    untouched = (depth[0].reshape(stop - start, -1).max(axis=1) == 0) & pure[1] & depth[1]
    for k in np.flatnonzero(untouched):  # only frames without indentation: usually the approach
        frame = pure[0][k]
        diff = np.maximum(frame, reference) - np.minimum(frame, reference)
        out[start + k] = float(diff.mean())


def _marked_pure_block(ctx: EpisodeContext, pad: str, start: int, stop: int,
                       blocks: dict[str, tuple[np.ndarray | None, np.ndarray]]) -> None:
    marked = blocks.get(f"tactile/{pad}/marked_rgb")
    pure = blocks.get(f"tactile/{pad}/pure_rgb")
    markers = ctx.arrays.get(f"tactile/{pad}/markers_px")
    if marked is None or pure is None or marked[0] is None or pure[0] is None or markers is None \
            or ctx.profile is None:
        return
    levels = ctx.summaries.get(f"{pad}/marked_pure_diff_levels")
    if levels is None:
        levels = _new(ctx, f"{pad}/marked_pure_diff_levels")
        _new(ctx, f"{pad}/marked_pure_diff_px")
    count = ctx.summaries[f"{pad}/marked_pure_diff_px"]
    centres = markers[start:stop]
    finite = np.isfinite(centres).reshape(stop - start, -1).all(axis=1)
    radius = ctx.profile.marker_radius_px + ctx.config.marker_clearance_px
    near = near_marker_mask(np.where(np.isfinite(centres), centres, -1e6), marked[0].shape[1],
                            marked[0].shape[2], radius)
    # |a - b| in uint8 without widening, and reductions over whole frames: a max over the 3-long channel
    # axis is several times slower than either.
    diff = np.maximum(marked[0], pure[0]) - np.minimum(marked[0], pure[0])
    diff *= ~near[..., None]  # zero near the markers (a multiply beats a masked assignment here)
    valid = marked[1] & pure[1] & finite
    worst = diff.reshape(stop - start, -1).max(axis=1)
    levels[start:stop] = np.where(valid, worst, np.nan)
    tol = ctx.config.marked_pure_tolerance_levels
    pixels = np.zeros(stop - start)
    for k in np.flatnonzero(worst > tol):  # only frames that differ: count their pixels
        over = diff[k] > tol
        pixels[k] = np.count_nonzero(over[..., 0] | over[..., 1] | over[..., 2])
    count[start:stop] = np.where(valid, pixels, np.nan)


def _camera_block(ctx: EpisodeContext, camera: str, start: int, stop: int,
                  blocks: dict[str, tuple[np.ndarray | None, np.ndarray]]) -> None:
    rgb = blocks.get(f"scene/cameras/{camera}/rgb")
    if rgb is not None and rgb[0] is not None:
        key = f"camera/{camera}/rgb_std_levels"
        spread = ctx.summaries.get(key)
        spread = _new(ctx, key) if spread is None else spread
        sample = rgb[0][:, ::4, ::4].reshape(stop - start, -1).astype(np.float32)
        spread[start:stop] = np.where(rgb[1], sample.std(axis=1), np.nan)
    depth = blocks.get(f"scene/cameras/{camera}/depth_m")
    if depth is None or depth[0] is None:
        return
    key = f"camera/{camera}/depth_nonfinite_px"
    out = ctx.summaries.get(key)
    out = _new(ctx, key) if out is None else out
    bad = (~np.isfinite(depth[0])).reshape(stop - start, -1).sum(axis=1).astype(np.float64)
    out[start:stop] = np.where(depth[1], bad, np.nan)


def scan_streamed(ctx: EpisodeContext, handle: EpisodeHandle, paths: list[str]) -> None:
    """Read every array of ``paths`` block by block, filling ``ctx.summaries`` and ``ctx.read_problems``."""
    readers = {path: _BlockReader(ctx, handle, path) for path in paths}
    if not readers:
        return
    block = ctx.config.read_block_frames
    for start in range(0, ctx.n_frames, block):
        stop = min(ctx.n_frames, start + block)
        blocks = {path: reader.read(start, stop) for path, reader in readers.items()}
        for pad in ctx.meta.pads:
            _pad_block(ctx, pad, start, stop, blocks)
        for camera in ctx.meta.cameras:
            _camera_block(ctx, camera.name, start, stop, blocks)
    for path, reader in readers.items():
        finding = reader.finding()
        if finding is not None:
            ctx.read_problems.append(finding)
            if len(reader.bad_frames) == ctx.n_frames:
                ctx.fields[path].problem = "unreadable"
