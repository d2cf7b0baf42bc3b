"""Normalisation of actions and low-dimensional states with saved statistics, and its inverse.

Modes::

    "none"      values as stored (metres, unit quaternions, newtons...)
    "mean_std"  (x - mean) / std                       (ACT)
    "min_max"   2 (x - min) / (max - min) - 1, in [-1, 1] over the data   (diffusion_policy)

A component whose std (or max - min) is below ``eps`` in the data, for example a quaternion component
that never changes, is only centred (scale 1), as diffusion_policy's range normaliser does: dividing by
a near-zero spread would turn the smallest deviation at test time into a huge input.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch

from univtac_data.loaders.stats import FieldStats

NormalizeMode = Literal["none", "mean_std", "min_max"]
NORMALIZE_MODES: tuple[str, ...] = ("none", "mean_std", "min_max")


@dataclass(frozen=True)
class Affine:
    """``normalised = (x - offset) / scale``, per component (float32, the shape of one frame)."""

    offset: np.ndarray
    scale: np.ndarray

    @classmethod
    def of(cls, stats: FieldStats, mode: NormalizeMode, eps: float) -> Affine:
        if mode == "none":
            return cls(np.zeros_like(stats.mean, np.float32), np.ones_like(stats.mean, np.float32))
        if mode == "mean_std":
            offset, scale = stats.mean, stats.std
        elif mode == "min_max":
            offset, scale = (stats.max + stats.min) / 2, (stats.max - stats.min) / 2
        else:
            raise ValueError(f"normalize must be one of {', '.join(NORMALIZE_MODES)} (got {mode!r})")
        scale = np.where(scale * (2 if mode == "min_max" else 1) < eps, 1.0, scale)
        return cls(np.asarray(offset, np.float32), np.asarray(scale, np.float32))


class Normalizer:
    """Per-path affine maps built from statistics. ``forward`` for inputs and targets, ``inverse`` to turn
    a policy's normalised actions back into commands (metres, quaternion, metres)."""

    def __init__(self, stats: dict[str, FieldStats], mode: NormalizeMode = "none", eps: float = 1e-4) -> None:
        if mode not in NORMALIZE_MODES:
            raise ValueError(f"normalize must be one of {', '.join(NORMALIZE_MODES)} (got {mode!r})")
        self.mode = mode
        self.eps = eps
        self.affine = {path: Affine.of(s, mode, eps) for path, s in stats.items()}

    def _get(self, path: str) -> Affine:
        try:
            return self.affine[path]
        except KeyError:
            raise KeyError(f"no statistics for {path!r}; have {sorted(self.affine)}") from None

    def forward(self, path: str, values: torch.Tensor) -> torch.Tensor:
        """(..., *frame_shape) float tensor in stored units -> normalised, same shape."""
        a = self._get(path)
        return (values - torch.from_numpy(a.offset)) / torch.from_numpy(a.scale)

    def inverse(self, path: str, values: torch.Tensor) -> torch.Tensor:
        """Undo ``forward``: normalised values -> stored units."""
        a = self._get(path)
        return values * torch.from_numpy(a.scale) + torch.from_numpy(a.offset)
