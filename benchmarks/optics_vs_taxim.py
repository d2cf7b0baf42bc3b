"""Calibrated optics against Taxim, side by side on the same presses (a benchmark-only extra).

    pip install taxim==1.4.1 jax        # JAX on the CPU
    OMP_NUM_THREADS=1 JAX_PLATFORMS=cpu python benchmarks/optics_vs_taxim.py [--quick]

Taxim (Si & Yuan, RA-L 2022; the example-based model, calibrated on a real GelSight Mini, that UniVTAC's tactile
images come from through TacEx) is given the rigid indenter's height map and the press depth and deforms the gel
itself (its Gaussian pyramid); each of our contact models gets the same rigid shape as a gap field, and its depth
map is rendered with the same calibration (``TaximCalibration.render``). Field and pitch are Taxim's own: its
sensor stays the calibration's 480 x 640 at ``pixmm`` = 0.0295 mm per calibration pixel for any output size
(positions and slopes are rescaled), so a 320 x 240 image is 18.88 x 14.16 mm at 0.059 mm/px, and our profile
is the GelSight Mini with that imaged field. Taxim shifts the height map by its minimum and the press depth and
returns RGB floats in [0, 1] (times 255 here); shadows are off on both sides (ours has none).

Reported per case (sphere, cylinder, cross, flat punch, star; 0.2 to 1.0 mm) and contact model:
* change-image PSNR (dB): each image minus its own untouched gel, so the flat-gel offset below does not count;
  over the whole image and over the changed footprint (pixels either side changes by more than 2 grey levels);
* SSIM of the change images (Gaussian window, sigma 1.5 px);
* the changed footprint (pixels changed by more than 2 grey levels) as a multiple of Taxim's;
* ms a frame: Taxim's render; ours, the whole ``simulate_frame`` (contact, shear, markers, calibrated optics)
  and the calibrated render alone; on the wall clock and as CPU time (the process's for Taxim and the frame, this
  thread's for the render), which other processes' load stretches far less: the speed-ups are given both ways.
And the untouched gel against the calibration's background frame f0 (at 640 x 480 and 320 x 240).

Also a third row, the elastic solver with the gel as the profile's 4 mm bonded layer (not a default), and
where each case's error lies (our contact, our sink-in around it, the gel we leave flat), to show where the
misses come from. The calibrated render is timed on the wall clock and on this thread's CPU clock.

Writes benchmarks/results/optics_vs_taxim.json and docs/figures/optics_vs_taxim.png (``--replot``: the chart
from the JSON).

``--gel-sweep`` asks instead whether any setting of our gel closes the gap to 35 dB: the change-image PSNR of
every case (no timing) for the elastic solver on a bonded layer over thickness and Poisson's ratio, for both
default models with their depth map blurred by Gaussians up to Taxim's own final blur and beyond, and for the
geometric model with its sink-in cut off at other distances (``ContactConfig.tail_start``). Writes
benchmarks/results/optics_gel_sweep.json and docs/figures/optics_gel_sweep.png.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
os.environ.setdefault("JAX_PLATFORMS", "cpu")

import argparse  # noqa: E402
import json  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from collections.abc import Callable  # noqa: E402

import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from scipy.ndimage import gaussian_filter, zoom  # noqa: E402

from univtac_data.generators.tactile import (  # noqa: E402
    ContactConfig, TactileConfig, load_taxim_calibration, simulate_frame, taxim_calibration_dir,
)
from univtac_data.schema.sensors import get_sensor  # noqa: E402
from common import FIGURES, RESULTS, machine  # noqa: E402  (benchmarks/ is on sys.path when run as a script)

H, W = 240, 320
CHANGED_GREY = 2.0  # a pixel is in the changed footprint when a channel moves by more than this, grey levels
FAR_MM = 5.0  # height of "no object" in the rigid height map, mm (anything above the deepest press works)
# the two contact models a user picks (defaults), and the elastic solver with the gel as the profile's 4 mm layer
# bonded to a rigid backing (ContactConfig.gel="layer"): not a default, measured to show where the misses come from
METHODS: dict[str, ContactConfig] = {
    "geometric": ContactConfig(method="geometric"),
    "elastic": ContactConfig(method="elastic"),
    "elastic_layer": ContactConfig(method="elastic", gel="layer"),
}
DEFAULT_METHODS = ("geometric", "elastic")


def field_profile():  # type: ignore[no-untyped-def]
    """The GelSight Mini imaged over the Taxim calibration's field (640 x 0.0295 by 480 x 0.0295 mm)."""
    calib = load_taxim_calibration(taxim_calibration_dir("gelsight_mini"))
    width, height = calib.field_mm  # type: ignore[misc]
    return get_sensor("gelsight_mini").model_copy(update={"imaged_width_mm": width, "imaged_height_mm": height}), calib


def rigid_heights(pitch_mm: float) -> dict[str, np.ndarray]:
    """Lower-surface heights (H, W) mm of the rigid indenters above their lowest point (0), FAR_MM off them."""
    y, x = np.meshgrid((np.arange(H) - (H - 1) / 2) * pitch_mm, (np.arange(W) - (W - 1) / 2) * pitch_mm,
                       indexing="ij")

    def rounded(dist: np.ndarray, edge: float) -> np.ndarray:  # flat top, edges rounded by ``edge`` mm
        return np.where(dist < edge, edge - np.sqrt(np.maximum(edge * edge - dist * dist, 0.0)), FAR_MM)

    r = np.hypot(x, y)
    sphere = np.where(r < 4.0, 4.0 - np.sqrt(np.maximum(16.0 - r * r, 0.0)), FAR_MM)
    across = -np.sin(np.pi / 6) * x + np.cos(np.pi / 6) * y
    cylinder = np.where(np.abs(across) < 3.0, 3.0 - np.sqrt(np.maximum(9.0 - across**2, 0.0)), FAR_MM)
    ax, ay = np.abs(x), np.abs(y)

    def bar(half_l: float, half_w: float, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        return np.hypot(np.maximum(u - half_l, 0.0), np.maximum(v - half_w, 0.0))

    cross = rounded(np.minimum(bar(4.0, 0.8, ax, ay), bar(0.8, 4.0, ax, ay)), 1.0)
    punch = np.where(r < 2.0, 0.0, FAR_MM)
    theta = np.arctan2(y, x)
    star_radius = 2.6 + 1.2 * np.cos(5.0 * theta)  # a five-pointed star, 1.4 to 3.8 mm
    star = rounded(np.maximum(r - star_radius, 0.0), 0.8)
    return {"sphere_r4": sphere, "cylinder_r3": cylinder, "cross": cross, "punch_r2": punch, "star": star}


def psnr(a: np.ndarray, b: np.ndarray, where: np.ndarray | None = None) -> float:
    diff = (a - b) if where is None else (a - b)[where]
    mse = float(np.mean(diff * diff)) if diff.size else 0.0
    return float("inf") if mse == 0.0 else 10.0 * np.log10(255.0**2 / mse)


def ssim(a: np.ndarray, b: np.ndarray) -> float:
    """Mean SSIM over channels of two (H, W, 3) images (grey levels, data range 255), Gaussian window 1.5 px."""
    c1, c2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2
    values = []
    for ch in range(3):
        x, y = a[..., ch], b[..., ch]
        mx, my = gaussian_filter(x, 1.5), gaussian_filter(y, 1.5)
        sxx = gaussian_filter(x * x, 1.5) - mx * mx
        syy = gaussian_filter(y * y, 1.5) - my * my
        sxy = gaussian_filter(x * y, 1.5) - mx * my
        values.append(np.mean((2 * mx * my + c1) * (2 * sxy + c2) / ((mx * mx + my * my + c1) * (sxx + syy + c2))))
    return float(np.mean(values))


def timed(fn: Callable[[], object], repeats: int, clock: Callable[[], float] = time.perf_counter) -> float:
    """Median ms of ``repeats`` calls after a warm-up; ``time.thread_time`` counts this thread's CPU time only,
    which other processes' load stretches far less than the wall clock."""
    fn()
    samples = []
    for _ in range(repeats):
        t = clock()
        fn()
        samples.append(clock() - t)
    return float(np.median(samples)) * 1e3


def error_shares(change_ours: np.ndarray, change_theirs: np.ndarray, contact: np.ndarray,
                 depth_mm: np.ndarray) -> dict[str, float]:
    """Where the squared change-image error lies: in our contact, in our sink-in around it (deformed by more
    than 1 um), or on gel that we leave flat. Fractions of the total."""
    err = ((change_ours - change_theirs) ** 2).sum(axis=-1)
    total = max(float(err.sum()), 1e-12)
    sink_in = (depth_mm > 1e-3) & ~contact
    return {"contact": round(float(err[contact].sum()) / total, 3),
            "sink_in": round(float(err[sink_in].sum()) / total, 3),
            "flat": round(float(err[~contact & ~sink_in].sum()) / total, 3)}


def background_check(calib, taxim) -> dict[str, object]:  # type: ignore[no-untyped-def]
    """Our untouched gel and Taxim's against f0, at the calibration's size and at 320 x 240."""
    out: dict[str, object] = {}
    for h, w in ((480, 640), (H, W)):
        f0 = zoom(calib.f0, (h / calib.f0.shape[0], w / calib.f0.shape[1], 1), order=1, grid_mode=True,
                  mode="nearest")
        ours = calib.render(np.zeros((h, w)), (calib.pixmm * 640 / w, calib.pixmm * 480 / h)).astype(np.float64)
        theirs = np.asarray(taxim.render(np.full((h, w), FAR_MM, np.float32), with_shadow=False),
                            dtype=np.float64) * 255.0
        out[f"{w}x{h}"] = {
            "ours_minus_f0_max_abs_grey": float(np.abs(ours - f0).max()),
            "taxim_minus_f0_mean_rgb_grey": [round(float(v), 2) for v in (theirs - f0).mean(axis=(0, 1))],
            "taxim_minus_f0_min_max_grey": [round(float((theirs - f0).min()), 1), round(float((theirs - f0).max()), 1)],
        }
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="two cases, one depth: a smoke run")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--replot", action="store_true", help="redraw the chart from the committed JSON")
    parser.add_argument("--gel-sweep", action="store_true",
                        help="PSNR over gel thickness, Poisson's ratio, depth blur and sink-in reach (no timing)")
    args = parser.parse_args()
    if args.replot:
        chart(json.loads((RESULTS / "optics_vs_taxim.json").read_text())["cases"], FIGURES / "optics_vs_taxim.png")
        if (RESULTS / "optics_gel_sweep.json").exists():
            sweep_chart(json.loads((RESULTS / "optics_gel_sweep.json").read_text()), FIGURES / "optics_gel_sweep.png")
        return
    if args.gel_sweep:
        gel_sweep()
        return
    from taxim.calibration import CALIB_GELSIGHT_MINI
    from taxim.taxim_jax import TaximJax

    profile, calib = field_profile()
    pitch = profile.mm_per_px_x
    taxim = TaximJax(calib_folder=CALIB_GELSIGHT_MINI)
    configs = {name: TactileConfig(optics="calibrated", calibration=calib, contact=contact)
               for name, contact in METHODS.items()}
    shapes = rigid_heights(pitch)
    depths = (0.2, 0.6, 1.0)
    if args.quick:
        shapes = {k: shapes[k] for k in ("sphere_r4", "cross")}
        depths = (0.6,)
    flat_ours = calib.render(np.zeros((H, W)), (pitch, pitch)).astype(np.float64)
    flat_taxim, changes = taxim_changes(taxim, shapes, depths)
    rows = []
    for name, heights in shapes.items():
        for depth in depths:
            hm = heights.astype(np.float32)
            change_theirs = changes[name, depth]
            theirs = change_theirs + flat_taxim
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                taxim_ms = timed(lambda: np.asarray(taxim.render(hm, with_shadow=False, press_depth=depth)),
                                 args.repeats)
                # CPU time of the whole process: XLA may run work on threads of its own
                taxim_cpu_ms = timed(lambda: np.asarray(taxim.render(hm, with_shadow=False, press_depth=depth)),
                                     args.repeats, time.process_time)
            gap = heights - depth
            row: dict[str, object] = {"shape": name, "depth_mm": depth, "taxim_ms": round(taxim_ms, 2),
                                      "taxim_cpu_ms": round(taxim_cpu_ms, 2)}
            for method, config in configs.items():
                frame = simulate_frame(profile, gap, config=config)
                ours = frame.pure_rgb.astype(np.float64)
                change_ours = ours - flat_ours
                changed_ours = np.abs(change_ours).max(axis=-1) > CHANGED_GREY
                changed_theirs = np.abs(change_theirs).max(axis=-1) > CHANGED_GREY
                footprint = changed_ours | changed_theirs
                frame_ms = timed(lambda: simulate_frame(profile, gap, config=config), args.repeats)  # noqa: B023
                frame_cpu_ms = timed(lambda: simulate_frame(profile, gap, config=config), args.repeats,  # noqa: B023
                                     time.process_time)
                depth_mm = frame.depth_mm
                render_ms = timed(lambda: calib.render(depth_mm, (pitch, pitch)), args.repeats)  # noqa: B023
                render_cpu_ms = timed(lambda: calib.render(depth_mm, (pitch, pitch)), args.repeats,  # noqa: B023
                                      time.thread_time)
                row[method] = {
                    "change_psnr_db": round(psnr(change_ours, change_theirs), 2),
                    "footprint_psnr_db": round(psnr(change_ours, change_theirs, footprint), 2),
                    "raw_psnr_db": round(psnr(ours, theirs), 2),
                    "change_ssim": round(ssim(change_ours + 128.0, change_theirs + 128.0), 4),
                    "footprint_ratio": round(float(changed_ours.sum()) / max(float(changed_theirs.sum()), 1.0), 3),
                    "error_share": error_shares(change_ours, change_theirs, frame.contact_mask, depth_mm),
                    "frame_ms": round(frame_ms, 3),
                    "frame_cpu_ms": round(frame_cpu_ms, 3),
                    "calibrated_render_ms": round(render_ms, 3),
                    "calibrated_render_cpu_ms": round(render_cpu_ms, 3),
                    "speedup_vs_taxim": round(taxim_ms / frame_ms, 1),
                    "speedup_vs_taxim_cpu": round(taxim_cpu_ms / frame_cpu_ms, 1),
                    "normal_force_n": round(float(frame.normal_force_n), 3),
                }
            rows.append(row)
            print(name, depth, f"taxim {taxim_ms:.1f} ms",
                  *(f"{m}: {row[m]['change_psnr_db']} dB, footprint x{row[m]['footprint_ratio']}, "  # type: ignore[index]
                    f"{row[m]['frame_ms']} ms" for m in ("geometric", "elastic")), flush=True)
    summary: dict[str, object] = {}
    for method in METHODS:
        values = [r[method] for r in rows]  # type: ignore[index]
        summary[method] = {
            "change_psnr_db_min": min(v["change_psnr_db"] for v in values),
            "change_psnr_db_median": float(np.median([v["change_psnr_db"] for v in values])),
            "cases_below_35_db": [f"{r['shape']} {r['depth_mm']} mm" for r, v in zip(rows, values)
                                  if v["change_psnr_db"] < 35.0],
            "sink_in_error_share_median_below_35_db": float(np.median(
                [v["error_share"]["sink_in"] for v in values if v["change_psnr_db"] < 35.0] or [0.0])),
            "footprint_ratio_range": [min(v["footprint_ratio"] for v in values), max(v["footprint_ratio"] for v in values)],
            "footprint_ratio_median": float(np.median([v["footprint_ratio"] for v in values])),
            "frame_ms_median": float(np.median([v["frame_ms"] for v in values])),
            "calibrated_render_ms_median": float(np.median([v["calibrated_render_ms"] for v in values])),
            "calibrated_render_ms_max": max(v["calibrated_render_ms"] for v in values),
            "calibrated_render_cpu_ms_median": float(np.median([v["calibrated_render_cpu_ms"] for v in values])),
            "calibrated_render_cpu_ms_max": max(v["calibrated_render_cpu_ms"] for v in values),
            "speedup_vs_taxim_median": float(np.median([v["speedup_vs_taxim"] for v in values])),
            "speedup_vs_taxim_min": min(v["speedup_vs_taxim"] for v in values),
            "speedup_vs_taxim_cpu_median": float(np.median([v["speedup_vs_taxim_cpu"] for v in values])),
            "speedup_vs_taxim_cpu_min": min(v["speedup_vs_taxim_cpu"] for v in values),
            "cases_at_or_above_35_db": int(sum(v["change_psnr_db"] >= 35.0 for v in values)),
        }
    summary["taxim_ms_median"] = float(np.median([r["taxim_ms"] for r in rows]))  # type: ignore[misc]
    summary["taxim_cpu_ms_median"] = float(np.median([r["taxim_cpu_ms"] for r in rows]))  # type: ignore[misc]
    summary["cases"] = len(rows)
    result = {
        "machine": {**machine(threads_used=1, packages=("numpy", "scipy", "numba", "jax", "taxim")),
                    "note": "shared 2-core machine, other engineers' tests running: timings are noisy; "
                            "Taxim and ours were timed side by side in the same run"},
        "settings": {"image": [W, H], "pitch_mm": pitch, "field_mm": [W * pitch, H * pitch],
                     "taxim": "TaximJax 1.4.1, gelsight_mini calibration, with_shadow=False, CPU",
                     "ours": "simulate_frame(optics='calibrated'); geometric and elastic: default ContactConfig "
                             "(elastic step 2, half-space); elastic_layer: gel='layer' (4 mm bonded layer), "
                             "not a default",
                     "changed_grey_levels": CHANGED_GREY, "repeats": args.repeats},
        "background": background_check(calib, taxim),
        "summary": summary,
        "cases": rows,
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    out = RESULTS / ("optics_vs_taxim_quick.json" if args.quick else "optics_vs_taxim.json")
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(summary, indent=2))
    if not args.quick:
        chart(rows, FIGURES / "optics_vs_taxim.png")


def taxim_changes(taxim, shapes: dict[str, np.ndarray], depths: tuple[float, ...]  # type: ignore[no-untyped-def]
                  ) -> tuple[np.ndarray, dict[tuple[str, float], np.ndarray]]:
    """Taxim's untouched gel (H, W, 3) and its change image (RGB grey levels minus that gel) for every case."""
    flat = np.asarray(taxim.render(np.full((H, W), FAR_MM, np.float32), with_shadow=False), dtype=np.float64) * 255.0
    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for name, heights in shapes.items():
            for depth in depths:
                image = taxim.render(heights.astype(np.float32), with_shadow=False, press_depth=depth)
                out[name, depth] = np.asarray(image, dtype=np.float64) * 255.0 - flat
    return flat, out


def gel_sweep() -> None:
    """Change-image PSNR of every case over the gel's parameters (see the module docstring)."""
    from taxim.calibration import CALIB_GELSIGHT_MINI
    from taxim.taxim_jax import TaximJax

    profile, calib = field_profile()
    pitch = profile.mm_per_px_x
    shapes = rigid_heights(pitch)
    _, theirs = taxim_changes(TaximJax(calib_folder=CALIB_GELSIGHT_MINI), shapes, (0.2, 0.6, 1.0))
    flat_ours = calib.render(np.zeros((H, W)), (pitch, pitch)).astype(np.float64)

    def scores(prof, contact: ContactConfig, blur_px: float = 0.0) -> dict[str, object]:  # type: ignore[no-untyped-def]
        config = TactileConfig(optics="calibrated", calibration=calib, contact=contact)
        per_case = {}
        for (name, depth), change_theirs in theirs.items():
            depth_mm = simulate_frame(prof, shapes[name] - depth, config=config).depth_mm
            if blur_px > 0.0:
                depth_mm = gaussian_filter(depth_mm, blur_px, mode="nearest")
            change_ours = calib.render(depth_mm, (pitch, pitch)).astype(np.float64) - flat_ours
            per_case[f"{name} {depth} mm"] = round(psnr(change_ours, change_theirs), 2)
        values = list(per_case.values())
        return {"change_psnr_db_min": min(values), "change_psnr_db_median": float(np.median(values)),
                "cases_below_35_db": [k for k, v in per_case.items() if v < 35.0], "per_case": per_case}

    layer = []
    for nu in (0.4, 0.48, 0.499):
        for thickness in (2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 12.0):
            material = profile.material.model_copy(update={"poisson_ratio": nu})
            prof = profile.model_copy(update={"gel_thickness_mm": thickness, "material": material})
            layer.append({"thickness_mm": thickness, "poisson_ratio": nu,
                          **scores(prof, ContactConfig(method="elastic", gel="layer"))})
            print(f"layer {thickness} mm, nu {nu}: min {layer[-1]['change_psnr_db_min']} dB", flush=True)
    blur = [{"model": method, "blur_px": sigma, **scores(profile, ContactConfig(method=method), sigma)}
            for method in ("geometric", "elastic") for sigma in (0.0, 1.0, 2.0)]
    tail = [{"tail_start": t, **scores(profile, ContactConfig(method="geometric", tail_start=t))}
            for t in (1.2, 2.0, 3.0)]
    result = {
        "machine": machine(threads_used=1, packages=("numpy", "scipy", "numba", "jax", "taxim")),
        "settings": {"image": [W, H], "pitch_mm": pitch, "taxim": "TaximJax 1.4.1, gelsight_mini calibration, "
                     "with_shadow=False", "taxim_final_blur_px": 1.0,
                     "defaults": {"gel_thickness_mm": get_sensor("gelsight_mini").gel_thickness_mm,
                                  "poisson_ratio": profile.material.poisson_ratio,
                                  "tail_start": ContactConfig().tail_start}},
        "layer": layer, "blur": blur, "tail": tail,
        "best_layer": max(layer, key=lambda r: r["change_psnr_db_min"]),
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "optics_gel_sweep.json").write_text(json.dumps(result, indent=2) + "\n")
    sweep_chart(result, FIGURES / "optics_gel_sweep.png")
    best = result["best_layer"]
    print(f"best layer: {best['thickness_mm']} mm, nu {best['poisson_ratio']}: min {best['change_psnr_db_min']} dB; "
          + "; ".join(f"{r['model']} blur {r['blur_px']} px: min {r['change_psnr_db_min']} dB" for r in blur))


def sweep_chart(result: dict, path) -> None:  # type: ignore[no-untyped-def,type-arg]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for nu in sorted({r["poisson_ratio"] for r in result["layer"]}):
        rows = [r for r in result["layer"] if r["poisson_ratio"] == nu]
        axes[0].plot([r["thickness_mm"] for r in rows], [r["change_psnr_db_min"] for r in rows], "o-",
                     label=f"bonded layer, nu = {nu}: worst case")
    for r in result["blur"]:
        if r["blur_px"] == 0.0:
            axes[0].axhline(r["change_psnr_db_min"], ls=":", color="C3" if r["model"] == "elastic" else "C4",
                            label=f"{r['model']}, half-space sink-in (default): worst case")
    axes[0].axhline(35.0, color="k", lw=0.8, ls="--", label="goal 35 dB")
    axes[0].set_xlabel("gel layer thickness (mm)")
    axes[0].set_ylabel("change-image PSNR vs Taxim (dB)")
    axes[0].legend(fontsize=7)
    axes[0].set_title("Worst of 15 presses, elastic solver")
    cases = list(result["layer"][0]["per_case"])
    best = result["best_layer"]
    xs = np.arange(len(cases))
    series = [("elastic, half-space", next(r for r in result["blur"] if r["model"] == "elastic" and r["blur_px"] == 0)),
              ("geometric, half-space", next(r for r in result["blur"] if r["model"] == "geometric" and r["blur_px"] == 0)),
              (f"layer {best['thickness_mm']:g} mm, nu {best['poisson_ratio']}", best)]
    for k, (label, row) in enumerate(series):
        axes[1].bar(xs + (k - 1) * 0.27, [row["per_case"][c] for c in cases], 0.27, label=label)
    axes[1].axhline(35.0, color="k", lw=0.8, ls="--")
    axes[1].set_ylim(25.0, 45.0)
    axes[1].set_xticks(xs, cases, rotation=90, fontsize=7)
    axes[1].set_ylabel("change-image PSNR (dB)")
    axes[1].legend(fontsize=7)
    axes[1].set_title("Per press")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def chart(rows: list[dict], path) -> None:  # type: ignore[no-untyped-def,type-arg]
    labels = [f"{r['shape']}\n{r['depth_mm']} mm" for r in rows]
    xs = np.arange(len(rows))
    fig, axes = plt.subplots(4, 1, figsize=(12, 11), sharex=True)
    width = 0.8 / len(METHODS)
    for k, method in enumerate(METHODS):
        off = (k - (len(METHODS) - 1) / 2) * width
        label = method if method in DEFAULT_METHODS else f"{method} (not a default)"
        axes[0].bar(xs + off, [r[method]["change_psnr_db"] for r in rows], width, label=label)
        axes[1].bar(xs + off, [r[method]["footprint_ratio"] for r in rows], width, label=label)
        axes[2].bar(xs + off, [r[method]["speedup_vs_taxim_cpu"] for r in rows], width, label=label)
        axes[3].bar(xs + off, [r[method]["calibrated_render_cpu_ms"] for r in rows], width, label=label)
    axes[2].axhline(5.0, color="k", lw=0.8, ls="--")
    axes[3].axhline(1.5, color="k", lw=0.8, ls="--")
    axes[3].set_ylabel("calibrated render\n(CPU ms a frame)")
    axes[0].axhline(35.0, color="k", lw=0.8, ls="--")
    axes[0].set_ylim(25.0, 45.0)
    axes[0].set_ylabel("change-image PSNR\nvs Taxim (dB)")
    axes[1].axhline(1.0, color="k", lw=0.8, ls="--")
    axes[1].set_ylabel("changed footprint\n/ Taxim's")
    axes[2].set_ylabel("speed-up over Taxim\n(whole frame, CPU time)")
    axes[2].set_yscale("log")
    axes[3].set_xticks(xs, labels, fontsize=7)
    axes[0].legend(fontsize=8, ncol=3, loc="upper right")
    axes[0].set_title("GelSight Mini calibration, 320 x 240 at 0.059 mm/px: ours (calibrated optics) vs Taxim 1.4.1")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
