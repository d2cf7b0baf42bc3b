"""``TaskSession``: one task, stepped by a policy one action at a time, with success and safety per step.

``reset(seed)`` draws the layout from the seed, builds the scene, runs the task's set-up (not recorded:
the gripper is placed at the task's start pose and the scene settles) and records frame 0 when recording.
``step(action)`` reaches the absolute target by interpolating from the previous one over the step's
control ticks, then reads the state: success, safety, and (when recording) a frame. The Gymnasium
environment, the expert collector and ``evaluate`` all run on this class, so a recorded episode's actions,
replayed from its seed, give the same rollout.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from univtac_data.generators.scene.geometry import quat_to_mat, slerp
from univtac_data.generators.scene.gripper import FINGER_TRAVEL_M, MAX_OPENING_M, MIN_OPENING_M, PADS, opening_to_finger_pos
from univtac_data.generators.scene.sim import GripperSim, SimConfig
from univtac_data.generators.scene.threads import one_blas_thread
from univtac_data.generators.tasks.base import SafetyCheck, Task, TaskConfig, TaskState
from univtac_data.schema.sensors import get_sensor

SETTLE_S = 0.2  # set-up: the scene settles this long before the policy's first step (not recorded)
GRIP_CONTACT_MM = 0.05  # both pads overlap an object by at least this: it is held (in-hand slip is measured)


@dataclass(frozen=True)
class ActionBounds:
    """The action space, world frame: workspace box (m), quaternion components, opening (m)."""

    low: np.ndarray
    high: np.ndarray

    @staticmethod
    def default() -> ActionBounds:
        low = np.array([-0.5, -0.5, 0.0, -1, -1, -1, -1, 0.0], np.float32)
        high = np.array([0.5, 0.5, 0.6, 1, 1, 1, 1, MAX_OPENING_M], np.float32)
        return ActionBounds(low, high)

    def check(self, action: np.ndarray) -> np.ndarray:
        """The action as float64 (8,), or a ValueError that says what is wrong with it."""
        a = np.asarray(action, dtype=np.float64)
        if a.shape != (8,):
            raise ValueError(f"an action is 8 numbers (x, y, z m; qw, qx, qy, qz; width m), got shape {a.shape}")
        if not np.isfinite(a).all():
            raise ValueError(f"action has a non-finite value: {a.tolist()}")
        if np.linalg.norm(a[3:7]) < 1e-6:
            raise ValueError("action quaternion has zero length")
        return a


class TaskSession:
    """A task in a running scene: owns the ``GripperSim``, the last action, and per-step success and safety."""

    def __init__(self, task: Task, *, record: bool = False) -> None:
        self.task = task
        self.config: TaskConfig = task.config
        self.record = record
        self.bounds = ActionBounds.default()
        self.sim: GripperSim | None = None  # type: ignore[assignment]
        self.layout: dict[str, Any] = {}
        self.seed = 0
        self.steps = 0
        self.last_action = np.zeros(8)
        self.actions: list[np.ndarray] = []
        self.primitives: list[int] = []
        self.safety_log: list[SafetyCheck] = []
        self.max_indentation_mm = 0.0
        self.max_in_hand_slip_mm = 0.0
        self._initial: dict[str, np.ndarray] = {}
        self._grip_anchor: tuple[str, np.ndarray] | None = None  # held object, its position in the hand at grip

    # --- life cycle --------------------------------------------------------------------------------
    def reset(self, seed: int) -> TaskState:
        """A new episode from ``seed``: layout, scene, set-up; frame 0 is recorded when recording."""
        with one_blas_thread():
            return self._reset(seed)

    def _reset(self, seed: int) -> TaskState:
        if self.sim is not None:
            self.sim.close()
        self.seed = int(seed)
        rng = np.random.default_rng(self.seed)
        self.rng = rng
        self.layout = self.task.sample_layout(rng)
        model = mujoco.MjModel.from_xml_string(self.task.scene_xml(self.layout))
        model.opt.timestep = self.config.timestep_s
        sim_config = SimConfig(record_rate_hz=None, control_period_steps=self.config.control_period_steps,
                               contact_method=self.config.contact_method, frame_capacity=self.task.step_limit + 1)
        self.sim = GripperSim(model, get_sensor(self.config.sensor), {p: self.task.pad_geoms() for p in PADS},
                              self.task.objects(), self.task.primitive_names, sim_config,
                              cameras=self.task.cameras(), textures=self.task.textures(self.layout))
        start = np.asarray(self.task.start_pose(self.layout), float)
        self._place_gripper(start)
        for _ in range(round(SETTLE_S / (self.config.timestep_s * self.config.control_period_steps))):
            self.sim.tick()
        self.steps = 0
        self.last_action = start.copy()
        self.actions, self.primitives, self.safety_log = [], [], []
        self.max_indentation_mm = self.max_in_hand_slip_mm = 0.0
        self._grip_anchor = None
        self._initial = {name: self.sim.object_pose(name) for name in self.task.objects()}
        if self.record:
            self.sim.start_recording()
        state = self.state()
        self._after_step(state, primitive=-1)
        return state

    def _place_gripper(self, start: np.ndarray) -> None:
        """Put the welded gripper and its target at ``start`` (the set-up's end), fingers at its opening."""
        sim = self.sim
        assert sim is not None
        sim.ee_setpoint[:] = start[:7]
        sim.data.mocap_pos[0], sim.data.mocap_quat[0] = start[:3], start[3:7]
        joint = sim.model.joint("gripper_free")
        sim.data.qpos[joint.qposadr[0]: joint.qposadr[0] + 7] = start[:7]
        finger = opening_to_finger_pos(float(start[7]))
        for pad in PADS:
            sim.data.qpos[sim.model.joint(f"{pad}_slide").qposadr[0]] = finger
        sim.finger_setpoints_m[:] = finger
        mujoco.mj_forward(sim.model, sim.data)

    def close(self) -> None:
        if self.sim is not None:
            self.sim.close()
            self.sim = None

    # --- stepping ----------------------------------------------------------------------------------
    def step(self, action: np.ndarray, primitive: str | None = None) -> TaskState:
        """Apply one absolute action (8,) for one policy step; returns the state after it."""
        with one_blas_thread():
            return self._step(action, primitive)

    def _step(self, action: np.ndarray, primitive: str | None) -> TaskState:
        sim = self.sim
        if sim is None:
            raise RuntimeError("step() before reset()")
        target = self.bounds.check(action)
        target[3:7] /= np.linalg.norm(target[3:7])
        target[:3] = np.clip(target[:3], self.bounds.low[:3], self.bounds.high[:3])
        target[7] = float(np.clip(target[7], MIN_OPENING_M, MAX_OPENING_M))
        start = self.last_action
        if np.dot(start[3:7], target[3:7]) < 0:
            target[3:7] = -target[3:7]
        if primitive is not None:
            sim.set_primitive(primitive)
        ticks = self.config.ticks_per_step
        for k in range(1, ticks + 1):
            t = k / ticks
            sim.ee_setpoint[:3] = start[:3] + (target[:3] - start[:3]) * t
            sim.ee_setpoint[3:] = slerp(start[3:7], target[3:7], t)
            sim.finger_setpoints_m[:] = min(FINGER_TRAVEL_M, opening_to_finger_pos(start[7] + (target[7] - start[7]) * t))
            sim.tick()
        self.last_action = target
        self.actions.append(target.copy())
        self.steps += 1
        state = self.state()
        self._after_step(state, sim.primitive)
        return state

    def _after_step(self, state: TaskState, primitive: int) -> None:
        self.max_indentation_mm = max(self.max_indentation_mm, state.indentation_mm)
        self.max_in_hand_slip_mm = max(self.max_in_hand_slip_mm, state.in_hand_slip_mm)
        self.safety_log.append(self.task.safety(state))
        self.primitives.append(primitive)
        if self.record:
            self.sim.record_frame()

    # --- reading -----------------------------------------------------------------------------------
    def state(self, memory: dict[str, Any] | None = None) -> TaskState:
        sim = self.sim
        assert sim is not None
        per_object = sim.object_gaps_mm()
        gaps = {pad: min(pads[pad] for pads in per_object.values()) for pad in PADS}
        ee = sim.ee_pose()
        objects = {name: sim.object_pose(name) for name in self.task.objects()}
        # the held object: the one both pads overlap
        held = next((name for name, pads in per_object.items() if all(-g >= GRIP_CONTACT_MM for g in pads.values())),
                    None)
        if held is not None:
            in_hand = quat_to_mat(ee[3:]).T @ (objects[held][:3] - ee[:3])
            if self._grip_anchor is None or self._grip_anchor[0] != held:
                self._grip_anchor = (held, in_hand)
            slip = float(np.linalg.norm(in_hand - self._grip_anchor[1])) * 1000.0
        else:
            self._grip_anchor, slip = None, 0.0
        return TaskState(step=self.steps, objects=objects, initial_objects=self._initial, ee_pose=ee,
                         opening_m=sim.opening_m, indentation_mm=max(0.0, -min(gaps.values())),
                         in_hand_slip_mm=slip, memory=memory or {}, layout=self.layout)

    @property
    def safe(self) -> bool:
        return all(check.ok for check in self.safety_log)

    def first_violation(self) -> str | None:
        return next((c.reason for c in self.safety_log if not c.ok), None)
