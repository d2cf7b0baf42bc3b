"""Half-space against bonded-layer gel (``ContactConfig.gel``): force, extent of the deformation, markers and
stored bytes for the same press on each sensor, and a figure to look at.

A sphere (radius 5 mm) and a cylinder lying across the pad (radius 4 mm) are pressed to the sensor's grasp
depth delta_th and to its safe indentation limit, with each gel model. Per case: the normal force (N), the
share of the image indented by 1 um or more, the largest pile-up of the layer before it is
clipped (as a fraction of the press), the mean radial marker displacement around the contact (px, positive
outward), the tangential force of a stuck drag of ``DRAG_MM`` along x (N) and the Blosc-compressed bytes of the stored I_pure residual (format 2.0: I_pure - pure_ref_rgb).

    python benchmarks/gel_models.py

Writes benchmarks/results/gel_models.json and docs/figures/gel_models.png.
"""

from __future__ import annotations

import json
from dataclasses import replace

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from common import FIGURES, RESULTS, machine  # noqa: E402
from numcodecs import blosc  # noqa: E402

from univtac_data.generators.tactile import (  # noqa: E402
    ContactConfig,
    TactileConfig,
    cylinder_gap,
    render_reference,
    sensor_grid,
    simulate_frame,
    solve_contact,
    sphere_gap,
)
from univtac_data.generators.scene.sim import SimConfig, cell_steps  # noqa: E402
from univtac_data.generators.tactile.kernels import convolve, kernel_set  # noqa: E402
from univtac_data.generators.tactile.sensor_model import downsample_overlap_or_mean  # noqa: E402
from univtac_data.schema.sensors import SENSORS  # noqa: E402
from univtac_data.storage.encoding import FRAME_BLOCK_BYTES, ZSTD_LEVEL  # noqa: E402

GELS = ("half_space", "layer")
DRAG_MM = 0.02  # small enough to stay stuck on every case
SHAPES = {"sphere R 5 mm": lambda p, d: sphere_gap(p, 5.0, d), "cylinder R 4 mm": lambda p, d: cylinder_gap(p, 4.0, d)}


def config(gel: str) -> TactileConfig:
    return TactileConfig(contact=ContactConfig(method="elastic", gel=gel), perspective_markers=False)  # type: ignore[arg-type]


def indented_share(depth_um: np.ndarray) -> float:
    """Share of the image indented by at least 1 um (the stored quantum)."""
    return round(float(np.count_nonzero(depth_um)) / depth_um.size, 3)


def pile_up_fraction(gap: np.ndarray, profile, depth: float) -> float:  # type: ignore[no-untyped-def]
    """The layer's most negative displacement before clipping, over the press (on the generator's solver grid,
    as ``simulate_frame`` solves it)."""
    step = cell_steps(profile, SimConfig())[0]
    grid = sensor_grid(profile, step)
    result = solve_contact(downsample_overlap_or_mean(gap, step), grid, profile.material,
                           ContactConfig(gel="layer", solver_step=step), thickness_mm=profile.gel_thickness_mm)
    ks = kernel_set(grid.shape, grid.dx_mm, grid.dy_mm, profile.material.youngs_modulus_mpa,
                    profile.material.poisson_ratio, profile.gel_thickness_mm)
    return round(float(convolve(result.pressure_mpa, ks.zz, ks.pad_shape).min()) / depth, 3)


def marker_radial_px(frame, profile) -> float:  # type: ignore[no-untyped-def]
    centre = np.array([profile.image_width_px / 2, profile.image_height_px / 2])
    moved = frame.markers_px - frame.markers_ref_px
    outward = frame.markers_ref_px - centre
    distance = np.linalg.norm(outward, axis=1)
    ring = (distance > 0.15 * profile.image_height_px) & (distance < 0.45 * profile.image_height_px)
    return round(float(np.mean(np.sum(moved[ring] * outward[ring], axis=1) / distance[ring])), 3)


def residual_kib(frame, reference: np.ndarray) -> float:  # type: ignore[no-untyped-def]
    residual = np.subtract(frame.pure_rgb, reference, dtype=np.uint8)
    return round(len(blosc.compress(residual, b"zstd", ZSTD_LEVEL, blosc.SHUFFLE, FRAME_BLOCK_BYTES)) / 1024, 1)


def main() -> None:
    blosc.use_threads = False
    rows = []
    for name, profile in SENSORS.items():
        reference = render_reference(profile, config("half_space"))
        for shape, make_gap in SHAPES.items():
            for press, depth in (("grasp depth", profile.grasp_threshold_mm), ("safe limit", profile.safe_indentation_mm)):
                gap = make_gap(profile, depth)
                row = {"sensor": name, "shape": shape, "press": press, "depth_mm": depth}
                for gel in GELS:
                    frame = simulate_frame(profile, gap, config=config(gel))
                    row[gel] = {"normal_force_n": round(float(frame.normal_force_n), 3),
                                "indented_share": indented_share(frame.depth_um),
                                "marker_radial_px": marker_radial_px(frame, profile),
                                "pure_residual_kib": residual_kib(frame, reference)}
                    dragged = simulate_frame(profile, gap, tangential_mm=(DRAG_MM, 0.0), config=config(gel))
                    assert float(dragged.slip_mm) == 0.0, (name, shape, press, gel)
                    row[gel]["stuck_drag_force_n"] = round(float(dragged.shear_force_n[0]), 4)
                row["layer"]["pile_up_fraction"] = pile_up_fraction(gap, profile, depth)
                rows.append(row)
                print(json.dumps(row))
    result = {"machine": machine(), "gels": list(GELS), "rows": rows}
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "gel_models.json").write_text(json.dumps(result, indent=2) + "\n")
    figure(FIGURES / "gel_models.png")


def figure(path) -> None:  # type: ignore[no-untyped-def]
    """GF225, sphere at the safe limit: I_pure - reference (amplified) for both gels, and the depth along x."""
    profile = SENSORS["gf225"]
    depth = profile.safe_indentation_mm
    gap = sphere_gap(profile, 5.0, depth)
    reference = render_reference(profile, config("half_space")).astype(np.int16)
    frames = {gel: simulate_frame(profile, gap, config=replace(config(gel), perspective_markers=True)) for gel in GELS}
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.4))
    for ax, gel in zip(axes[:2], GELS, strict=True):
        difference = frames[gel].pure_rgb.astype(np.int16) - reference
        ax.imshow(np.clip(128 + 8 * difference, 0, 255).astype(np.uint8))
        ax.set_title(f"{gel.replace('_', '-')}: I_pure - reference (x8)\n"
                     f"{float(frames[gel].normal_force_n):.2f} N, "
                     f"{100 * np.count_nonzero(difference.any(axis=2)) / difference[..., 0].size:.0f} % of pixels changed",
                     fontsize=9)
        ax.axis("off")
    x_mm = sensor_grid(profile, 1).x_mm
    row = profile.image_height_px // 2
    overlap = np.maximum(-gap[row], 0.0)
    for gel, colour in zip(GELS, ("tab:orange", "tab:green"), strict=True):
        axes[2].plot(x_mm, frames[gel].depth_mm[row], color=colour, label=gel.replace("_", "-"))
    axes[2].plot(x_mm, overlap, "k:", label="sphere overlap")
    axes[2].set_xlabel("x in the gel-pad-centre frame (mm)")
    axes[2].set_ylabel("indentation D (mm)")
    axes[2].set_title(f"depth along the centre row (gel {profile.gel_thickness_mm} mm thick)", fontsize=9)
    axes[2].legend(fontsize=8)
    fig.suptitle(f"ViTai GF225, sphere R 5 mm pressed {depth} mm: half-space against bonded-layer gel", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)


if __name__ == "__main__":
    main()
