"""Safety rules: the gel stays within its safe indentation, a held object does not slip, grasp forces stay
in bounds, and the metadata's safety summary tells the truth.

Safety comparisons treat a non-finite value as a violation (an unknown force is not a safe force).
Frames that could not be read are left out (``schema.readable`` reports them).
"""

from __future__ import annotations

import numpy as np

from univtac_data.validators.context import EpisodeContext
from univtac_data.validators.registry import Skip, collect, frame_finding, rule
from univtac_data.validators.report import Finding


def depth_over(ctx: EpisodeContext, limit_mm: float, what: str) -> list[Finding]:
    """Frames whose deepest indentation, on any pad, exceeds ``limit_mm``; ``what`` names the limit."""
    out = []
    for pad in ctx.meta.pads:
        depth_mm = ctx.summary(f"{pad}/depth_max_um") / 1000.0
        out.append(frame_finding(f"tactile/{pad}/depth_um", depth_mm > limit_mm, depth_mm,
                                 f"deeper than the {what} {limit_mm} mm", ctx.config.max_listed_frames, unit="mm"))
    return collect(out)


@rule("safety.max_indentation", "safety", threshold="profile.safe_indentation_mm")
def max_indentation(ctx: EpisodeContext) -> list[Finding]:
    """The deepest indentation of each frame stays within the sensor's safe_indentation_mm."""
    return depth_over(ctx, ctx.require_profile().safe_indentation_mm, "safe limit")


def held_frames(ctx: EpisodeContext) -> np.ndarray:
    """(T,) bool: the object is held, i.e. every pad has contact pixels, or every pad's normal force is at
    least held_normal_force_n."""
    by_contact = np.ones(ctx.n_frames, bool)
    by_force = np.ones(ctx.n_frames, bool)
    have_contact = have_force = True
    for pad in ctx.meta.pads:
        try:
            by_contact &= np.nan_to_num(ctx.summary(f"{pad}/contact_px")) > 0
        except Skip:
            have_contact = False
        path = f"tactile/{pad}/normal_force_n"
        if path in ctx.arrays:
            by_force &= np.nan_to_num(ctx.arrays[path].astype(np.float64)) >= ctx.config.held_normal_force_n
        else:
            have_force = False
    if not have_contact and not have_force:
        raise Skip("neither contact masks nor normal forces are usable to tell when the object is held")
    return (by_contact & have_contact) | (by_force & have_force)


def controlled_slip_frames(ctx: EpisodeContext) -> np.ndarray:
    """(T,) bool: frames of a task primitive that lets the object slip on purpose (the task's
    ``controlled_slip_primitives``, e.g. Put Bottle in Shelf's swing); none for other episodes."""
    none = np.zeros(ctx.n_frames, bool)
    if ctx.meta.kind != "task" or "scene/primitive" not in ctx.arrays:
        return none
    from univtac_data.generators.tasks.registry import TASKS

    task = TASKS.get(ctx.meta.name)
    names = list(ctx.meta.primitive_names or [])
    wanted = [names.index(p) for p in getattr(task, "controlled_slip_primitives", ()) if p in names]
    if not wanted:
        return none
    return np.isin(ctx.arrays["scene/primitive"].astype(np.int64), wanted)


def slip_since_controlled(slip: np.ndarray, controlled: np.ndarray) -> np.ndarray:
    """(T,) slip_mm counted from the end of the last controlled-slip frame (slip_mm accumulates from contact
    onset; a drop means a new contact, which counts from 0)."""
    out = slip.copy()
    base = 0.0
    for k in range(len(slip)):
        if controlled[k]:
            base, out[k] = slip[k], 0.0
            continue
        if slip[k] < base:
            base = 0.0
        out[k] = slip[k] - base
    return out


def _slip_limit_mm(ctx: EpisodeContext) -> float:
    """max_slip_held_mm, or a registered task's own ``max_pad_slip_mm`` when it declares one (an insertion
    expert slides the object in the grasp on purpose)."""
    if ctx.meta.kind == "task":
        from univtac_data.generators.tasks.registry import TASKS

        task = TASKS.get(ctx.meta.name)
        if task is not None and task.max_pad_slip_mm is not None:
            return float(task.max_pad_slip_mm)
    return ctx.config.max_slip_held_mm


@rule("safety.slip_while_held", "safety", threshold="max_slip_held_mm")
def slip_while_held(ctx: EpisodeContext) -> list[Finding]:
    """While the object is held (contact on every pad, or every pad's normal force >= held_normal_force_n),
    each pad's slip_mm stays at or below max_slip_held_mm (a task's max_pad_slip_mm, if it declares one). A
    task's controlled slip (its ``controlled_slip_primitives``) is exempt, and the slip it leaves behind does not
    count afterwards."""
    held = held_frames(ctx)
    limit = _slip_limit_mm(ctx)
    controlled = controlled_slip_frames(ctx)
    out = []
    for pad in ctx.meta.pads:
        slip = ctx.array(f"tactile/{pad}/slip_mm").astype(np.float64)
        if controlled.any():
            slip = slip_since_controlled(slip, controlled)
        out.append(frame_finding(f"tactile/{pad}/slip_mm", held & ~(slip <= limit), slip,
                                 f"slip more than {limit} mm while the object is held", ctx.config.max_listed_frames,
                                 unit="mm"))
    return collect(out)


@rule("safety.grasp_force", "safety", threshold="max_normal_force_n")
def grasp_force(ctx: EpisodeContext) -> list[Finding]:
    """Each pad's normal_force_n lies in [0, max_normal_force_n]."""
    limit = ctx.config.max_normal_force_n
    out = []
    for pad in ctx.meta.pads:
        force = ctx.array(f"tactile/{pad}/normal_force_n").astype(np.float64)
        out.append(frame_finding(f"tactile/{pad}/normal_force_n", ~((force >= 0) & (force <= limit)), force,
                                 f"outside [0, {limit}] N", ctx.config.max_listed_frames, unit="N"))
    return collect(out)


def _episode_max(values: list[np.ndarray]) -> tuple[float, bool]:
    """Max over pads and frames, and whether every frame was known (no NaN from unreadable frames)."""
    stacked = np.concatenate([v.ravel() for v in values]) if values else np.zeros(0)
    complete = not np.isnan(stacked).any()
    known = stacked[~np.isnan(stacked)]
    return (float(known.max()) if known.size else 0.0), complete


@rule("safety.summary", "safety", threshold="summary_tolerance_mm")
def summary(ctx: EpisodeContext) -> list[Finding]:
    """meta.safety (max indentation, slip, normal force) equals the arrays' maxima within summary_tolerance_mm
    / summary_tolerance_n."""
    cfg, pads, safety = ctx.config, ctx.meta.pads, ctx.meta.safety
    depth, depth_complete = _episode_max([ctx.summary(f"{p}/depth_max_um") / 1000.0 for p in pads])
    slip, _ = _episode_max([ctx.array(f"tactile/{p}/slip_mm").astype(np.float64) for p in pads])
    force, _ = _episode_max([ctx.array(f"tactile/{p}/normal_force_n").astype(np.float64) for p in pads])
    checks = (("max_indentation_mm", safety.max_indentation_mm, depth, cfg.summary_tolerance_mm, depth_complete),
              ("max_slip_mm", safety.max_slip_mm, slip, cfg.summary_tolerance_mm, True),
              ("max_normal_force_n", safety.max_normal_force_n, force, cfg.summary_tolerance_n, True))
    out = []
    for key, stated, actual, tolerance, complete in checks:
        # With unreadable frames the recomputed maximum is a lower bound: only an understatement is certain.
        wrong = not (abs(stated - actual) <= tolerance) if complete else not (stated >= actual - tolerance)
        if wrong:
            out.append(Finding(message=f"meta.safety.{key} is {stated:.6g} but the arrays give {actual:.6g}",
                               field=f"meta.safety.{key}", values=[stated], limits=[actual]))
    return out
