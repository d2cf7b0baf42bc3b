"""The task kit: what every benchmark task provides (``Task``), the state its checks read (``TaskState``),
and the settings every task shares (``TaskConfig``).

A task builds its MuJoCo scene from a seeded layout, says which objects and cameras it has, runs its
scripted expert as a closed-loop policy (a generator of actions that reads the pads' touch and what a
camera would see), and answers ``success(state)`` and ``safety(state)`` with thresholds written in its
docstring. ``session.TaskSession`` runs any task step by step; ``envs`` wraps that as a Gymnasium
environment and ``collect`` records expert episodes. Imports go one way: tasks -> scene -> tactile.

Action (every task): an absolute end-effector target in the world frame and a gripper opening,
``(x, y, z) m, quaternion (w, x, y, z), gel-to-gel width m`` (the format's ``robot/action``), held for one
policy step (1 / ``rate_hz`` s) and reached by interpolating from the previous target over the step's
control ticks.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal

import numpy as np

from univtac_data.generators.scene.cameras import DEFAULT_CAMERA_SIZE, CameraSpec
from univtac_data.generators.scene.geometry import quat_to_mat
from univtac_data.generators.scene.pad_forces import PadForce, pad_forces
from univtac_data.generators.scene.sim import GeomTexture
from univtac_data.generators.scene.touch import TouchReading
from univtac_data.schema.sensors import SensorProfile

# Seeds: generation draws environment seeds below EVAL_SEED_BASE and evaluation at or above it, so an
# evaluated rollout never starts from a layout a demonstration was recorded on (UniVTAC evaluates from 1e6).
EVAL_SEED_BASE = 1_000_000


@dataclass(frozen=True)
class TaskConfig:
    """Settings shared by every task (each changes the recorded data, so each is stored with an episode)."""

    sensor: str = "gelsight_mini"
    contact_method: Literal["geometric", "elastic"] = "geometric"  # tactile contact model of the images
    # policy steps (and recorded frames) per second; UniVTAC records at 60 Hz, which is not a whole number of
    # 2 ms control ticks: 50 Hz is (10 ticks), so every step lasts exactly 20 ms
    rate_hz: float = 50.0
    timestep_s: float = 0.001  # MuJoCo step: 2 ms explodes with the finger servos (scenes-and-tasks.md)
    control_period_steps: int = 2  # finger servos and set-point interpolation tick every 2 physics steps
    cameras: bool = True  # record/observe the head and wrist cameras
    camera_size: tuple[int, int] = DEFAULT_CAMERA_SIZE  # width, height px

    def __post_init__(self) -> None:
        self.ticks_per_step  # noqa: B018  (refuses a rate that is not a whole number of control ticks)

    @property
    def ticks_per_step(self) -> int:
        """Control ticks per policy step (a whole number, so that every step lasts the same)."""
        if not self.rate_hz > 0:  # NaN too
            raise ValueError(f"rate must be a positive number of Hz (got {self.rate_hz})")
        ticks = (1.0 / self.rate_hz) / (self.timestep_s * self.control_period_steps)
        if ticks < 1 - 1e-9 or abs(ticks - round(ticks)) > 1e-6:
            tick_ms = self.timestep_s * self.control_period_steps * 1000
            raise ValueError(f"rate {self.rate_hz} Hz is not a whole number of {tick_ms:g} ms control ticks "
                             f"(e.g. 50, 25, 10 Hz)")
        return round(ticks)


def time_limited_steps(max_steps: int, rate_hz: float) -> int:
    """A task's step limit at ``rate_hz``: ``max_steps`` counts steps at the tasks' default 50 Hz, so the limit
    is a time (``max_steps / 50`` s) and a rollout at ``rate_hz`` gets ``max_steps * rate_hz / 50`` steps. One
    rule for generation, evaluation and the environments: a demonstration kept at 25 Hz fits an evaluation."""
    return max(1, round(max_steps * rate_hz / TaskConfig.rate_hz))


@dataclass(frozen=True)
class Step:
    """One expert action: the absolute target (8,) and the primitive that issued it."""

    action: np.ndarray
    primitive: str


@dataclass(frozen=True)
class TaskState:
    """What success and safety checks read at one step. Poses are world frame (x, y, z m; w, x, y, z)."""

    step: int
    objects: dict[str, np.ndarray]  # current pose of every task object
    initial_objects: dict[str, np.ndarray]  # pose at the first step
    ee_pose: np.ndarray
    opening_m: float
    indentation_mm: float  # deepest pad-object overlap over both pads now, mm (>= 0)
    in_hand_slip_mm: float  # how far the held object moved in the gripper frame since both pads gripped it
    memory: dict[str, Any] = field(default_factory=dict)  # what the task's expert decided (e.g. classes)
    layout: dict[str, Any] = field(default_factory=dict)  # the seeded randomisation (e.g. which object is which)

    def axis(self, name: str) -> np.ndarray:
        """(3,) the object's local +z axis in the world."""
        return quat_to_mat(self.objects[name][3:])[:, 2]


@dataclass(frozen=True)
class SafetyCheck:
    """Tactile safety at one step: ``ok`` unless the gel is pressed past the sensor's safe limit or the
    held object slipped in the hand beyond the task's limit; ``reason`` names the first violation."""

    ok: bool
    reason: str | None = None


class Task(ABC):
    """One benchmark task. Subclasses set the class attributes and implement the abstract methods; their
    docstring follows Gymnasium's MuJoCo environments (description, objects with sizes and masses,
    randomisation, expert, success and safety thresholds, step limit)."""

    name: ClassVar[str]  # registry key, e.g. 'lift_can'
    gym_id: ClassVar[str]  # e.g. 'univtac/LiftCan-v0'
    max_steps: ClassVar[int]  # 50 Hz policy steps before a rollout is cut off (a time limit: ``step_limit``)
    primitive_names: ClassVar[list[str]]
    max_in_hand_slip_mm: ClassVar[float] = 5.0  # safety: a held object may move this far in the hand, mm
    # primitives that let the held object slip on the gel on purpose (a controlled slip, e.g. a swing in a
    # loosened grasp): the validators' gel-slip rule does not count slip during them
    controlled_slip_primitives: ClassVar[tuple[str, ...]] = ()
    # the most a pad's recorded slip (tactile/{pad}/slip_mm) may reach while holding, mm, for a task whose expert
    # slides the object in the grasp on purpose (insertion); None: the validators' default (max_slip_held_mm)
    max_pad_slip_mm: ClassVar[float | None] = None

    def __init__(self, config: TaskConfig, profile: SensorProfile) -> None:
        self.config = config
        self.profile = profile

    @property
    def step_limit(self) -> int:
        """Policy steps before a rollout is cut off at this task's rate (``time_limited_steps``)."""
        return time_limited_steps(self.max_steps, self.config.rate_hz)

    # --- scene -------------------------------------------------------------------------------------
    @abstractmethod
    def sample_layout(self, rng: np.random.Generator) -> dict[str, Any]:
        """The seeded randomisation (JSON-able: stored with the episode)."""

    @abstractmethod
    def scene_xml(self, layout: dict[str, Any]) -> str:
        """MJCF of the scene for ``layout``, gripper included (``scene.gripper``, welded mount)."""

    @abstractmethod
    def objects(self) -> list[str]:
        """Bodies whose poses are recorded; the first is the tactile object."""

    def pad_geoms(self) -> list[str]:
        """Geoms the pads can feel (default: each object's geom of the same name)."""
        return self.objects()

    def textures(self, layout: dict[str, Any]) -> list[GeomTexture]:
        return []

    def cameras(self) -> list[CameraSpec]:
        if not self.config.cameras:
            return []
        w, h = self.config.camera_size
        return [CameraSpec("head", "world", w, h), CameraSpec("wrist", "gripper", w, h)]

    @abstractmethod
    def start_pose(self, layout: dict[str, Any]) -> np.ndarray:
        """(8,) where the set-up leaves the gripper (not recorded): pose and opening (the policy starts here)."""

    # --- behaviour ---------------------------------------------------------------------------------
    @abstractmethod
    def expert(self, ctx: ExpertContext) -> Iterator[Step]:
        """The scripted expert as a closed-loop policy: yields one ``Step`` per policy step."""

    @abstractmethod
    def success(self, state: TaskState) -> bool:
        """Whether the task is done at ``state`` (thresholds in the class docstring)."""

    def safety(self, state: TaskState) -> SafetyCheck:
        """The paper's tactile safety: maximum indentation within the sensor's safe limit and in-hand slip
        within ``max_in_hand_slip_mm``."""
        if state.indentation_mm > self.profile.safe_indentation_mm:
            return SafetyCheck(False, f"indentation {state.indentation_mm:.2f} mm > safe "
                                      f"{self.profile.safe_indentation_mm} mm")
        if state.in_hand_slip_mm > self.max_in_hand_slip_mm:
            return SafetyCheck(False, f"in-hand slip {state.in_hand_slip_mm:.1f} mm > {self.max_in_hand_slip_mm} mm")
        return SafetyCheck(True)


class ExpertContext:
    """What an expert may read, and the last action it sent.

    ``touch()``: what the pads feel now (``scene.touch``). ``seen(name)``: an object's pose as a camera
    would estimate it (ground truth plus the layout's estimation error, drawn from the seed: experts must
    correct from touch what vision gets wrong). ``target``: the last action (8,); primitives start from it.
    ``memory``: what the expert decided (classes, corrections), recorded with the episode.
    """

    def __init__(self, session: Any, rng: np.random.Generator) -> None:
        self._session = session
        self.rng = rng
        self.dt_s = 1.0 / session.config.rate_hz  # one policy step, s
        # one policy step in steps of the tasks' default 50 Hz (1 at 50 Hz, 2 at 25 Hz): experts whose feedback
        # is stated per 20 ms step scale it by this, so that they keep their timing at any rate
        self.step_scale = self.dt_s / (1.0 / TaskConfig.rate_hz)
        self.layout: dict[str, Any] = session.layout
        self.target = session.last_action.copy()
        self.memory: dict[str, Any] = {"corrections": []}
        self.corrections_enabled = True  # False: the expert skips its corrections (to measure their worth)

    def touch(self) -> dict[str, TouchReading]:
        return self._session.sim.touch()

    def pad_forces(self) -> dict[str, PadForce]:
        """Per pad, the summed contact force on the gel now (``scene.pad_forces``: normal and shear, N)."""
        sim = self._session.sim
        return pad_forces(sim.model, sim.data)

    def indentation_mm(self) -> dict[str, float]:
        """Per pad, the deepest overlap with the object now, mm (>= 0; from MuJoCo's narrow phase)."""
        return {pad: max(0.0, -gap) for pad, gap in self._session.sim.gap_mm().items()}

    def gap_mm(self) -> dict[str, float]:
        return self._session.sim.gap_mm()

    def opening_m(self) -> float:
        return self._session.sim.opening_m

    def ee_pose(self) -> np.ndarray:
        return self._session.sim.ee_pose()

    def object_pose(self, name: str) -> np.ndarray:
        """Ground truth: for what a camera sees at this precision (positions to about a centimetre)."""
        return self._session.sim.object_pose(name)

    def step(self, primitive: str, action: np.ndarray) -> Step:
        """Record ``action`` as the new target and wrap it as a ``Step``."""
        self.target = np.asarray(action, float).copy()
        return Step(self.target.copy(), primitive)

    def correction(self, what: str, signal: str, **values: Any) -> None:
        """Note a correction: what was corrected, the signal that triggered it, and its numbers."""
        self.memory["corrections"].append({"what": what, "signal": signal, "step": self._session.steps,
                                           **{k: float(v) if isinstance(v, (int, float, np.floating)) else v
                                              for k, v in values.items()}})


def yaw_quat(yaw_rad: float) -> np.ndarray:
    """Top-down gripper orientation (fingers down, closing along the rotated world x) turned by ``yaw_rad``."""
    return np.array([math.cos(yaw_rad / 2), 0.0, 0.0, math.sin(yaw_rad / 2)])


__all__ = ["EVAL_SEED_BASE", "ExpertContext", "SafetyCheck", "Step", "Task", "TaskConfig", "TaskState", "time_limited_steps",
           "yaw_quat"]
