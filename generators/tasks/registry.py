"""The tasks by name: what the CLI, the collector and the Gymnasium environments can make."""

from __future__ import annotations

from univtac_data.generators.tasks.base import Task, TaskConfig
from univtac_data.generators.tasks.grasp_classify import GraspClassify
from univtac_data.generators.tasks.grasp_classify_held import GraspClassifyHeld
from univtac_data.generators.tasks.insert_hdmi import InsertHDMI
from univtac_data.generators.tasks.insert_hole import InsertHole
from univtac_data.generators.tasks.insert_tube import InsertTube
from univtac_data.generators.tasks.lift_bottle import LiftBottle
from univtac_data.generators.tasks.lift_can import LiftCan
from univtac_data.generators.tasks.pull_out_key import PullOutKey
from univtac_data.generators.tasks.put_bottle_in_shelf import PutBottleInShelf
from univtac_data.schema.sensors import get_sensor

# the paper's order: pose reasoning, shape perception, contact-rich; Grasp Classify's held version (the paper's
# policy protocol) beside it
TASKS: dict[str, type[Task]] = {
    cls.name: cls
    for cls in (LiftCan, LiftBottle, PutBottleInShelf, GraspClassify, GraspClassifyHeld, InsertHole, InsertTube,
                InsertHDMI, PullOutKey)
}
TASK_NAMES: tuple[str, ...] = tuple(TASKS)


class UnknownTaskError(KeyError):
    """A task name that is not registered; the message lists the known ones."""

    def __str__(self) -> str:
        return str(self.args[0])


def task_class(name: str) -> type[Task]:
    """The task registered as ``name`` (e.g. 'lift_can')."""
    try:
        return TASKS[name]
    except KeyError:
        raise UnknownTaskError(f"unknown task {name!r}; known: {', '.join(TASK_NAMES)}") from None


def make_task(name: str, config: TaskConfig | None = None) -> Task:
    config = config or TaskConfig()
    return task_class(name)(config, get_sensor(config.sensor))


__all__ = ["TASKS", "TASK_NAMES", "UnknownTaskError", "make_task", "task_class"]
