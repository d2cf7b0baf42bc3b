"""Lift Bottle: stand up a bottle that lies on the table with its base towards a wall, and square it on the wall.

Description
    A bottle lies on its side, its base a few centimetres from a wall. The gripper starts open above it,
    from a camera estimate and a set-up whose hand is pitched about the closing axis by up to 15 deg (UniVTAC's
    pitch noise), so the bottle sits in the hand at an angle the camera cannot see once the hand covers it.
    The expert grasps the body across, lifts it 6 mm and turns it about its base in four steps to the hand pose
    that would hold a squarely grasped bottle upright. The bottle then stands off vertical by the grasp's
    angle, which only the pads see: **if the contact strips say it is not upright, the expert turns it
    further by the angle they show, sets it down and pushes its base against the wall** (the base's distance
    to the wall comes from the same in-hand pose), lets go and backs away.
Objects (procedural; plausible real sizes)
    ``bottle``: ``bottle.py``, a half-full 50 cl water bottle 6.5 cm across and 21.5 cm tall, 0.275 kg; its
    origin on the axis 8 cm from the base, where the expert grips (3.5 cm from the centre of mass, above the
    water: the turn loads the grasp little). Wall (fixed): a box 4 cm thick, 40 cm
    wide, 20 cm high, its face at x = 0.12 m. Ground: a plane, friction 0.8.
Randomisation (seeded)
    base face U(5, 7) cm from the wall (the turn about the base sweeps its rim 3.25 cm towards the wall), y
    U(-5, 5) cm, yaw U(-10, 10) deg (UniVTAC's +-1 cm, +-5 cm, +-10 deg); the camera's estimate of the grip
    point is off by U(-4, 4) mm along the bottle (the ends of a lying bottle are seen less well than its
    sides: across it, the fingers close centred, and a bottle one pad pushes across the table rolls on the gel)
    and of the yaw by U(-2, 2) deg; the set-up's pitch U(3, 15) deg.
Expert (closed loop; the signal behind each correction is recorded in ``memory['corrections']``)
    descend to the axis height, tactile grasp to 0.9 mm (0.36 mm on the GF225 and Xense WS: Put Bottle in
    Shelf's ``grasp_law``; the kit's 0.5 mm lets the bottle twist in the hand by a millimetre of gel slip
    while it turns); read the in-hand
    angle from the strips (``bottle.in_hand_from_touch``); lift 6 mm; turn the hand about the closing axis
    through the seen base centre in 4 steps of a quarter each, 0.1 s apart, to the hand pose that would hold
    a square grasp upright. **Upright from touch**: the strips' angle with the hand's orientation gives the
    bottle's tilt; if it exceeds 1.5 deg, turn further by it about the base (recorded: tilt, deg); then
    **push to the wall**: the base centre from the in-hand pose (strip centroids and angle, 8 cm down the
    axis); carry it towards the wall until its rim is 2 mm from the wall's face, lower it to 2 mm above the
    table (recorded: the push and the base height, mm). Open (the bottle drops onto its base), back away 8 cm.
Success
    axis upright (axis . z > 0.99, 8.1 deg), base on the table (base centre below 1 cm), base centre within
    5 cm of the wall's face (3.25 cm when the rim touches it).
Safety (per step; a violation makes the rollout invalid)
    deepest pad indentation <= the sensor's safe limit (1.5 mm Mini, 0.8 mm GF225 / Xense WS); the bottle moves
    at most 5 mm in the gripper frame once both pads grip it. The validators' gel-slip rule (1 mm while held)
    holds on every seed checked (1-4, 6, 13, 20-23, 42-51).
Step limit
    500 policy steps (10 s at 50 Hz).
Version history
    v0: first version.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import numpy as np

from univtac_data.generators.scene.contact_pairs import TASK_OPTION_XML, PadContact
from univtac_data.generators.scene.geometry import quat_from_axis_angle, quat_mul, quat_to_mat
from univtac_data.generators.scene.gripper import GripperParams, gripper_actuator_xml, gripper_body_xml, gripper_equality_xml
from univtac_data.generators.scene.stage import STAGE_ASSETS_XML, stage_xml
from univtac_data.generators.tasks.base import ExpertContext, Step, Task, TaskState, yaw_quat
from univtac_data.generators.tasks.bottle import BODY_RADIUS_M, bottle_xml, in_hand_from_touch, tilt_rad
from univtac_data.generators.tasks.motions import close_until, move_to, open_to, rotate_about, wait
from univtac_data.generators.tasks.put_bottle_in_shelf import grasp_law

GRIP_FROM_BASE_M = 0.08  # where the expert grips, along the axis from the base (the bottle's origin)
WALL_X_M = 0.12  # the wall's face, world x
WALL_HALF_M = (0.02, 0.20, 0.10)
GAP_RANGE_M = (0.05, 0.07)  # base face to the wall: 5 cm is the success limit for the base centre
Y_NOISE_M = 0.05
YAW_NOISE_RAD = math.radians(10.0)
SEEN_ERROR_M = 0.004
SEEN_YAW_ERROR_RAD = math.radians(2.0)
PITCH_RANGE_RAD = (math.radians(3.0), math.radians(15.0))
OPEN_MARGIN_M = 0.012
# let go quickly: a bottle let go slowly starts to fall while the pads still touch it, a gel slip of a millimetre
RELEASE_SPEED_M_S = 0.3
LIFT_M = 0.006
TURN_STEPS = 4
TURN_PAUSE_S = 0.1
UPRIGHT_TOLERANCE_RAD = math.radians(1.5)
WALL_GAP_M = 0.002  # the rim stops this short of the wall: the base position from touch is good to a few mm
SET_DOWN_CLEARANCE_M = 0.002  # let go this high: the pads' estimate of the base height is good to about 1 mm
BACK_AWAY_M = 0.08
SUCCESS_AXIS_Z = 0.99
SUCCESS_WALL_M = 0.05
SUCCESS_BASE_Z_M = 0.01


class LiftBottle(Task):
    __doc__ = __doc__
    name = "lift_bottle"
    gym_id = "univtac/LiftBottle-v0"
    max_steps = 500
    primitive_names = ["move", "grasp", "lift", "rotate", "hold", "square", "push", "release"]

    # --- scene -------------------------------------------------------------------------------------
    def sample_layout(self, rng: np.random.Generator) -> dict[str, Any]:
        return {"gap_m": float(rng.uniform(*GAP_RANGE_M)), "y_m": float(rng.uniform(-Y_NOISE_M, Y_NOISE_M)),
                "yaw_rad": float(rng.uniform(-YAW_NOISE_RAD, YAW_NOISE_RAD)),
                "seen_along_error_m": float(rng.uniform(-SEEN_ERROR_M, SEEN_ERROR_M)),
                "seen_yaw_error_rad": float(rng.uniform(-SEEN_YAW_ERROR_RAD, SEEN_YAW_ERROR_RAD)),
                "pitch_rad": float(rng.uniform(*PITCH_RANGE_RAD))}

    def objects(self) -> list[str]:
        return ["bottle"]

    @staticmethod
    def axis_lying(yaw: float) -> np.ndarray:
        """(3,) the lying bottle's axis, base to cap: away from the wall (-x) turned by ``yaw``."""
        return np.array([-math.cos(yaw), -math.sin(yaw), 0.0])

    @staticmethod
    def base_centre(layout: dict[str, Any]) -> np.ndarray:
        """(3,) m world: the lying bottle's base centre."""
        base = np.array([WALL_X_M - layout["gap_m"], layout["y_m"], BODY_RADIUS_M])
        # the gap is the base face's nearest point to the wall; a yawed base reaches r sin|yaw| further
        base[0] -= BODY_RADIUS_M * abs(math.sin(layout["yaw_rad"]))
        return base

    def scene_xml(self, layout: dict[str, Any]) -> str:
        axis = self.axis_lying(layout["yaw_rad"])
        origin = self.base_centre(layout) + axis * GRIP_FROM_BASE_M
        origin[2] += 0.0005
        # local +z along the lying axis: turn +z to -x (about +y by -90 deg), then yaw about the vertical
        quat = quat_mul(quat_from_axis_angle((0, 0, 1), layout["yaw_rad"]), quat_from_axis_angle((0, 1, 0), -math.pi / 2))
        hx, hy, hz = WALL_HALF_M
        params = GripperParams(mount="welded")
        return f"""<mujoco model="lift_bottle">
  <compiler angle="radian" autolimits="true"/>
  {TASK_OPTION_XML}
  <asset>{STAGE_ASSETS_XML}
  </asset>
  <worldbody>{stage_xml(head_eye=(-0.05, 0.5, 0.35), head_target=(0.02, 0.0, 0.08))}
    <geom name="wall" type="box" pos="{WALL_X_M + hx} 0 {hz}" size="{hx} {hy} {hz}" rgba="0.8 0.78 0.72 1"
          friction="0.8 0.005 0.0001"/>{bottle_xml("bottle", origin, quat, GRIP_FROM_BASE_M)}
    {gripper_body_xml(self.profile, params, (0.0, 0.0, 0.4))}
  </worldbody>
  <contact>{PadContact().pair_xml("bottle")}</contact>
  <actuator>{gripper_actuator_xml(params)}</actuator>
  <equality>{gripper_equality_xml(params)}</equality>
</mujoco>"""

    # --- what the camera estimates -----------------------------------------------------------------
    def seen(self, layout: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        """The camera's estimate: grip point (3,) m and the lying axis (3,), base to cap."""
        axis = self.axis_lying(layout["yaw_rad"] + layout["seen_yaw_error_rad"])
        true_axis = self.axis_lying(layout["yaw_rad"])
        grip = self.base_centre(layout) + true_axis * (GRIP_FROM_BASE_M + layout["seen_along_error_m"])
        return grip, axis

    @staticmethod
    def square_quat(axis: np.ndarray) -> np.ndarray:
        """Top-down, the fingers closing across ``axis`` (gripper y along the axis)."""
        return yaw_quat(math.atan2(axis[1], axis[0]) - math.pi / 2)

    def start_pose(self, layout: dict[str, Any]) -> np.ndarray:
        grip, axis = self.seen(layout)
        square = self.square_quat(axis)
        # the set-up's pitch about the closing axis (gripper x)
        quat = quat_mul(square, quat_from_axis_angle((1, 0, 0), layout["pitch_rad"]))
        return np.array([grip[0], grip[1], grip[2] + 0.06, *quat, 2 * BODY_RADIUS_M + OPEN_MARGIN_M])

    # --- behaviour ---------------------------------------------------------------------------------
    def expert(self, ctx: ExpertContext) -> Iterator[Step]:
        layout = ctx.layout
        grip, axis = self.seen(layout)
        yield from move_to(ctx, grip, speed_m_s=0.2)
        yield from close_until(ctx, grasp_law(self.profile))
        held = in_hand_from_touch(**ctx.touch())
        ctx.memory["in_hand_angle_deg"] = math.degrees(held.angle_rad)
        yield from move_to(ctx, ctx.target[:3] + [0.0, 0.0, LIFT_M], speed_m_s=0.05, primitive="lift")
        # the turn that brings the cap up: about axis x z (horizontal, across the bottle), through the base
        turn_axis = np.cross(axis, [0.0, 0.0, 1.0])
        turn_axis /= np.linalg.norm(turn_axis)
        base = grip - axis * GRIP_FROM_BASE_M + [0.0, 0.0, LIFT_M]
        up_quat = quat_mul(quat_from_axis_angle(turn_axis, math.pi / 2), self.square_quat(axis))
        angle = self._angle_about(ctx.target[3:7], up_quat, turn_axis)
        for _ in range(TURN_STEPS):
            yield from rotate_about(ctx, turn_axis, angle / TURN_STEPS, base, turn_rad_s=1.5)
            yield from wait(ctx, TURN_PAUSE_S)
        if not ctx.corrections_enabled:
            yield from self._let_go(ctx)
            return
        yield from self._square(ctx, turn_axis, base)
        yield from self._push_to_wall(ctx)
        yield from self._let_go(ctx)

    @staticmethod
    def _angle_about(start: np.ndarray, goal: np.ndarray, axis: np.ndarray) -> float:
        """The signed angle (rad) about ``axis`` that turns orientation ``start`` into ``goal`` (both
        differ by a turn about it)."""
        rel = quat_mul(goal, np.array([start[0], -start[1], -start[2], -start[3]]))
        angle = 2 * math.atan2(float(np.dot(rel[1:], axis)), float(rel[0]))
        return (angle + math.pi) % (2 * math.pi) - math.pi

    def _tilt(self, ctx: ExpertContext, turn_axis: np.ndarray) -> tuple[float, np.ndarray]:
        """The bottle's signed tilt about ``turn_axis`` (rad; positive: turn further) and its axis (3,), from touch."""
        pose = in_hand_from_touch(**ctx.touch())
        axis = pose.axis_world(ctx.ee_pose()[3:])
        # the turn about turn_axis that brings the axis to +z
        signed = math.atan2(float(np.dot(np.cross(axis, [0.0, 0.0, 1.0]), turn_axis)), float(axis[2]))
        return signed, axis

    def _square(self, ctx: ExpertContext, turn_axis: np.ndarray, base: np.ndarray) -> Iterator[Step]:
        tilt, axis = self._tilt(ctx, turn_axis)
        if abs(tilt) <= UPRIGHT_TOLERANCE_RAD:
            return
        ctx.correction("turn upright", "contact strip angle on both pads with the hand's orientation: bottle tilt",
                       tilt_deg=math.degrees(tilt), total_tilt_deg=math.degrees(tilt_rad(axis)))
        yield from rotate_about(ctx, turn_axis, tilt, base, turn_rad_s=1.0, primitive="square")
        yield from wait(ctx, TURN_PAUSE_S)

    def _push_to_wall(self, ctx: ExpertContext) -> Iterator[Step]:
        """Set the base down and push its rim against the wall, from where the pads say the base is."""
        pose = in_hand_from_touch(**ctx.touch())
        ee = ctx.ee_pose()
        axis = pose.axis_world(ee[3:])
        base = pose.grip_point_world(ee) - axis * GRIP_FROM_BASE_M
        push = WALL_X_M - WALL_GAP_M - (base[0] + BODY_RADIUS_M)
        down = base[2] - SET_DOWN_CLEARANCE_M
        ctx.correction("push to the wall", "contact strip centroids and angle on both pads: base position",
                       push_mm=push * 1000, base_height_mm=base[2] * 1000)
        # to the wall in the air (dragging the base on the table would turn the bottle in the hand), then down
        yield from move_to(ctx, ctx.target[:3] + [push, 0.0, 0.0], speed_m_s=0.08, primitive="push")
        yield from move_to(ctx, ctx.target[:3] - [0.0, 0.0, down], speed_m_s=0.05, primitive="push")
        yield from wait(ctx, TURN_PAUSE_S)

    def _let_go(self, ctx: ExpertContext) -> Iterator[Step]:
        yield from open_to(ctx, ctx.target[7] + OPEN_MARGIN_M, speed_m_s=RELEASE_SPEED_M_S)
        fingers = -quat_to_mat(ctx.target[3:7])[:, 2]
        yield from move_to(ctx, ctx.target[:3] + fingers * BACK_AWAY_M, speed_m_s=0.15)
        yield from wait(ctx, 0.2)

    # --- checks ------------------------------------------------------------------------------------
    @staticmethod
    def base_of(pose: np.ndarray) -> np.ndarray:
        """(3,) m world: the base centre of a bottle at ``pose``."""
        return pose[:3] - quat_to_mat(pose[3:])[:, 2] * GRIP_FROM_BASE_M

    def success(self, state: TaskState) -> bool:
        pose = state.objects["bottle"]
        base = self.base_of(pose)
        return bool(quat_to_mat(pose[3:])[2, 2] > SUCCESS_AXIS_Z and base[2] < SUCCESS_BASE_Z_M
                    and WALL_X_M - base[0] < SUCCESS_WALL_M)


__all__ = ["LiftBottle"]
