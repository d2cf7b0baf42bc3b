"""Rules for task episodes (``meta.kind == "task"``): the recorded success agrees with the recorded final
state, actions stay inside the action space, camera frames are not blank, and the held object does not
slip in the hand beyond the task's limit. Indenter episodes skip them.

The success check re-runs the task's own ``success(state)`` on the last frame's recorded poses (the task is
looked up by ``meta.name`` in the task registry), with the episode's recorded safety verdict, so a flag
that disagrees with the data is found whoever wrote the file.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from univtac_data.validators.context import EpisodeContext
from univtac_data.validators.registry import Skip, collect, frame_finding, rule
from univtac_data.validators.report import Finding

BLANK_STD_LEVELS = 1.0  # a camera frame whose pixels spread less than this (uint8 levels) shows nothing


def _task(ctx: EpisodeContext) -> Any:
    if ctx.meta.kind != "task":
        raise Skip("not a task episode")
    from univtac_data.generators.tasks.registry import TASKS, make_task

    if ctx.meta.name not in TASKS:
        raise Skip(f"task {ctx.meta.name!r} is not registered in this version")
    return make_task(ctx.meta.name)


def _task_meta(ctx: EpisodeContext) -> dict[str, Any]:
    task_meta = ctx.meta.extra.get("task")
    if not isinstance(task_meta, dict):
        raise Skip("meta.extra.task is missing: not written by the task collector")
    return task_meta


@rule("physics.task_success_agrees", "physics")
def task_success_agrees(ctx: EpisodeContext) -> list[Finding]:
    """A task episode's success flag equals the task's success check on its last recorded frame (and safety)."""
    from univtac_data.generators.tasks.base import TaskState

    task = _task(ctx)
    task_meta = _task_meta(ctx)
    objects = task.objects()
    poses = {name: ctx.array(f"scene/objects/{name}/pose").astype(np.float64) for name in objects}
    ee = ctx.array("robot/ee_pose")
    width = ctx.array("robot/gripper_width_m")
    state = TaskState(step=ctx.n_frames - 1, objects={n: p[-1] for n, p in poses.items()},
                      initial_objects={n: p[0] for n, p in poses.items()}, ee_pose=ee[-1].astype(np.float64),
                      opening_m=float(width[-1]), indentation_mm=0.0, in_hand_slip_mm=0.0,
                      memory=task_meta.get("memory", {}), layout=task_meta.get("layout", {}))
    recomputed = bool(task.success(state)) and bool(task_meta.get("safe", True))
    if ctx.meta.success is None or bool(ctx.meta.success) != recomputed:
        return [Finding(message=f"meta.success is {ctx.meta.success} but the task's check on the last frame "
                                f"gives {recomputed}", field="scene/objects")]
    return []


@rule("schema.task_actions_in_bounds", "schema")
def task_actions_in_bounds(ctx: EpisodeContext) -> list[Finding]:
    """A task episode's actions lie in the task action space (workspace box, quaternion components, opening)."""
    _task(ctx)
    from univtac_data.generators.tasks.session import ActionBounds

    bounds = ActionBounds.default()
    actions = ctx.array("robot/action").astype(np.float64)
    below = actions < bounds.low - 1e-6
    above = actions > bounds.high + 1e-6
    bad = (below | above).any(axis=1)
    worst = np.where(below, bounds.low - actions, np.where(above, actions - bounds.high, 0.0)).max(axis=1)
    return collect([frame_finding("robot/action", bad, worst, "outside the action space (by up to)",
                                  ctx.config.max_listed_frames)])


@rule("physics.camera_not_blank", "physics", threshold="camera_blank_std_levels")
def camera_not_blank(ctx: EpisodeContext) -> list[Finding]:
    """Every scene camera frame shows something: its pixel values spread by at least camera_blank_std_levels."""
    if not ctx.meta.cameras:
        raise Skip("the episode has no scene camera")
    out = []
    for camera in ctx.meta.cameras:
        spread = ctx.summary(f"camera/{camera.name}/rgb_std_levels")
        limit = ctx.config.camera_blank_std_levels
        out.append(frame_finding(f"scene/cameras/{camera.name}/rgb", np.nan_to_num(spread, nan=np.inf) < limit,
                                 spread, f"are blank (pixel spread below {limit} levels)", ctx.config.max_listed_frames,
                                 unit="levels"))
    return collect(out)


@rule("safety.task_in_hand_slip", "safety")
def task_in_hand_slip(ctx: EpisodeContext) -> list[Finding]:
    """While both pads touch a task's object it moves in the gripper frame by at most the task's max_in_hand_slip_mm."""
    from univtac_data.generators.scene.geometry import quat_to_mat

    task = _task(ctx)
    held = np.ones(ctx.n_frames, bool)
    for pad in ctx.meta.pads:
        held &= np.nan_to_num(ctx.summary(f"{pad}/contact_px")) > 0
    ee = ctx.array("robot/ee_pose").astype(np.float64)
    names = task.objects()
    positions = np.stack([ctx.array(f"scene/objects/{n}/pose")[:, :3].astype(np.float64) for n in names])
    slip = np.zeros(ctx.n_frames)
    anchor: tuple[int, np.ndarray] | None = None
    for k in range(ctx.n_frames):
        if not held[k]:
            anchor = None
            continue
        # the held object sits between the pads: of the task's objects, the nearest the gripper origin
        nearest = int(np.argmin(np.linalg.norm(positions[:, k] - ee[k, :3], axis=1)))
        rel = quat_to_mat(ee[k, 3:]).T @ (positions[nearest, k] - ee[k, :3])
        if anchor is None or anchor[0] != nearest:
            anchor = (nearest, rel)
        slip[k] = float(np.linalg.norm(rel - anchor[1])) * 1000.0
    limit = task.max_in_hand_slip_mm
    return collect([frame_finding("scene/objects", slip > limit, slip,
                                  f"slipped in the hand beyond {limit} mm", ctx.config.max_listed_frames, unit="mm")])
