"""MP4 writing through PyAV (FFmpeg's libraries, shipped inside the ``av`` wheel): one H.264 stream per file.

Used by ``export lerobot --video`` (one file per camera, episodes one after another) and ``preview --video``.
PyAV is an optional extra (``[video]``); :func:`require_av` says which extra to install when it is missing.
"""

from __future__ import annotations

from fractions import Fraction
from typing import Any

import numpy as np

from univtac_data.storage.errors import DatasetError

CODEC = "libx264"      # H.264: decoded by every player, browser and by LeRobot's readers (torchcodec, PyAV)
PIX_FMT = "yuv420p"
CRF = "18"             # visually lossless for the tactile images; depth and markers are exported as arrays
GOP = "2"              # a key frame every 2 frames, as LeRobot encodes: random access costs at most one frame


def require_av() -> Any:
    """``import av``, or one clear error naming the extra to install."""
    try:
        import av
    except ImportError:
        raise DatasetError("writing MP4 needs PyAV: pip install 'univtac-data[video]'") from None
    return av


class Mp4Writer:
    """An H.264 MP4 being written frame by frame at a constant ``fps``; ``frames_written`` counts frames.

    Width and height must be even (yuv420p halves the chroma planes); callers pad odd images.
    """

    def __init__(self, path: str, width: int, height: int, fps: int) -> None:
        if width % 2 or height % 2:
            raise ValueError(f"{path}: H.264 in yuv420p needs even sizes (got {width} x {height})")
        av = require_av()
        self.path = path
        self.frames_written = 0
        self._av = av
        self._container = av.open(path, mode="w")
        self._stream = self._container.add_stream(CODEC, rate=Fraction(fps))
        self._stream.width, self._stream.height, self._stream.pix_fmt = width, height, PIX_FMT
        self._stream.options = {"crf": CRF, "g": GOP, "preset": "veryfast"}

    def write(self, rgb: np.ndarray) -> None:
        """Append one (height, width, 3) uint8 RGB frame."""
        frame = self._av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
        frame.pts = self.frames_written  # in the encoder's time base, 1 / fps
        for packet in self._stream.encode(frame):
            self._container.mux(packet)
        self.frames_written += 1

    def close(self) -> None:
        """Flush the encoder and write the file's index (an MP4 is unreadable until then)."""
        for packet in self._stream.encode():
            self._container.mux(packet)
        self._container.close()

    def __enter__(self) -> Mp4Writer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def read_mp4(path: str) -> np.ndarray:
    """Every frame of the first video stream of ``path`` as (T, H, W, 3) uint8 RGB."""
    av = require_av()
    with av.open(path) as container:
        return np.stack([f.to_ndarray(format="rgb24") for f in container.decode(video=0)])
