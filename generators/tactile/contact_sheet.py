"""Contact sheets: a PNG of tactile frames for a human to look at (matplotlib, Agg backend).

One column per frame; rows: I_marked, I_pure, depth D (colour map, colour bar in mm) and the marker
displacement arrows (scaled for visibility, the scale is written in the panel title).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["SheetFrame", "contact_sheet", "image_gallery"]


@dataclass(frozen=True)
class SheetFrame:
    """What a contact-sheet column needs; built from a :class:`TactileFrame` or from stored arrays.

    ``marked_rgb``/``pure_rgb``: (H, W, 3) uint8. ``depth_mm``: (H, W) float. ``markers_ref_px``,
    ``markers_px``: (N, 2) px. ``title``: column label.
    """

    marked_rgb: np.ndarray
    pure_rgb: np.ndarray
    depth_mm: np.ndarray
    markers_ref_px: np.ndarray
    markers_px: np.ndarray
    title: str = ""

    @classmethod
    def from_frame(cls, frame: object, title: str = "") -> SheetFrame:
        """From any object with the :class:`TactileFrame` attributes."""
        return cls(
            marked_rgb=frame.marked_rgb, pure_rgb=frame.pure_rgb, depth_mm=frame.depth_mm,  # type: ignore[attr-defined]
            markers_ref_px=frame.markers_ref_px, markers_px=frame.markers_px, title=title,  # type: ignore[attr-defined]
        )


def contact_sheet(frames: Sequence[object], path: str | Path, title: str = "") -> Path:
    """Write a PNG contact sheet of ``frames`` (``SheetFrame`` or ``TactileFrame`` objects) to ``path``."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    cols = [f if isinstance(f, SheetFrame) else SheetFrame.from_frame(f, title=f"frame {i}") for i, f in enumerate(frames)]
    if not cols:
        raise ValueError("contact_sheet needs at least one frame")
    h, w = cols[0].depth_mm.shape
    n = len(cols)
    panel_w = 3.2
    fig, axes = plt.subplots(4, n, figsize=(panel_w * n + 0.8, 4 * panel_w * h / w + 0.9), squeeze=False)
    d_max = max(float(np.max(c.depth_mm)) for c in cols) or 1e-3
    moves = [np.hypot(*(np.asarray(c.markers_px, float) - np.asarray(c.markers_ref_px, float)).T) for c in cols]
    m_max = max((float(m.max()) if m.size else 0.0) for m in moves)
    scale = 1.0 if m_max == 0.0 else max(1.0, 0.08 * w / m_max)
    for j, c in enumerate(cols):
        axes[0, j].imshow(c.marked_rgb)
        axes[0, j].set_title(f"{c.title}\nI_marked" if c.title else "I_marked", fontsize=8)
        axes[1, j].imshow(c.pure_rgb)
        axes[1, j].set_title("I_pure", fontsize=8)
        im = axes[2, j].imshow(c.depth_mm, cmap="viridis", vmin=0.0, vmax=d_max)
        axes[2, j].set_title(f"D (max {float(np.max(c.depth_mm)):.3f} mm)", fontsize=8)
        ref = np.asarray(c.markers_ref_px, float)
        delta = np.asarray(c.markers_px, float) - ref
        axes[3, j].imshow(c.marked_rgb, alpha=0.35)
        axes[3, j].quiver(
            ref[:, 0], ref[:, 1], delta[:, 0] * scale, delta[:, 1] * scale, color="crimson",
            angles="xy", scale_units="xy", scale=1.0, width=0.006,
        )
        axes[3, j].set_title(f"marker motion x{scale:.0f} (max {moves[j].max() if moves[j].size else 0:.2f} px)",
                             fontsize=8)
        for i in range(4):
            axes[i, j].set_xticks([])
            axes[i, j].set_yticks([])
        axes[3, j].set_xlim(0, w)
        axes[3, j].set_ylim(h, 0)
    fig.colorbar(im, ax=axes[2, :].tolist(), label="depth D (mm)", shrink=0.9)
    if title:
        fig.suptitle(title, fontsize=10)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def image_gallery(tiles: Sequence[tuple[np.ndarray, str]], path: str | Path, title: str = "",
                  columns: int | None = None) -> Path:
    """Write a PNG grid of ``(image (H, W, 3) uint8, caption)`` tiles to ``path`` (one look at many episodes).
    ``columns``: tiles a row (default: 7 tactile images, fewer as the tiles get wider, e.g. 3 for a camera
    beside a tactile image)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    if not tiles:
        raise ValueError("image_gallery needs at least one tile")
    aspect = max(image.shape[1] / image.shape[0] for image, _ in tiles)  # width / height of the widest tile
    if columns is None:
        columns = min(7, max(1, round(9.3 / aspect)))
    columns = max(1, min(columns, len(tiles)))
    rows = -(-len(tiles) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(1.95 * aspect * columns, 2.3 * rows + 0.5), squeeze=False)
    for ax in axes.ravel():
        ax.axis("off")
    for ax, (image, caption) in zip(axes.ravel(), tiles):
        ax.imshow(image)
        ax.set_title(caption, fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 0.97) if title else None)
    out = Path(path)
    fig.savefig(out, dpi=90)
    plt.close(fig)
    return out
