"""The task's whole expert under a stability sweep's settings: the run the sweeps add to their scripted trials
(``insertion_stability.py``, ``pivot_stability.py``), because a setting can pass a trial and still lose the task."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from univtac_data.generators.tasks.base import Task, TaskConfig
from univtac_data.generators.tasks.expert_rollout import expert_rollout

_TASK = TaskConfig()
CONTROL_TICK_S = _TASK.timestep_s * _TASK.control_period_steps  # the tasks' controller tick (2 ms)


def swept_config(timestep_s: float) -> TaskConfig:
    """A task's configuration at a swept physics step, without cameras: the controller still ticks every
    ``CONTROL_TICK_S`` (at least one step a tick), so a finer or coarser step changes the physics, not the
    finger servos' rate."""
    return TaskConfig(cameras=False, timestep_s=timestep_s,
                      control_period_steps=max(1, round(CONTROL_TICK_S / timestep_s)))


@dataclass(frozen=True)
class ExpertRun:
    """One seed's expert run: its outcome, the first safety violation (None: safe throughout), the expert's
    memory (what it decided, e.g. its attempts) and the object's largest slip in the hand, mm."""

    seed: int
    success: bool
    safe: bool
    finite: bool
    first_violation: str | None
    memory: dict[str, Any]
    max_in_hand_slip_mm: float


def whole_expert(task: Task, seed: int) -> ExpertRun:
    """Run ``task``'s expert from ``seed`` to its end or the task's step limit, not recorded; a non-finite state
    stops it and counts as a failure and a violation."""
    with expert_rollout(task, seed) as run:
        session, state, finite = run.session, run.state, True
        for step in run.steps():
            state = run.take(step)
            if not session.sim.finite():
                finite = False
                break
        return ExpertRun(seed, bool(finite and task.success(state)), bool(finite and session.safe), finite,
                         session.first_violation() if finite else "non-finite state", dict(run.ctx.memory),
                         float(session.max_in_hand_slip_mm))
