"""Pull-out Key: turn a key in its lock back to the release angle, felt at the lock's end stop, and pull it out.

Description
    A key stands in a lock cylinder, turned away from the angle at which it can be withdrawn. The gripper
    starts open around the key's bow (aimed from a camera estimate). The expert grasps the bow with the
    closed-loop tactile grasp and turns the key towards the release angle. The camera's estimate of the
    lock's orientation is off by several degrees, more than the keyway allows, so the expert does not stop
    at the angle it sees: it turns until the lock's end stop, which lies a fixed 12 deg past the release
    angle, shows on the pads (the turning moment presses one edge of the bow into each gel), overshoots a
    little while it feels it, turns back 12 deg from where the stop was felt, and pulls the key 3 cm
    straight up.
Objects (procedural; sizes of a pin-tumbler house key and lock)
    ``key`` (the tactile object; MJCF geom ``key`` is the bow the pads hold): a plastic-headed bow
    24 x 8 x 20 mm (width, thickness, height; the gripper closes no narrower than 4 mm) whose centre is 16 mm
    above the lock face; shank a 2 mm diameter rod through the
    face; blade 14 x 2.6 x 20 mm below the face; 8 g in all. The key's body origin is on its axis at the
    lock face. It rides on two joints of the lock: ``key_turn`` (hinge about the vertical axis, angle 0 =
    the release angle, range -120 to +12 deg: the end stop, solref 4 ms; joint friction 0.01 N m, damping
    1e-4 N m s, armature 2e-4 kg m^2: the lock core's inertia, without which MuJoCo's stop is too soft to
    feel) and ``key_pull`` (slide along the axis, 0-50 mm, armature 0.05 kg). The pad-bow contact pair has
    half the kit's default stiffness (the lock, not a free object, takes the squeeze).
    ``lock``: fixed, a cylinder housing 30 mm across whose face is 35 mm above the table; the face is a
    3 mm plate with the keyway, a slot 17 x 3.5 mm along the lock's x. The blade (14 x 2.6 mm) can pass
    the slot only within +-3.7 deg of the release angle (its corners touch the slot's sides beyond); at
    any other angle the blade's top catches under the face plate and the key cannot be pulled. The blade
    and the face plate collide (explicit box pairs, solref 2 ms, solimp 0.99: a pull of 16 N, what the
    pads' friction carries, keeps the blade less than 0.2 mm into the plate); nothing else of the key touches the
    lock. ``benchmarks/key_detent_stability.py`` charts these choices.
Randomisation (seeded)
    lock centre x, y U(-5, 5) mm, lock yaw U(-45, 45) deg; the key's angle from the release angle
    U(-90, -45) deg. The camera's estimate of the lock's yaw (so of the release angle) is off by
    +-U(5, 10) deg; its estimate of the key's own angle (the bow is large) by U(-3, 3) deg.
Expert (closed loop; the signal and size of each correction are in ``memory['corrections']``)
    grasp the bow to 0.5 mm (0.3 mm on GF225 / Xense WS) and note each pad's depth; **turn until the stop
    is felt**: turn about the vertical through the gripper at 1.2 rad/s to 15 deg before the seen release
    angle, then at 0.6 rad/s on, at most 25 deg past it; the signal is the rise of the deepest indentation on either pad above its
    depth after the grasp: a key turned against the stop twists in the grasp about its axis and digs the
    bow's edges into the gels; a rise over 0.12 mm for two steps is the stop. The key's turning friction
    alone raises it by under 0.05 mm. **Overshoot and correct**: the gripper, still turning while the rise
    builds, ends 1.4 deg past where the stop was first felt; it turns back to 12 deg before the
    angle of first contact with the stop (the gripper's own yaw at the step the rise began), the release
    angle. Recorded: the felt stop angle, the overshoot past it and the turn back (deg). Then **pull** 3 cm
    straight up at 3 cm/s and hold 0.2 s. With corrections switched off the expert turns to the release
    angle the camera sees and pulls.
Success
    the key raised at least 26 mm (the blade's bottom clears the face plate after 23.5 mm) with its axis
    within 15 deg of vertical (the key rides on the lock's joints while in it, so this holds by
    construction until it is out).
Safety (per step; a violation makes the rollout invalid)
    deepest pad indentation <= the sensor's safe limit (1.5 mm Mini, 0.8 mm GF225 / Xense WS); the key
    moves at most 5 mm in the gripper frame once both pads grip it.
Step limit
    300 policy steps (6 s at 50 Hz), UniVTAC's; the expert takes at most 248 on seeds 0-99.
Version history
    v0: first version.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import numpy as np

from univtac_data.generators.scene.contact_pairs import TASK_OPTION_XML, PadContact
from univtac_data.generators.scene.gripper import GripperParams, gripper_actuator_xml, gripper_body_xml, gripper_equality_xml
from univtac_data.generators.scene.stage import STAGE_ASSETS_XML, stage_xml
from univtac_data.generators.tasks.base import ExpertContext, Step, Task, TaskConfig, TaskState, yaw_quat
from univtac_data.generators.tasks.motions import GraspLaw, close_until, grasp_depth_mm, move_to, rotate_about, wait
from univtac_data.schema.sensors import SensorProfile

FACE_Z_M = 0.035  # lock face above the table
STOP_RAD = math.radians(12.0)  # the end stop, past the release angle
PLATE_T_M = 0.003  # face plate thickness
SLOT_HALF_M = (0.0085, 0.00175)  # keyway half length, half width
BOW_HALF_M = (0.012, 0.004, 0.010)
BOW_CENTRE_M = 0.016  # above the face
SHANK_R_M = 0.001
BLADE_HALF_M = (0.007, 0.0013, 0.010)
BLADE_TOP_M = -0.0035  # below the face
KEY_MASS_KG = (0.005, 0.0005, 0.0025)  # bow, shank, blade
TURN_FRICTION_NM = 0.01
TURN_DAMPING_NMS = 1e-4
# MuJoCo scales a constraint's stiffness by the inertia it acts on: against the bare key (about 3e-7 kg m^2)
# the stop would give way like a spring of 0.02 N m/rad. The lock core's armature makes it a stop.
TURN_ARMATURE_KGM2 = 2e-4
# the same for the face plate holding the blade against the pull (16 N at most, what the pads' friction carries):
# with it and the stiff blade pairs the contact stays on the plate's underside; with the default softness the
# blade sank in until the contact found a sideways way out through the keyway's edge
PULL_ARMATURE_KG = 0.05
STOP_SOLREF = (0.004, 1.0)  # the stop's time constant (s) and damping ratio (benchmarks/key_detent_stability.py)
PULL_M = 0.03
OUT_M = 0.026  # success: raised this far
MAX_TILT_RAD = math.radians(15.0)
SEEN_LOCK_YAW_ERROR_RAD = (math.radians(5.0), math.radians(10.0))
SEEN_KEY_ANGLE_ERROR_RAD = math.radians(3.0)
# The lock holds the key against the pads' squeeze, so the pad contact acts on a finger alone and comes
# out stiffer than on a free object: halved, 0.5 mm takes 10-15 N, as on a held can.
KEY_PAD_CONTACT = PadContact(stiffness=50000.0, damping=450.0)
TURN_SPEED_RAD_S = 1.2  # up to 15 deg before the seen release angle
SEARCH_SPEED_RAD_S = 0.6  # from there on, feeling for the stop
SEARCH_PAST_RAD = math.radians(25.0)  # how far past the seen release angle the search may turn
DEPTH_RISE_MM = 0.12  # indentation rise that reads as the stop
OPEN_M = 0.018  # opening around the bow before the grasp


def current_yaw(quat: np.ndarray) -> float:
    """Yaw (rad) of a top-down gripper orientation ``yaw_quat(yaw)``."""
    return 2.0 * math.atan2(float(quat[3]), float(quat[0]))


def wrap(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


class PullOutKey(Task):
    __doc__ = __doc__
    name = "pull_out_key"
    gym_id = "univtac/PullOutKey-v0"
    max_steps = 300
    primitive_names = ["move", "grasp", "turn", "correct", "pull", "hold"]

    def __init__(self, config: TaskConfig, profile: SensorProfile, *, stop_solref: tuple[float, float] = STOP_SOLREF,
                 turn_damping_nms: float = TURN_DAMPING_NMS, turn_armature: float = TURN_ARMATURE_KGM2) -> None:
        super().__init__(config, profile)
        self.stop_solref = stop_solref  # the benchmark sweeps these; the task uses the defaults
        self.turn_damping_nms = turn_damping_nms
        self.turn_armature = turn_armature

    def sample_layout(self, rng: np.random.Generator) -> dict[str, Any]:
        lo, hi = SEEN_LOCK_YAW_ERROR_RAD
        return {"x_m": float(rng.uniform(-0.005, 0.005)), "y_m": float(rng.uniform(-0.005, 0.005)),
                "lock_yaw_rad": float(rng.uniform(-math.pi / 4, math.pi / 4)),
                "key_angle_rad": float(rng.uniform(-math.pi / 2, -math.pi / 4)),
                "seen_lock_yaw_error_rad": float(rng.uniform(lo, hi) * rng.choice((-1.0, 1.0))),
                "seen_key_angle_error_rad": float(rng.uniform(-SEEN_KEY_ANGLE_ERROR_RAD, SEEN_KEY_ANGLE_ERROR_RAD))}

    def objects(self) -> list[str]:
        return ["key"]

    def scene_xml(self, layout: dict[str, Any]) -> str:
        x, y, psi, angle = layout["x_m"], layout["y_m"], layout["lock_yaw_rad"], layout["key_angle_rad"]
        lock_q = " ".join(f"{v:.9f}" for v in yaw_quat(psi))
        key_q = " ".join(f"{v:.9f}" for v in yaw_quat(psi + angle))
        sl, sw = SLOT_HALF_M
        half_plate, hz = 0.014, PLATE_T_M / 2
        side = (half_plate - sw) / 2
        end = (half_plate - sl) / 2
        plate = "".join(
            f'\n      <geom name="face_{i}" type="box" pos="{px} {py} {-hz}" size="{sx} {sy} {hz}" contype="2" '
            f'conaffinity="2" rgba="0.75 0.65 0.3 1"/>'
            for i, (px, py, sx, sy) in enumerate([(0, sw + side, half_plate, side), (0, -sw - side, half_plate, side),
                                                  (sl + end, 0, end, sw), (-sl - end, 0, end, sw)]))
        bx, by, bz = BOW_HALF_M
        lx, ly, lz = BLADE_HALF_M
        shank_half = (BOW_CENTRE_M - bz - BLADE_TOP_M) / 2
        # explicit pairs: the key and the lock are both children of the world, which MuJoCo's parent filter
        # would otherwise exclude from colliding
        blade_pairs = "".join(f'<pair geom1="key_blade" geom2="face_{i}" condim="3" friction="0.3 0.3 0.005 0.0001 0.0001" '
                              f'solref="0.002 1" solimp="0.99 0.99 0.001"/>'
                              for i in range(4))
        params = GripperParams(mount="welded")
        stop = " ".join(map(str, self.stop_solref))
        return f"""<mujoco model="pull_out_key">
  <compiler angle="radian" autolimits="true"/>
  {TASK_OPTION_XML}
  <asset>{STAGE_ASSETS_XML}
  </asset>
  <worldbody>{stage_xml(head_target=(0.0, 0.0, FACE_Z_M))}
    <body name="lock" pos="{x} {y} {FACE_Z_M}" quat="{lock_q}">
      <geom name="housing" type="cylinder" pos="0 0 {-(FACE_Z_M + PLATE_T_M) / 2}"
            size="0.015 {(FACE_Z_M - PLATE_T_M) / 2}" rgba="0.55 0.55 0.6 1" contype="0" conaffinity="0"/>{plate}
    </body>
    <body name="key" pos="{x} {y} {FACE_Z_M}" quat="{key_q}">
      <joint name="key_pull" type="slide" axis="0 0 1" range="0 0.05" damping="0.01" armature="{PULL_ARMATURE_KG}"/>
      <joint name="key_turn" type="hinge" axis="0 0 1" ref="{angle}" range="{-2 * math.pi / 3} {STOP_RAD}"
             frictionloss="{TURN_FRICTION_NM}" armature="{self.turn_armature}" damping="{self.turn_damping_nms}" solreflimit="{stop}"/>
      <geom name="key" type="box" pos="0 0 {BOW_CENTRE_M}" size="{bx} {by} {bz}" mass="{KEY_MASS_KG[0]}"
            rgba="0.8 0.7 0.35 1" contype="0" conaffinity="0"/>
      <geom name="key_shank" type="cylinder" pos="0 0 {BLADE_TOP_M + shank_half}" size="{SHANK_R_M} {shank_half}"
            mass="{KEY_MASS_KG[1]}" rgba="0.8 0.7 0.35 1" contype="0" conaffinity="0"/>
      <geom name="key_blade" type="box" pos="0 0 {BLADE_TOP_M - lz}" size="{lx} {ly} {lz}" mass="{KEY_MASS_KG[2]}"
            rgba="0.8 0.7 0.35 1" contype="2" conaffinity="2"/>
    </body>
    {gripper_body_xml(self.profile, params, (0.0, 0.0, 0.3))}
  </worldbody>
  <contact>{KEY_PAD_CONTACT.pair_xml("key")}{blade_pairs}</contact>
  <actuator>{gripper_actuator_xml(params)}</actuator>
  <equality>{gripper_equality_xml(params)}</equality>
</mujoco>"""

    # --- what the camera estimates -----------------------------------------------------------------
    @staticmethod
    def seen_release_yaw(layout: dict[str, Any]) -> float:
        """Gripper yaw (rad) that holds the key at the release angle, as the camera sees the lock."""
        return layout["lock_yaw_rad"] + layout["seen_lock_yaw_error_rad"] + math.pi / 2

    def start_pose(self, layout: dict[str, Any]) -> np.ndarray:
        # the fingers close across the bow: the closing axis (gripper x) along the key's thin axis (key y)
        yaw = layout["lock_yaw_rad"] + layout["key_angle_rad"] + layout["seen_key_angle_error_rad"] + math.pi / 2
        return np.array([layout["x_m"], layout["y_m"], FACE_Z_M + BOW_CENTRE_M, *yaw_quat(yaw), OPEN_M])

    # --- behaviour ---------------------------------------------------------------------------------
    def expert(self, ctx: ExpertContext) -> Iterator[Step]:
        law = GraspLaw(threshold_mm=grasp_depth_mm(self.profile))
        yield from close_until(ctx, law)
        yield from wait(ctx, 0.1, primitive="grasp")
        touch = ctx.touch()
        base = {pad: reading.max_depth_mm for pad, reading in touch.items()}
        ctx.memory["grasp_depth_mm"] = base
        axis = np.array([0.0, 0.0, 1.0])
        seen = self.seen_release_yaw(ctx.layout)
        if not ctx.corrections_enabled:
            yield from rotate_about(ctx, axis, wrap(seen - current_yaw(ctx.target[3:7])), turn_rad_s=TURN_SPEED_RAD_S,
                                    primitive="turn")
        else:
            yield from self._turn_to_stop(ctx, axis, seen, base)
        yield from move_to(ctx, ctx.target[:3] + [0.0, 0.0, PULL_M], speed_m_s=0.03, primitive="pull")
        yield from wait(ctx, 0.2)

    def _turn_to_stop(self, ctx: ExpertContext, axis: np.ndarray, seen: float,
                      base: dict[str, float]) -> Iterator[Step]:
        """Turn until the stop shows on the pads, then back to the release angle (12 deg before the stop)."""
        near = wrap(seen - current_yaw(ctx.target[3:7])) - max(SEEN_LOCK_YAW_ERROR_RAD) - math.radians(5.0)
        if near > 0:
            yield from rotate_about(ctx, axis, near, turn_rad_s=TURN_SPEED_RAD_S, primitive="turn")
        start = current_yaw(ctx.target[3:7])
        total = wrap(seen - start) + SEARCH_PAST_RAD
        step = SEARCH_SPEED_RAD_S * ctx.dt_s
        yaws: list[float] = []
        risen = 0
        while abs(current_yaw(ctx.target[3:7]) - start) < total:
            yaws.append(current_yaw(ctx.target[3:7]))
            yield from rotate_about(ctx, axis, step, turn_rad_s=SEARCH_SPEED_RAD_S, primitive="turn")
            touch = ctx.touch()
            rise = max(touch[pad].max_depth_mm - base[pad] for pad in base)
            risen = risen + 1 if rise > DEPTH_RISE_MM else 0
            if risen >= 2:
                break
        if risen < 2:
            ctx.memory["stop_felt"] = False
            return
        # the rise began one step before it was read twice: the gripper's yaw then is the stop's angle
        felt = yaws[-2]
        now = current_yaw(ctx.target[3:7])
        release = felt - STOP_RAD
        ctx.memory["stop_felt"] = True
        ctx.correction("turn back from the end stop to the release angle",
                       "indentation rise on the pads (the stop's moment digs the bow's edges into the gels)",
                       rise_mm=rise, stop_felt_yaw_deg=math.degrees(felt), overshoot_deg=math.degrees(now - felt),
                       turn_back_deg=math.degrees(now - release))
        yield from rotate_about(ctx, axis, wrap(release - now), turn_rad_s=TURN_SPEED_RAD_S / 2, primitive="correct")
        yield from wait(ctx, 0.1, primitive="correct")

    # --- checks ------------------------------------------------------------------------------------
    def success(self, state: TaskState) -> bool:
        raised = state.objects["key"][2] - state.initial_objects["key"][2]
        tilt = math.acos(min(1.0, abs(float(state.axis("key")[2]))))
        return bool(raised >= OUT_M and tilt < MAX_TILT_RAD)


__all__ = ["PullOutKey"]
