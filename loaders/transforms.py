"""Sample transforms for the loaders (run in the DataLoader worker, on one sample).

``Resize`` brings tactile images of any sensor to one size, e.g. to train at 96 x 128 on a CPU. Marker
coordinates in ``TactileFrameDataset`` samples are already scaled to [-1, 1] and need no change; pixel
markers (``markers_px``) are rescaled to the new size.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import torch
import torch.nn.functional as F

IMAGE_KEYS: tuple[str, ...] = ("marked_rgb", "pure_rgb", "depth_mm", "contact_mask")


@dataclass(frozen=True)
class Resize:
    """Resize the image-like tensors of a sample to ``height x width`` pixels.

    Float images (``(C, H, W)`` or a history ``(Hh, C, H, W)``) use area averaging when shrinking and
    bilinear interpolation when growing; boolean masks use nearest neighbour and stay boolean.
    ``keys`` are sample keys; keys of a policy sample's ``obs`` dict are matched too.
    """

    height: int
    width: int
    keys: Sequence[str] = IMAGE_KEYS

    def __post_init__(self) -> None:
        if self.height < 1 or self.width < 1:
            raise ValueError(f"height and width must be >= 1 (got {self.height} x {self.width})")

    def _resize(self, image: torch.Tensor) -> torch.Tensor:
        batch = image if image.ndim == 4 else image[None]
        if image.dtype == torch.bool:
            out = F.interpolate(batch.to(torch.uint8), size=(self.height, self.width), mode="nearest").bool()
        else:
            shrink = self.height <= batch.shape[-2] and self.width <= batch.shape[-1]
            out = F.interpolate(batch, size=(self.height, self.width), mode="area" if shrink else "bilinear",
                                **({} if shrink else {"align_corners": False}))
        return out if image.ndim == 4 else out[0]

    def __call__(self, sample: dict[str, Any]) -> dict[str, Any]:
        out = dict(sample)
        for key, value in sample.items():
            if key == "obs" and isinstance(value, dict):
                out[key] = self({**value})
            elif any(key == k or key.endswith("/" + k) for k in self.keys) and isinstance(value, torch.Tensor):
                if value.ndim < 3:
                    raise ValueError(f"{key}: expected (C, H, W) or (Hh, C, H, W), got shape {tuple(value.shape)}")
                out[key] = self._resize(value)
        if "markers_px" in sample and "marked_rgb" in sample:
            h, w = sample["marked_rgb"].shape[-2:]
            scale = torch.tensor([(self.width - 1) / (w - 1), (self.height - 1) / (h - 1)])
            out["markers_px"] = sample["markers_px"] * scale
        return out
