"""An episode as an MP4 to watch (``univtac-data preview PATH --video OUT.mp4``).

Each video frame is one recorded frame laid out left to right: the scene cameras (if the episode has any),
each pad's I_marked, and each pad's depth map in false colour (black = untouched, scaled to the episode's
deepest press), all at the tactile image height; above them a text band with the frame, time, the running
primitive and both pads' normal forces.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from univtac_data.export.video import Mp4Writer

BAND_PX = 22  # the text band above the tiles


def resize_to_height(rgb: np.ndarray, height: int) -> np.ndarray:
    """An (h, w, 3) uint8 image scaled (bilinear) to ``height`` rows, its aspect kept."""
    if rgb.shape[0] == height:
        return rgb
    from PIL import Image

    width = max(2, round(rgb.shape[1] * height / rgb.shape[0]))
    return np.asarray(Image.fromarray(rgb).resize((width, height), Image.Resampling.BILINEAR))


def depth_colour(depth_um: np.ndarray, deepest_um: float) -> np.ndarray:
    """(H, W) uint16 depth -> (H, W, 3) uint8 in matplotlib's "inferno" (0 is black)."""
    from matplotlib import colormaps

    scaled = depth_um.astype(np.float32) / max(deepest_um, 1.0)
    return (colormaps["inferno"](np.clip(scaled, 0.0, 1.0))[..., :3] * 255).astype(np.uint8)


def frame_caption(meta: Any, t: int, timestamp_ns: int, primitive: int, forces: dict[str, float]) -> str:
    """The text over frame ``t``: frame, time, primitive name, normal force per pad."""
    names = meta.primitive_names
    name = names[primitive] if 0 <= primitive < len(names) else "none"
    force = "  ".join(f"{pad} {value:.2f} N" for pad, value in forces.items())
    return f"{meta.episode_id}  frame {t}/{meta.n_frames}  t={timestamp_ns / 1e9:.3f} s  {name}  normal force: {force}"


def compose_frame(tiles: list[np.ndarray], caption: str) -> np.ndarray:
    """Tiles side by side (each already at one height) under a caption band; even width and height."""
    from PIL import Image, ImageDraw, ImageFont

    row = np.concatenate(tiles, axis=1)
    height, width = row.shape[0] + BAND_PX, row.shape[1]
    canvas = np.zeros((height + height % 2, width + width % 2, 3), np.uint8)
    canvas[BAND_PX:BAND_PX + row.shape[0], :width] = row
    image = Image.fromarray(canvas)
    ImageDraw.Draw(image).text((4, 3), caption, fill=(255, 255, 255), font=ImageFont.load_default(size=14))
    return np.asarray(image)


def write_episode_video(handle: Any, out: str, fps: int | None = None) -> tuple[int, int, int]:
    """Write the episode open in ``handle`` to the MP4 ``out``; returns (frames, width, height).
    ``fps``: playback rate (default: the recorded rate, rounded)."""
    meta = handle.meta
    rate = fps if fps is not None else max(1, round(meta.nominal_rate_hz))
    timestamps = handle.read("timestamps_ns")
    primitive = handle.read("scene/primitive")
    forces = {pad: handle.read(f"tactile/{pad}/normal_force_n") for pad in meta.pads}
    deepest = {pad: float(handle.read(f"tactile/{pad}/depth_um").max()) for pad in meta.pads}
    height = None
    writer: Mp4Writer | None = None
    try:
        for t in range(meta.n_frames):
            pads = [handle.read(f"tactile/{pad}/marked_rgb", t) for pad in meta.pads]
            height = height or pads[0].shape[0]
            tiles = [resize_to_height(handle.read(f"scene/cameras/{c.name}/rgb", t), height) for c in meta.cameras]
            tiles += pads
            tiles += [resize_to_height(depth_colour(handle.read(f"tactile/{pad}/depth_um", t), deepest[pad]), height)
                      for pad in meta.pads]
            caption = frame_caption(meta, t, int(timestamps[t]), int(primitive[t]),
                                    {pad: float(forces[pad][t]) for pad in meta.pads})
            frame = compose_frame(tiles, caption)
            if writer is None:
                writer = Mp4Writer(out, frame.shape[1], frame.shape[0], rate)
            writer.write(frame)
    finally:
        if writer is not None:
            writer.close()
    assert writer is not None
    return writer.frames_written, frame.shape[1], frame.shape[0]
