"""Physical invariants of the tactile channels: depth within the gel, no depth or force without contact,
markers inside the image and at rest when nothing touches, markers the only difference between
I_marked and I_pure, and I_pure equal to the episode's undeformed-gel image when nothing indents the gel.

Like the other physics rules these ignore non-finite values and unreadable frames (reported elsewhere).
"""

from __future__ import annotations

import numpy as np

from univtac_data.validators.context import EpisodeContext
from univtac_data.validators.registry import Skip, collect, frame_finding, rule
from univtac_data.validators.report import Finding
from univtac_data.validators.rules_safety import depth_over


@rule("physics.depth_range", "physics", threshold="profile.gel_thickness_mm")
def depth_range(ctx: EpisodeContext) -> list[Finding]:
    """Indentation depth lies in [0, gel_thickness_mm] (>= 0 holds by the uint16 dtype)."""
    return depth_over(ctx, ctx.require_profile().gel_thickness_mm, "gel thickness")


def _no_contact(ctx: EpisodeContext, pad: str) -> np.ndarray:
    return ctx.summary(f"{pad}/contact_px") == 0  # NaN (unreadable) compares False


@rule("physics.contact_consistency", "physics", threshold="contact_force_tolerance_n")
def contact_consistency(ctx: EpisodeContext) -> list[Finding]:
    """A frame with an empty contact_mask has zero depth everywhere and normal_force_n <=
    contact_force_tolerance_n (no depth, no force without contact)."""
    tol, out = ctx.config.contact_force_tolerance_n, []
    for pad in ctx.meta.pads:
        free = _no_contact(ctx, pad)
        depth_um = ctx.summary(f"{pad}/depth_max_um")
        force = ctx.array(f"tactile/{pad}/normal_force_n").astype(np.float64)
        out.append(frame_finding(f"tactile/{pad}/depth_um", free & (depth_um > 0), depth_um,
                                 "show indentation with an empty contact_mask", ctx.config.max_listed_frames,
                                 unit="um"))
        out.append(frame_finding(f"tactile/{pad}/normal_force_n", free & (force > tol), force,
                                 f"show a force above {tol} N with an empty contact_mask",
                                 ctx.config.max_listed_frames, unit="N"))
    return collect(out)


def _outside_px(points: np.ndarray, width: int, height: int) -> np.ndarray:
    """How far (px) each (..., 2) point lies outside [-0.5, W - 0.5] x [-0.5, H - 0.5]; 0 inside."""
    u, v = points[..., 0].astype(np.float64), points[..., 1].astype(np.float64)
    du = np.maximum(-0.5 - u, u - (width - 0.5))
    dv = np.maximum(-0.5 - v, v - (height - 0.5))
    out = np.maximum(np.maximum(du, dv), 0.0)
    return np.where(np.isfinite(points).all(axis=-1), out, np.nan)  # non-finite: physics.finite's business


@rule("physics.markers_in_image", "physics")
def markers_in_image(ctx: EpisodeContext) -> list[Finding]:
    """Reference and current marker centres lie inside the sensor image (pixel centres at integers)."""
    profile = ctx.require_profile()
    w, h, out = profile.image_width_px, profile.image_height_px, []
    for pad in ctx.meta.pads:
        ref = ctx.array(f"tactile/{pad}/markers_ref_px")
        outside = _outside_px(ref, w, h)
        worst_ref = float(np.nanmax(outside, initial=0.0))
        if worst_ref > 0:
            out.append(Finding(message=f"tactile/{pad}/markers_ref_px: {int((outside > 0).sum())} marker(s) outside "
                                       f"the {w}x{h} image, up to {worst_ref:.3g} px",
                               field=f"tactile/{pad}/markers_ref_px", values=[worst_ref]))
        worst = np.nanmax(_outside_px(ctx.array(f"tactile/{pad}/markers_px"), w, h), axis=1, initial=0.0)
        out.append(frame_finding(f"tactile/{pad}/markers_px", worst > 0, worst,
                                 f"have markers outside the {w}x{h} image (value: px beyond the edge)",
                                 ctx.config.max_listed_frames, unit="px"))
    return collect(out)


@rule("physics.markers_at_rest", "physics", threshold="marker_rest_tolerance_px")
def markers_at_rest(ctx: EpisodeContext) -> list[Finding]:
    """When nothing touches a pad (empty contact_mask, normal force <= contact_force_tolerance_n) its markers sit
    within marker_rest_tolerance_px of markers_ref_px."""
    cfg, out = ctx.config, []
    for pad in ctx.meta.pads:
        force = ctx.array(f"tactile/{pad}/normal_force_n").astype(np.float64)
        rest = _no_contact(ctx, pad) & (force <= cfg.contact_force_tolerance_n)
        ref = ctx.array(f"tactile/{pad}/markers_ref_px").astype(np.float64)
        current = ctx.array(f"tactile/{pad}/markers_px").astype(np.float64)
        displacement = np.linalg.norm(current - ref[None], axis=-1)
        displacement[~np.isfinite(displacement)] = np.nan  # non-finite: physics.finite's business
        moved = np.nanmax(displacement, axis=1, initial=0.0)
        out.append(frame_finding(f"tactile/{pad}/markers_px", rest & (moved > cfg.marker_rest_tolerance_px), moved,
                                 "have markers off the reference grid with nothing touching (value: largest "
                                 "displacement)", cfg.max_listed_frames, unit="px"))
    return collect(out)


@rule("physics.marked_pure", "physics", threshold="marked_pure_tolerance_levels")
def marked_pure(ctx: EpisodeContext) -> list[Finding]:
    """I_marked equals I_pure (within marked_pure_tolerance_levels) at every pixel farther than marker_radius_px +
    marker_clearance_px from every current marker centre."""
    tol, out = ctx.config.marked_pure_tolerance_levels, []
    ctx.require_profile()
    for pad in ctx.meta.pads:
        levels = ctx.summary(f"{pad}/marked_pure_diff_levels")
        pixels = ctx.summary(f"{pad}/marked_pure_diff_px")
        finding = frame_finding(f"tactile/{pad}/marked_rgb", levels > tol, levels,
                                "differ from pure_rgb away from the markers (value: largest difference in levels)",
                                ctx.config.max_listed_frames, unit="levels")
        if finding is not None:
            first = finding.frames[0]
            finding = finding.model_copy(update={
                "message": f"{finding.message}; {int(pixels[first])} pixel(s) differ at frame {first}"})
        out.append(finding)
    return collect(out)


@rule("physics.reference_untouched", "physics", threshold="reference_tolerance_levels")
def reference_untouched(ctx: EpisodeContext) -> list[Finding]:
    """Where a pad's gel is not indented (depth 0 everywhere), I_pure matches the episode's pure_ref_rgb (the
    undeformed gel's image) within reference_tolerance_levels on average. Skipped without pure_ref_rgb."""
    tol, out = ctx.config.reference_tolerance_levels, []
    pads = [pad for pad in ctx.meta.pads if f"{pad}/reference_diff_levels" in ctx.summaries]
    if not pads:
        raise Skip("no pad holds pure_ref_rgb (optional; written since format 2.0)")
    for pad in pads:
        levels = ctx.summary(f"{pad}/reference_diff_levels")
        out.append(frame_finding(f"tactile/{pad}/pure_rgb", levels > tol, levels,
                                 "differ from pure_ref_rgb without any indentation (value: mean difference in "
                                 "levels; is pure_ref_rgb this sensor's undeformed image?)",
                                 ctx.config.max_listed_frames, unit="levels"))
    return collect(out)
