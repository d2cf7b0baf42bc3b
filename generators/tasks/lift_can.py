"""Lift Can: pick a can lying on its side and lift it upright.

Description
    One of three cans lies on its side on the table, its top pointing in a random direction. The gripper
    starts open above it (the set-up, not recorded, aims from a camera estimate with its error). The expert
    descends, closes with the closed-loop tactile grasp across the can's diameter, reads from the two contact
    patches whether the fingers close squarely across the can, re-grasps if not, lifts, and turns the can
    upright about the closing axis.
Objects (procedural, sizes of real cans, masses of partly filled ones)
    ``can``: a cylinder of diameter 4, 5 or 6 cm, length 7, 9 or 11.5 cm, 60, 100 or 150 g (an espresso,
    a 250 ml and a 330 ml can); its local +z is the top. Ground: a plane, friction 0.8.
Randomisation (seeded)
    diameter uniform from {4, 5, 6} cm; can centre x U(-3, 3) cm, y U(-5, 5) cm; top direction (yaw)
    U(-180, 180) deg; the camera's estimate of the can's yaw is off by +-U(6, 18) deg and of its centre by
    U(-1, 1) cm along the can.
Expert (closed loop; the signal behind each correction is recorded in ``memory['corrections']``)
    descend to the can's axis height; tactile grasp to 0.5 mm (0.3 mm on the GF225 and Xense WS, whose safe
    limit is 0.8 mm); **squareness correction**: a can crossing the pads at an angle ``e`` touches each pad over
    a strip that starts at the pad's end, where it is deepest, and ends where the can leaves the gel: its depth
    ``d`` over its length ``L`` along the pad gives ``tan e = d / L``, the end it sits at the sign; where a
    patch runs off the image (the GF225's, about 10 deg from square: a sliver at the image's edge, perhaps on
    one pad only), ``L`` runs from the patch's inner end to the gel's end and ``d`` is the pad's press (the
    grasp law's indentation); if ``|e| > 3 deg`` (6 deg after a blind turn, below) open 1.2 cm (at most to the
    gripper's stroke), turn the gripper by ``e`` about the vertical, re-grasp (at most twice). **Patch off the
    image**: when both pads press (the grasp law's indentation) but neither image shows a patch, the can
    touches the gel only beyond the imaged area (the GF225 images 23.5 of its 27 mm gel, so a can more than
    about 10 deg from square) and which way it crosses is unknown: open 1.2 cm, turn 12 deg (the middle of the
    camera's error) and re-grasp; if still unseen, turn back 24 deg, towards square, where the can narrows
    between the pads: open 3 mm and turn at 2.4 rad/s (at most these two turns; recorded as ``grasp
    squareness, patch off the image``). After a blind turn another re-grasp (about 50 steps) no longer fits
    the step limit, and a can within 6 deg of square still stands within the 8.1 deg allowed. The Mini images
    all of its gel and the Xense WS nearly all (29.3 of 29.37 mm), so this does not happen there. Lift 12 cm
    at 10 cm/s; turn 90 deg about the closing axis, the way that brings the top up; hold 0.4 s.
Success
    can centre at least 10 cm above where it lay and its axis upright: axis . z > 0.99 (8.1 deg).
Safety (per step; a violation makes the rollout invalid)
    deepest pad indentation <= the sensor's safe limit (1.5 mm Mini, 0.8 mm GF225 / Xense WS); the held can
    moves at most 5 mm in the gripper frame once both pads grip it.
Step limit
    300 policy steps (6 s at 50 Hz).
Version history
    v0: first version (the environment). Its expert since: the turn when the patch is off the image (GF225);
    the squareness from a patch at the image's edge (GF225); a quicker turn back after a blind turn and no
    re-grasp past the stroke (GF225: 299 of development seeds 100-399 kept, was 269).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import numpy as np

from univtac_data.generators.scene.contact_pairs import TASK_OPTION_XML, PadContact
from univtac_data.generators.scene.stage import STAGE_ASSETS_XML, stage_xml
from univtac_data.generators.scene.geometry import quat_from_axis_angle, quat_mul, quat_to_mat
from univtac_data.generators.scene.gripper import MAX_OPENING_M, GripperParams, gripper_actuator_xml, gripper_body_xml, gripper_equality_xml
from univtac_data.generators.scene.touch import TouchReading
from univtac_data.generators.tasks.base import ExpertContext, Step, Task, TaskState, yaw_quat
from univtac_data.generators.tasks.motions import GraspLaw, close_until, grasp_depth_mm, move_to, open_to, rotate_about, wait

CANS = {  # diameter m -> (length m, mass kg)
    0.04: (0.070, 0.060),
    0.05: (0.090, 0.100),
    0.06: (0.115, 0.150),
}
LIFT_M = 0.12
SQUARE_TOLERANCE_RAD = math.radians(3.0)
# after a blind turn a further re-grasp (about 50 steps) no longer fits the step limit, and a can up to 6 deg
# from square still stands within the 8.1 deg the task allows once turned upright
AFTER_BLIND_TOLERANCE_RAD = math.radians(6.0)
BLIND_TURN_RAD = math.radians(12.0)  # the middle of the camera's 6-18 deg yaw error
MAX_BLIND_TURNS = 2
EDGE_MM = 0.25  # a patch ending this close to the image's edge runs off it
REGRASP_OPEN_M = 0.012  # a re-grasp opens this much wider before it turns the hand
REGRASP_TURN_RAD_S = 1.2  # and turns the hand this fast
TOWARDS_SQUARE_OPEN_M = 0.003  # the same for the blind turn back, towards square
TOWARDS_SQUARE_TURN_RAD_S = 2.4


def regrasp_opening_m(width_m: float, wider_m: float) -> float:
    """The opening (m) a re-grasp opens to from ``width_m``: ``wider_m`` wider, at most the gripper's stroke
    (a can far from square is held at nearly the full stroke, and a target beyond it cost the close that
    follows ten steps to come back to the stroke)."""
    return min(MAX_OPENING_M, width_m + wider_m)


def patch_at_image_edge(reading: TouchReading, pad_width_mm: float, imaged_width_mm: float) -> bool:
    """Whether ``reading``'s patch runs off the image along pad x into gel the image does not show (the GF225
    images 23.5 of its 27 mm gel; the Mini all of it, the Xense WS all but 0.07 mm, less than a cell)."""
    hidden_mm = (pad_width_mm - imaged_width_mm) / 2
    outer_mm = abs(reading.centroid_mm[0]) + reading.span_x_mm / 2
    return reading.touching and hidden_mm > EDGE_MM and outer_mm >= imaged_width_mm / 2 - EDGE_MM


def squareness_from_touch(left: TouchReading, right: TouchReading, pad_width_mm: float,
                          imaged_width_mm: float | None = None, press_mm: tuple[float, float] = (0.0, 0.0)) -> float:
    """Angle (rad) to turn the gripper about the vertical so that the fingers close square across the can.

    A can whose axis makes an angle e with the pads touches each pad over a patch that starts at one end
    of the pad, where it is deepest, and ends where the surface leaves the gel: its length L and depth d give
    tan e = d / L. A square grasp touches along the whole pad, evenly. The side of the pad the patches sit
    on (the centroids, in gripper y: left pad x is gripper +y, right pad x is gripper -y) gives the sign.
    L is read along the pad's x (the can's direction), where the patch of a tilted can is a short strip.

    A patch that runs off the image (``patch_at_image_edge``; ``imaged_width_mm`` narrower than the pad)
    starts at the gel's end out of sight, where the pad presses ``press_mm`` (left, right: the grasp law's
    indentation): there L runs from the patch's inner end to the gel's end, and one such pad is enough (the
    other's patch may lie wholly out of sight).
    """
    if left.span_x_mm >= 0.8 * pad_width_mm and right.span_x_mm >= 0.8 * pad_width_mm:
        return 0.0
    edges = [imaged_width_mm is not None and patch_at_image_edge(r, pad_width_mm, imaged_width_mm)
             for r in (left, right)]
    if any(edges):
        slopes = [press / max(pad_width_mm / 2 - (abs(r.centroid_mm[0]) - r.span_x_mm / 2), 1e-6) if edge
                  else r.max_depth_mm / max(r.span_x_mm, 1e-6)
                  for r, edge, press in zip((left, right), edges, press_mm) if r.touching]
        tilt = math.atan(sum(slopes) / len(slopes))
    else:
        tilt = math.atan2(0.5 * (left.max_depth_mm + right.max_depth_mm), 0.5 * (left.span_x_mm + right.span_x_mm))
    offset = left.centroid_mm[0] + right.centroid_mm[0]  # gripper y of the left patch minus that of the right
    return math.copysign(tilt, offset) if abs(offset) > 0.5 else 0.0


class LiftCan(Task):
    __doc__ = __doc__
    name = "lift_can"
    gym_id = "univtac/LiftCan-v0"
    max_steps = 300
    primitive_names = ["move", "grasp", "release", "lift", "rotate", "hold", "regrasp"]

    def sample_layout(self, rng: np.random.Generator) -> dict[str, Any]:
        diameter = float(rng.choice(sorted(CANS)))
        yaw = float(rng.uniform(-math.pi, math.pi))
        err = float(rng.uniform(math.radians(6), math.radians(18)) * rng.choice((-1.0, 1.0)))
        return {"diameter_m": diameter, "length_m": CANS[diameter][0], "mass_kg": CANS[diameter][1],
                "x_m": float(rng.uniform(-0.03, 0.03)), "y_m": float(rng.uniform(-0.05, 0.05)), "yaw_rad": yaw,
                "seen_yaw_error_rad": err, "seen_along_error_m": float(rng.uniform(-0.01, 0.01))}

    def objects(self) -> list[str]:
        return ["can"]

    @staticmethod
    def _can_quat(yaw: float) -> np.ndarray:
        # local +z (the top) along the world direction (cos yaw, sin yaw, 0)
        lie = quat_from_axis_angle((0, 1, 0), math.pi / 2)
        return quat_mul(quat_from_axis_angle((0, 0, 1), yaw), lie)

    def scene_xml(self, layout: dict[str, Any]) -> str:
        r, half = layout["diameter_m"] / 2, layout["length_m"] / 2
        q = " ".join(f"{v:.9f}" for v in self._can_quat(layout["yaw_rad"]))
        params = GripperParams(mount="welded")
        return f"""<mujoco model="lift_can">
  <compiler angle="radian" autolimits="true"/>
  {TASK_OPTION_XML}
  <asset>{STAGE_ASSETS_XML}
  </asset>
  <worldbody>{stage_xml()}
    <body name="can" pos="{layout['x_m']} {layout['y_m']} {r + 0.0005}" quat="{q}">
      <freejoint name="can_free"/>
      <geom name="can" type="cylinder" size="{r} {half}" mass="{layout['mass_kg']}" rgba="0.75 0.1 0.1 1"
            friction="0.8 0.005 0.0001" condim="4"/>
      <geom name="can_lid" type="cylinder" pos="0 0 {half - 0.002}" size="{r * 0.93} 0.0025" rgba="0.85 0.85 0.88 1"
            contype="0" conaffinity="0" mass="0"/>
    </body>
    {gripper_body_xml(self.profile, params, (0.0, 0.0, 0.3))}
  </worldbody>
  <contact>{PadContact().pair_xml("can")}</contact>
  <actuator>{gripper_actuator_xml(params)}</actuator>
  <equality>{gripper_equality_xml(params)}</equality>
</mujoco>"""

    def _seen(self, layout: dict[str, Any]) -> tuple[np.ndarray, float]:
        """The camera's estimate: can centre (m) and yaw of its axis (rad)."""
        yaw = layout["yaw_rad"] + layout["seen_yaw_error_rad"]
        along = np.array([math.cos(layout["yaw_rad"]), math.sin(layout["yaw_rad"]), 0.0])
        centre = np.array([layout["x_m"], layout["y_m"], layout["diameter_m"] / 2]) + along * layout["seen_along_error_m"]
        return centre, yaw

    def start_pose(self, layout: dict[str, Any]) -> np.ndarray:
        centre, yaw = self._seen(layout)
        # fingers close across the can: the closing axis (gripper x) perpendicular to the can's axis
        quat = yaw_quat(yaw + math.pi / 2)
        return np.array([centre[0], centre[1], centre[2] + 0.06, *quat, MAX_OPENING_M])

    def expert(self, ctx: ExpertContext) -> Iterator[Step]:
        layout = ctx.layout
        r = layout["diameter_m"] / 2
        law = GraspLaw(threshold_mm=grasp_depth_mm(self.profile))
        yield from move_to(ctx, ctx.target[:3] - np.array([0, 0, 0.06]), width=2 * r + 0.012, speed_m_s=0.12)
        blind = 0
        for attempt in range(3 + MAX_BLIND_TURNS):
            yield from close_until(ctx, law)
            touch = ctx.touch()
            if not (touch["left"].touching or touch["right"].touching) and ctx.memory["grasped"] \
                    and ctx.corrections_enabled and blind < MAX_BLIND_TURNS:
                # both pads press (the grasp law's reading) but neither image shows a patch: the can crosses
                # the pads so far from square that it touches them only beyond the imaged area (the GF225
                # images 23.5 of its 27 mm gel). Which way is unknown: turn one way, then back past the start
                angle = BLIND_TURN_RAD * (1 if blind == 0 else -2)
                blind += 1
                ctx.correction("grasp squareness, patch off the image", "both pads press (indentation) but "
                               "neither image shows a contact patch", angle_deg=math.degrees(angle), blind_turn=blind)
                # the turn back goes towards square, where the can is narrower between the pads: a little
                # opening frees it, the pads cannot catch it while they turn, and the close that follows
                # starts nearer the can
                back = blind == 2
                yield from open_to(ctx, regrasp_opening_m(ctx.target[7], TOWARDS_SQUARE_OPEN_M if back else
                                                          REGRASP_OPEN_M), primitive="regrasp")
                yield from rotate_about(ctx, np.array([0.0, 0.0, 1.0]), angle, primitive="regrasp",
                                        turn_rad_s=TOWARDS_SQUARE_TURN_RAD_S if back else REGRASP_TURN_RAD_S)
                continue
            gel_mm, imaged_mm = self.profile.gel_width_mm, self.profile.imaged_width_mm
            off_image = any(patch_at_image_edge(touch[pad], gel_mm, imaged_mm) for pad in ("left", "right"))
            if not (touch["left"].touching and touch["right"].touching) and not off_image:
                break
            press = ctx.indentation_mm()
            angle = squareness_from_touch(touch["left"], touch["right"], gel_mm, imaged_mm,
                                          (press["left"], press["right"]))
            tolerance = SQUARE_TOLERANCE_RAD if blind == 0 else AFTER_BLIND_TOLERANCE_RAD
            if abs(angle) <= tolerance or attempt - blind == 2 or not ctx.corrections_enabled:
                break
            ctx.correction("grasp squareness", "contact patch depth gradient and centroid along the can",
                           angle_deg=math.degrees(angle), patch_span_mm=touch["left"].span_x_mm)
            yield from open_to(ctx, regrasp_opening_m(ctx.target[7], REGRASP_OPEN_M), primitive="regrasp")
            yield from rotate_about(ctx, np.array([0.0, 0.0, 1.0]), angle, primitive="regrasp",
                                    turn_rad_s=REGRASP_TURN_RAD_S)
        yield from move_to(ctx, ctx.target[:3] + np.array([0, 0, LIFT_M]), speed_m_s=0.10, primitive="lift")
        # the top must come up: turn about the closing axis (gripper x) the way that lifts the can's +z end
        closing_axis = quat_to_mat(ctx.target[3:7])[:, 0]
        top = quat_to_mat(ctx.object_pose("can")[3:])[:, 2]
        sign = 1.0 if np.dot(np.cross(closing_axis, top), [0, 0, 1]) > 0 else -1.0
        yield from rotate_about(ctx, closing_axis, sign * math.pi / 2, turn_rad_s=1.5)
        yield from wait(ctx, 0.4)

    def success(self, state: TaskState) -> bool:
        lifted = state.objects["can"][2] - state.initial_objects["can"][2] >= 0.10
        return bool(lifted and state.axis("can")[2] > 0.99)
