"""A task's expert driving one session from one seed: the loop that demonstration collection, the expert
benchmarks and the task tests share, so that the step limit and the session's life are decided in one place.

    with expert_rollout(task, seed) as run:
        for step in run.steps():        # run.state: the state the expert decided this step from
            state = run.take(step)      # every yielded step must be taken before the next is asked for
        success = task.success(run.state)
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

from univtac_data.generators.tasks.base import ExpertContext, Step, Task, TaskState
from univtac_data.generators.tasks.session import TaskSession

__all__ = ["ExpertRollout", "expert_rollout"]


@dataclass
class ExpertRollout:
    """One expert rollout in progress. ``state``: the latest observation (after the reset, then after each
    step taken); ``ctx``: the expert's context (its ``memory`` holds what it read and corrected)."""

    task: Task
    session: TaskSession
    ctx: ExpertContext
    state: TaskState

    def steps(self) -> Iterator[Step]:
        """The expert's steps until its script ends or the rollout reaches the task's step limit
        (``Task.step_limit``, a time limit at the configured rate). Take each with ``take`` before asking for
        the next: the expert decides its next step from the state the last one left."""
        for step in self.task.expert(self.ctx):
            if self.session.steps >= self.task.step_limit:
                return
            taken = self.session.steps
            yield step
            if self.session.steps != taken + 1:
                raise RuntimeError(f"{self.task.name}: expert step {taken} was not taken once with "
                                   f"ExpertRollout.take before the next was asked for")

    def take(self, step: Step) -> TaskState:
        """Apply ``step``'s action (with its primitive label) and return the new state."""
        self.state = self.session.step(step.action, step.primitive)
        return self.state

    def run(self) -> TaskState:
        """Take every remaining step; the final state."""
        for step in self.steps():
            self.take(step)
        return self.state


@contextmanager
def expert_rollout(task: Task, seed: int, *, record: bool = False, corrections: bool = True
                   ) -> Iterator[ExpertRollout]:
    """A session of ``task`` reset to ``seed`` with its expert ready; closed on leaving the block.
    ``record``: the session records frames (for an episode); ``corrections=False`` switches the expert's
    corrections off (to measure what they are worth)."""
    session = TaskSession(task, record=record)
    try:
        state = session.reset(seed)
        ctx = ExpertContext(session, session.rng)
        ctx.corrections_enabled = corrections
        yield ExpertRollout(task, session, ctx, state)
    finally:
        session.close()
