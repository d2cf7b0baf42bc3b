"""Put Bottle in Shelf: lift an upright bottle, let it swing upright in a loosened grasp, set it in a shelf's cavity.

Description
    A bottle stands on the table before a low shelf whose top has a square cavity. The expert grasps the
    bottle from above across its body, lifts it, tilts the hand about the closing axis (the reference's
    in-hand reorientation: a bottle picked at an angle must be brought back to vertical without setting it
    down), loosens the grasp so that the bottle pivots between the pads under gravity until the contact strips
    say it hangs upright, grips again, carries it over the cavity with the in-hand pose the pads read, lowers
    it in and lets go.
Objects (procedural; plausible real sizes)
    ``bottle``: ``bottle.py``, a half-full 50 cl water bottle 6.5 cm across and 21.5 cm tall, 0.275 kg, its
    centre of mass 4.5 cm above the base; its origin on the axis 13 cm above the base, where the expert grips
    (the line between the pads, which the bottle turns about; 8.5 cm above the centre of mass, the lever
    gravity turns it with). Shelf (fixed): a block 14 x 24 cm, 8 cm high, with a cavity on top: a square 8.5 x 8.5 cm
    pocket with a 2 cm rim (10 mm clearance around the bottle's body on each side). Ground: a plane,
    friction 0.8.
Randomisation (seeded)
    shelf centre x 0.12 + U(-5, 5) cm, y 0; bottle at x -0.10 m, y U(-3, 3) cm; the camera's estimate of the
    bottle's centre is off by U(-4, 4) mm in x and y; the grip height by U(-3, 3) mm; the lift U(15, 20) cm;
    the hand's tilt 60 + U(0, 11.5) deg (UniVTAC's numbers).
Expert (closed loop; the signal behind each correction is recorded in ``memory['corrections']``)
    descend over the seen bottle (top-down, fingers closing along world y); tactile grasp to 0.9 mm (0.36 mm on
    the GF225 and Xense WS: ``grip_depth_factor``); lift while tilting the hand about the closing axis.
    **Swing upright (controlled slip)**, in 20 ms steps (at another rate the per-step numbers below are scaled
    to the same speeds and times): each step, the pads' contact strips give the bottle's axis in the
    gripper frame (``bottle.in_hand_from_touch``) and, with the hand's orientation, its tilt from vertical; while
    it turns by less than 6 deg a step, open by 0.2 mm while the shallower pad presses more than 0.3 mm and by
    0.15 mm below that; when it turns faster than 12 deg a step or the press falls below 0.09 mm (the weight
    must still hang on friction), close by 0.15 mm; once the tilt is under 5 deg, or under 15 deg and turning
    less than 0.3 deg a step, or it swung through upright, or it turns by less than 0.15 deg a step for 8 steps
    at the loosest press, grip again to 0.8 times the kit's grasp depth (0.4 mm on the Mini). Quick, because
    a loose bottle slides down the pads for as long as it is loose (the more, the longer the contact strip).
    Recorded: the tilt before and after (from touch), the opening given up (mm) and the steps.
    **Place from the in-hand pose**: where the strips cross the pads (their centroids, with the strip angle)
    gives the bottle axis's offset from the gripper centre; the hand is aimed so that the axis, not the hand,
    is over the cavity centre (recorded: the offset, mm, and the tilt). Lower the base to 3 mm above the cavity
    floor, open, lift away. A bottle that still leans by up to 20 deg stands up in the cavity once let go (its
    centre of mass 4.5 cm up a base 3.25 cm in radius tips back below 36 deg).
Success
    bottle base centre within 2 cm (xy) of the cavity centre, base less than 1.5 cm above the cavity floor,
    axis tilted less than 15 deg from vertical.
Safety (per step; a violation makes the rollout invalid)
    deepest pad indentation <= the sensor's safe limit (1.5 mm Mini, 0.8 mm GF225 / Xense WS); the bottle's
    origin moves at most 10 mm in the gripper frame once both pads grip it. The swing is a turn of some
    55 deg about the pads' centre line, which the origin misses by up to 5 mm (the camera's error along the
    pads, the grip height's): that alone moves it up to 4.6 mm; the bottle also sinks along the pads by up
    to 3 mm while the grasp is loose (seeds 0-29: at most 6.9 mm in all).
Physics (``benchmarks/pivot_stability.py``; docs/tasks.md)
    the kit's scene options (1 ms, implicitfast, elliptic cone, 4 noslip iterations, impratio 1): the pivot
    sweep finds the swing stable and converged there (0.25 and 0.5 ms turn it the same), so no override.
Step limit
    300 policy steps (6 s at 50 Hz).
Version history
    v0: first version (the environment). Its expert since: the thinner grip on the GF225 and Xense WS; the
    quicker swing (0.15 mm and 6 deg a step, was 0.03 mm and 1.5 deg) with its exit under 15 deg.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import replace
from typing import Any

import numpy as np

from univtac_data.generators.scene.contact_pairs import TASK_OPTION_XML, PadContact
from univtac_data.generators.scene.geometry import quat_from_axis_angle, quat_mul, quat_to_mat
from univtac_data.generators.scene.gripper import GripperParams, gripper_actuator_xml, gripper_body_xml, gripper_equality_xml
from univtac_data.generators.scene.stage import STAGE_ASSETS_XML, stage_xml
from univtac_data.generators.tasks.base import ExpertContext, Step, Task, TaskState, yaw_quat
from univtac_data.generators.tasks.bottle import (
    BODY_RADIUS_M,
    HEIGHT_M,
    InHandPose,
    bottle_xml,
    in_hand_from_touch,
    tilt_rad,
)
from univtac_data.schema.sensors import SensorProfile
from univtac_data.generators.tasks.motions import GraspLaw, close_until, grasp_depth_mm, move_to, open_to, wait

GRIP_HEIGHT_M = 0.13  # where the expert grips, above the base (the bottle's origin)
SHELF_HALF_M = (0.07, 0.12, 0.04)  # block half sizes x, y, z: its top is 8 cm up
CAVITY_HALF_M = 0.0425  # half the inner width of the square pocket
RIM_HEIGHT_M = 0.02
RIM_THICKNESS_M = 0.01
SHELF_X_M = 0.12
SHELF_NOISE_M = 0.05
BOTTLE_X_M = -0.10
BOTTLE_Y_NOISE_M = 0.03
SEEN_ERROR_M = 0.004
GRIP_HEIGHT_NOISE_M = 0.003
LIFT_RANGE_M = (0.15, 0.20)
TILT_RANGE_RAD = (math.radians(60.0), math.radians(71.5))
OPEN_MARGIN_M = 0.012
# let go quickly: a bottle let go slowly starts to fall while the pads still touch it, a gel slip of a millimetre
RELEASE_SPEED_M_S = 0.3
# the kit's grasp depth (0.5 mm on a GelSight Mini) holds a can; a bottle tilted 70 deg with its water 8.5 cm
# below the pads turns in it (0.2 N m against the strips' torsional friction): 0.9 mm holds it (pivot_stability.py:
# "tight"), still 0.6 mm inside the Mini's 1.5 mm safe limit
GRIP_DEPTH_FACTOR = 1.8
# on the gels safe to 0.8 mm (GF225, Xense WS) the same factor, 0.54 mm, let the bottle's weight press one pad
# to 0.80-1.04 mm, 0.26-0.50 mm past the grip: a quarter of Lift Bottle's and three fifths of
# Put Bottle's held-out seeds were unsafe on the GF225 (expert_heldout.py); 0.36 mm holds the bottle within it
THIN_GEL_GRIP_FACTOR = 1.2
REGRIP_FACTOR = 0.8  # of the kit's grasp depth, once the bottle hangs upright
# the swing (controlled slip), per 20 ms policy step (50 Hz); at other rates scaled by ctx.step_scale
PIVOT_DONE_RAD = math.radians(5.0)
# under this tilt and hardly turning, grip again: a bottle leaning this much still stands up in the cavity, and
# every step at the loosest press slides it further down the pads
PIVOT_NEAR_RAD = math.radians(15.0)
PIVOT_MOVING_RAD = math.radians(0.3)  # turning at least this much a step: leave the grip as it is
PIVOT_FAST_STEP_M = 0.0002  # opening change a step while the pads still press deeper than PIVOT_FAST_ABOVE_MM, m
PIVOT_FAST_ABOVE_MM = 0.3
# a quick swing: the loose bottle slides down the pads for as long as the press is light, and the more the longer
# the contact strip resists the turn (the GF225's 29 mm gel against the Mini's 20.75 mm): at 0.03 mm and 1.5 deg
# a step the GF225's swing moved a bottle a median 8.1 mm in the hand (up to 13.4: 20 of 100 held-out seeds over
# the task's 10 mm), at 0.15 mm and 6 deg 4.0 (up to 7.4; the Mini 3.7 -> 2.0-2.2; expert_heldout.py)
PIVOT_STEP_M = 0.00015  # opening change a step near the press where the bottle turns, m
PIVOT_RATE_RAD = math.radians(6.0)  # wanted turn a step: loosen while slower
PIVOT_FAST_RATE_RAD = math.radians(12.0)  # tighten while faster
PIVOT_MIN_DEPTH_MM = 0.09  # never looser than this: friction must still carry the bottle's weight
PIVOT_STALL_STEPS = 8  # this many steps slower than PIVOT_CREEP_RAD once turned a good way: stopped
PIVOT_CREEP_RAD = math.radians(0.15)
PIVOT_STALL_DEPTH_MM = 0.02
PIVOT_MAX_STEPS = 100
PLACE_CLEARANCE_M = 0.003
SUCCESS_RADIUS_M = 0.02
SUCCESS_HEIGHT_M = 0.015
MAX_TILT_RAD = math.radians(15.0)


def grip_depth_factor(profile: SensorProfile) -> float:
    """How many times the kit's grasp depth the bottle is gripped to: ``GRIP_DEPTH_FACTOR`` on a gel safe to
    1.5 mm, ``THIN_GEL_GRIP_FACTOR`` on the thinner ones."""
    return GRIP_DEPTH_FACTOR if profile.safe_indentation_mm >= 1.5 else THIN_GEL_GRIP_FACTOR


def grasp_law(profile: SensorProfile) -> GraspLaw:
    """The kit's tactile grasp to ``grip_depth_factor`` times its depth, with a finger lead of 4 mm (the kit's
    1.5 mm stalls short of 0.5 mm on this bottle: the servo's squeeze is its lead times 20 N/mm) and a 20 mm/s
    slow phase that pushes a bottle one pad reached first across to the other (the camera's centre is off by up
    to 4 mm) in a third of UniVTAC's time."""
    return GraspLaw(threshold_mm=grip_depth_factor(profile) * grasp_depth_mm(profile), v_slow_m_s=0.02,
                    max_lead_m=0.004)


class PutBottleInShelf(Task):
    __doc__ = __doc__
    name = "put_bottle_in_shelf"
    gym_id = "univtac/PutBottleInShelf-v0"
    max_steps = 300
    primitive_names = ["move", "grasp", "tilt", "swing", "regrasp", "carry", "place", "release", "hold"]
    max_in_hand_slip_mm = 10.0
    controlled_slip_primitives = ("swing",)

    # --- scene -------------------------------------------------------------------------------------
    def sample_layout(self, rng: np.random.Generator) -> dict[str, Any]:
        return {"shelf_x_m": SHELF_X_M + float(rng.uniform(-SHELF_NOISE_M, SHELF_NOISE_M)),
                "bottle_xy_m": [BOTTLE_X_M, float(rng.uniform(-BOTTLE_Y_NOISE_M, BOTTLE_Y_NOISE_M))],
                "seen_error_m": [float(v) for v in rng.uniform(-SEEN_ERROR_M, SEEN_ERROR_M, 2)],
                "grip_height_error_m": float(rng.uniform(-GRIP_HEIGHT_NOISE_M, GRIP_HEIGHT_NOISE_M)),
                "lift_m": float(rng.uniform(*LIFT_RANGE_M)),
                "tilt_rad": float(rng.uniform(*TILT_RANGE_RAD))}

    def objects(self) -> list[str]:
        return ["bottle"]

    @staticmethod
    def cavity_floor_m() -> float:
        return 2 * SHELF_HALF_M[2]

    @staticmethod
    def cavity_centre(layout: dict[str, Any]) -> np.ndarray:
        """(3,) m world: the centre of the cavity's floor."""
        return np.array([layout["shelf_x_m"], 0.0, 2 * SHELF_HALF_M[2]])

    def _shelf_xml(self, layout: dict[str, Any]) -> str:
        sx, (hx, hy, hz) = layout["shelf_x_m"], SHELF_HALF_M
        top, c, t, h = 2 * hz, CAVITY_HALF_M, RIM_THICKNESS_M / 2, RIM_HEIGHT_M / 2
        rims = [((sx, c + t), (c + 2 * t, t)), ((sx, -c - t), (c + 2 * t, t)),
                ((sx + c + t, 0.0), (t, c)), ((sx - c - t, 0.0), (t, c))]
        geoms = [f'<geom name="shelf" type="box" pos="{sx} 0 {hz}" size="{hx} {hy} {hz}" rgba="0.55 0.4 0.28 1" '
                 f'friction="0.8 0.005 0.0001"/>']
        for k, ((x, y), (ax, ay)) in enumerate(rims):
            geoms.append(f'<geom name="shelf_rim{k}" type="box" pos="{x} {y} {top + h}" size="{ax} {ay} {h}" '
                         f'rgba="0.45 0.32 0.22 1" friction="0.8 0.005 0.0001"/>')
        return "\n    ".join(geoms)

    def scene_xml(self, layout: dict[str, Any]) -> str:
        x, y = layout["bottle_xy_m"]
        params = GripperParams(mount="welded")
        bottle = bottle_xml("bottle", np.array([x, y, GRIP_HEIGHT_M + 0.0005]), np.array([1.0, 0, 0, 0]), GRIP_HEIGHT_M)
        return f"""<mujoco model="put_bottle_in_shelf">
  <compiler angle="radian" autolimits="true"/>
  {TASK_OPTION_XML}
  <asset>{STAGE_ASSETS_XML}
  </asset>
  <worldbody>{stage_xml(head_eye=(0.0, 0.55, 0.42), head_target=(0.02, 0.0, 0.12))}
    {self._shelf_xml(layout)}{bottle}
    {gripper_body_xml(self.profile, params, (0.0, 0.0, 0.4))}
  </worldbody>
  <contact>{PadContact().pair_xml("bottle")}</contact>
  <actuator>{gripper_actuator_xml(params)}</actuator>
  <equality>{gripper_equality_xml(params)}</equality>
</mujoco>"""

    # --- what the camera estimates -----------------------------------------------------------------
    @staticmethod
    def seen_bottle(layout: dict[str, Any]) -> np.ndarray:
        """(3,) m world: the camera's estimate of the point the expert grips (on the axis, at grip height)."""
        x, y = layout["bottle_xy_m"]
        ex, ey = layout["seen_error_m"]
        return np.array([x + ex, y + ey, GRIP_HEIGHT_M + layout["grip_height_error_m"]])

    @staticmethod
    def hand_quat() -> np.ndarray:
        """Top-down, the fingers closing along world y (gripper x = world y)."""
        return yaw_quat(math.pi / 2)

    def start_pose(self, layout: dict[str, Any]) -> np.ndarray:
        grip = self.seen_bottle(layout)
        return np.array([grip[0], grip[1], HEIGHT_M + 0.03, *self.hand_quat(), 2 * BODY_RADIUS_M + OPEN_MARGIN_M])

    # --- behaviour ---------------------------------------------------------------------------------
    def expert(self, ctx: ExpertContext) -> Iterator[Step]:
        layout = ctx.layout
        law = grasp_law(self.profile)
        grip = self.seen_bottle(layout)
        yield from move_to(ctx, grip, speed_m_s=0.35)
        yield from close_until(ctx, law)
        closing_axis = quat_to_mat(ctx.target[3:7])[:, 0]
        tilted = quat_mul(quat_from_axis_angle(closing_axis, layout["tilt_rad"]), ctx.target[3:7])
        yield from move_to(ctx, ctx.target[:3] + [0.0, 0.0, layout["lift_m"]], tilted, speed_m_s=0.40,
                           turn_rad_s=3.0, primitive="tilt")
        if ctx.corrections_enabled:
            yield from self._swing_upright(ctx, law)
        pose = in_hand_from_touch(**ctx.touch())
        yield from self._place(ctx, pose)

    def _tilt_from_touch(self, ctx: ExpertContext) -> tuple[float, InHandPose]:
        pose = in_hand_from_touch(**ctx.touch())
        return tilt_rad(pose.axis_world(ctx.ee_pose()[3:])), pose

    def _swing_upright(self, ctx: ExpertContext, law: GraspLaw) -> Iterator[Step]:
        """Controlled slip: loosen until the bottle turns, keep it turning, grip again once it hangs upright."""
        start, _ = self._tilt_from_touch(ctx)
        start_width = float(ctx.target[7])
        previous, slow, steps = start, 0, 0
        per = ctx.step_scale
        moving, wanted, too_fast, creep = (per * r for r in (PIVOT_MOVING_RAD, PIVOT_RATE_RAD, PIVOT_FAST_RATE_RAD,
                                                             PIVOT_CREEP_RAD))
        stall_steps, max_steps = math.ceil(PIVOT_STALL_STEPS / per), math.ceil(PIVOT_MAX_STEPS / per)
        tilt = start
        while steps < max_steps:
            tilt, _ = self._tilt_from_touch(ctx)
            if tilt < PIVOT_DONE_RAD:
                break
            rate = previous - tilt  # rad a step, towards upright
            depth = min(ctx.indentation_mm().values())
            # as loose as the weight allows and hardly turning: gravity's torque no longer beats the friction
            loosest = depth < PIVOT_MIN_DEPTH_MM + PIVOT_STALL_DEPTH_MM
            slow = slow + 1 if rate < creep and loosest else 0
            if slow >= stall_steps:
                break
            if tilt < PIVOT_NEAR_RAD and rate < moving:
                # near enough for the place and hardly turning, or swung through upright (turning back): every
                # loose step slides it down the pads, so grip where it is
                break
            previous = tilt
            action = ctx.target.copy()
            if depth < PIVOT_MIN_DEPTH_MM or rate > too_fast:
                action[7] -= per * PIVOT_STEP_M
            elif rate < wanted:
                action[7] += per * (PIVOT_FAST_STEP_M if depth > PIVOT_FAST_ABOVE_MM else PIVOT_STEP_M)
            steps += 1
            yield ctx.step("swing", action)
        end, _ = self._tilt_from_touch(ctx)
        ctx.correction("swing upright", "contact strip angle on both pads with the hand's orientation: bottle tilt",
                       tilt_before_deg=math.degrees(start), tilt_after_deg=math.degrees(end),
                       loosened_mm=(float(ctx.target[7]) - start_width) * 1000, steps=steps)
        # upright in the hand, the bottle needs only to be carried: a lighter grip, quicker to make
        yield from close_until(ctx, replace(law, threshold_mm=REGRIP_FACTOR * grasp_depth_mm(self.profile)),
                               primitive="regrasp")

    def _place(self, ctx: ExpertContext, pose: InHandPose) -> Iterator[Step]:
        """Carry the bottle's axis (where the pads see it) over the cavity centre, lower it in, let go."""
        ee = ctx.ee_pose()
        axis = pose.axis_world(ee[3:])
        # the base is GRIP_HEIGHT_M down the axis from the grip point (the height the camera chose)
        base_from_hand = pose.grip_point_world(ee) - ee[:3] - axis * GRIP_HEIGHT_M
        offset = quat_to_mat(ee[3:]).T @ (pose.grip_point_world(ee) - ee[:3])
        ctx.correction("place from the in-hand pose", "contact strip centroids and angle on both pads",
                       offset_mm=float(offset[1]) * 1000, axis_tilt_deg=math.degrees(tilt_rad(axis)))
        cavity = self.cavity_centre(ctx.layout)
        above = cavity - base_from_hand + [0.0, 0.0, RIM_HEIGHT_M + 0.03]
        yield from move_to(ctx, above, speed_m_s=0.45, primitive="carry")
        yield from move_to(ctx, above - [0.0, 0.0, RIM_HEIGHT_M + 0.03 - PLACE_CLEARANCE_M], speed_m_s=0.15,
                           primitive="place")
        yield from open_to(ctx, ctx.target[7] + OPEN_MARGIN_M, speed_m_s=RELEASE_SPEED_M_S)
        yield from move_to(ctx, ctx.target[:3] + [0.0, 0.0, 0.05], speed_m_s=0.2)
        yield from wait(ctx, 0.1)

    # --- checks ------------------------------------------------------------------------------------
    def success(self, state: TaskState) -> bool:
        pose = state.objects["bottle"]
        axis = quat_to_mat(pose[3:])[:, 2]
        base = pose[:3] - axis * GRIP_HEIGHT_M
        cavity = self.cavity_centre(state.layout)
        return bool(np.linalg.norm(base[:2] - cavity[:2]) < SUCCESS_RADIUS_M
                    and -0.005 < base[2] - cavity[2] < SUCCESS_HEIGHT_M and tilt_rad(axis) < MAX_TILT_RAD)


__all__ = ["PutBottleInShelf"]
