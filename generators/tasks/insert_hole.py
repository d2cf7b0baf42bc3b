"""Insert Hole: find by touch which way a hole in a cube is inclined, pivot the held tube to its axis, push it in.

Description
    An 8 cm cube stands on the table with a round hole bored into its top face at 30 deg from the vertical
    (at 60 or 120 deg to the table, seeded: it leans toward +x or -x). The gripper holds a tube upright
    from the start (the set-up, not recorded, leaves the tube's end 2 mm above where the camera sees the
    hole's entrance; the camera cannot tell which way the bore leans). The expert lowers the tube into the
    entrance until the bore's lower wall pushes its end sideways, which turns the tube in the grasp about
    the pads' normal; the sign of that turn, read from the pads, is the bore's lean. The expert swings the
    gripper, tube held, onto the bore's axis and pushes the tube along it until its end is 4.5 cm deep.
Objects (procedural, boxes; sizes of a lab tube-rack block)
    ``tube``: a cylinder of diameter 2.0 cm and length 12 cm, 60 g (a thick-walled tube part filled), its
    origin at its centre, local +z along its axis; held at its centre (the same tube as Insert Tube). The
    cube (static): 8 cm, its top face at z = 8 cm, built from boxes: four side walls, a floor and a top plate
    with an opening around the bore. The bore: diameter 3.0 cm (5 mm radial clearance), 4.8 cm long, a ring
    of 16 box walls 5 mm thick (``holes.Bore``) turned 30 deg about world y, each wall cut where it meets the
    top face; its axis enters the top face at the cube's centre. Hole frame: origin at the entrance centre,
    +z the bore's axis pointing out of the cube. Tube-wall contact: solref 0.002 s, solimp 0.95-0.99 (the
    Insert Tube stability study). Pad contact with 1 cm torsional friction (the grasp resists turning).
Randomisation (seeded)
    cube centre x U(-2, 2) cm, y U(-3, 3) cm; lean toward +x or -x (p = 0.5); the camera's estimate of the
    entrance is off by U(-1.5, 1.5) mm in x and y.
Expert (closed loop; corrections in ``memory['corrections']``)
    **explore**: lower the upright tube up to 3 cm at 1 cm/s, stopping once the pads' marker field has
    turned by 5 deg about their normal (``turn``: the tube's turn in the grasp, the field's mean rotation);
    the bore's wall pushes the tube's lower end toward the lean, so the direction that end moved (gripper y
    times sin(turn), in world x) is the lean. **pivot** (the correction, when ``|turn| > 2 deg``): the hole
    is at 60 or 120 deg, so its axis is 30 deg from the vertical on the side the pads found; turn the
    gripper, tube held, about the point where the tube (as the pads place it in the hand) crosses the
    entrance plane, about the pads' normal, by the angle from the tube's axis to that axis (20-28 deg),
    0.6 rad/s; recorded with ``turn_deg``, ``lean`` and ``pivot_deg``. **push** in four parts at 2 cm/s
    along the tube's axis as the pads read it (the gripper's axis turned by the marker field's rotation),
    each part a quarter of what remains to 4.5 cm depth (the tube's end from the hand pose and the pads'
    shear); hold 0.2 s. ``corrections=False`` skips the pivot and pushes along the gripper's axis, as an expert
    blind to the turn: the tube turns more than 15 deg in the grasp (unsafe).
Success
    the tube's lower end at least 4 cm deep along the hole's axis and within 1 cm of it, the tube's axis
    within 8.1 deg of the hole's axis (dot product > 0.99), in-hand slip < 4 cm.
Safety (per step)
    pad indentation <= the sensor's safe limit; the tube moves at most 20 mm in the gripper frame (it slides
    up the pads as the bore drags on it; UniVTAC allows 40 mm) and turns at most 15 deg in the grasp (the angle
    between its axis and the gripper's: rotational slip). The validators hold the pads' recorded slip (the
    sliding path, the pivot's turn of the grasp included: 13-18 mm) to 30 mm (``max_pad_slip_mm``).
Step limit
    300 policy steps (6 s at 50 Hz); the expert takes 170-230.
Version history
    v0: first version.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import numpy as np

from univtac_data.generators.scene.contact_pairs import TASK_OPTION_XML, PadContact
from univtac_data.generators.scene.geometry import quat_from_axis_angle, quat_to_mat
from univtac_data.generators.scene.gripper import GripperParams, gripper_actuator_xml, gripper_body_xml, gripper_equality_xml
from univtac_data.generators.scene.stage import STAGE_ASSETS_XML, stage_xml
from univtac_data.generators.tasks.base import ExpertContext, SafetyCheck, Step, Task, TaskConfig, TaskState, yaw_quat
from univtac_data.generators.tasks.holes import Bore, in_hole_frame
from univtac_data.generators.tasks.insert_tube import (
    HOLE_CONTACT,
    TUBE_HALF_M,
    TUBE_MASS_KG,
    TUBE_RADIUS_M,
    PadShear,
    grip_opening_m,
)
from univtac_data.generators.tasks.motions import move_to, rotate_about, wait
from univtac_data.schema.sensors import SensorProfile

CUBE_HALF_M = 0.04
# the tube's pad contact, with torsional friction for a patch as long as the pads: the grasp resists the bore's
# push by turning only a little, so the pads read the lean and the gripper has to follow it
PAD_CONTACT = PadContact(stiffness=3e5, damping=1100.0, torsional_friction_m=0.01)
BORE = Bore(radius_m=0.015, depth_m=0.048, n_walls=16, wall_thickness_m=0.005, rgba="0.8 0.55 0.3 1")
TILT_RAD = math.radians(30.0)
SEEN_ERROR_M = 0.0015
EXPLORE_M = 0.03
EXPLORE_SPEED_M_S = 0.01
EXPLORE_TURN_RAD = math.radians(5.0)
WEDGED_SHEAR_MM = 0.5
MAX_IN_HAND_TURN_RAD = math.radians(15.0)  # safety: the tube turns at most this far in the grasp
PIVOT_MIN_RAD = math.radians(2.0)
PUSH_DEPTH_M = 0.045  # the tube end's depth along the axis the push aims for
PUSH_PARTS = 4
PUSH_SPEED_M_S = 0.02
SUCCESS_DEPTH_M = 0.04
SUCCESS_RADIUS_M = 0.01
SUCCESS_AXIS_DOT = 0.99
SUCCESS_SLIP_MM = 40.0


# the bore's walls end where they meet the tilted top face: within this depth of the entrance (along the axis)
# some of the ring is missing, the mouth
MOUTH_M = (BORE.radius_m + BORE.wall_thickness_m) * math.tan(TILT_RAD)


def hole_pose(layout: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """The hole frame (world): entrance centre (3,) m and quaternion; +z the bore axis out of the cube."""
    x, y = layout["cube_xy_m"]
    lean = float(layout["lean"])  # +1: the bore runs toward +x as it goes down
    quat = quat_from_axis_angle((0.0, 1.0, 0.0), -lean * TILT_RAD)
    return np.array([x, y, 2 * CUBE_HALF_M]), quat


class InsertHole(Task):
    __doc__ = __doc__
    name = "insert_hole"
    gym_id = "univtac/InsertHole-v0"
    max_steps = 300
    primitive_names = ["explore", "pivot", "push", "hold"]
    # the bore's wall drags on the tube as it is pushed 4.5 cm along it: it slides up to 10 mm up the pads
    # (UniVTAC stops at 40 mm)
    max_in_hand_slip_mm = 20.0
    # the pads' recorded slip (tactile/{pad}/slip_mm) adds up the sliding, the pivot's turn of the grasp included
    max_pad_slip_mm = 30.0

    def __init__(self, config: TaskConfig, profile: SensorProfile, *, corrections: bool = True) -> None:
        super().__init__(config, profile)
        self.corrections = corrections

    def sample_layout(self, rng: np.random.Generator) -> dict[str, Any]:
        xy = [float(rng.uniform(-0.02, 0.02)), float(rng.uniform(-0.03, 0.03))]
        lean = float(rng.choice((-1.0, 1.0)))
        err = [float(v) for v in rng.uniform(-SEEN_ERROR_M, SEEN_ERROR_M, 2)]
        return {"cube_xy_m": xy, "lean": lean, "hole_angle_deg": 90.0 - 30.0 * lean, "seen_error_m": err}

    def objects(self) -> list[str]:
        return ["tube"]

    @staticmethod
    def seen_entrance(layout: dict[str, Any]) -> np.ndarray:
        """Where the camera sees the bore's entrance, (3,) m world: the top face's centre, off by the seen
        error (the camera cannot tell which way the bore leans: that is for the pads)."""
        x, y = layout["cube_xy_m"]
        ex, ey = layout["seen_error_m"]
        return np.array([x + ex, y + ey, 2 * CUBE_HALF_M])

    def start_pose(self, layout: dict[str, Any]) -> np.ndarray:
        seen = self.seen_entrance(layout)
        # fingers close along world y: the bore leans in x, which turns the tube about the pads' normal
        quat = yaw_quat(math.pi / 2)
        return np.array([seen[0], seen[1], seen[2] + TUBE_HALF_M + 0.002, *quat, grip_opening_m(self.profile)])

    def _cube_xml(self, layout: dict[str, Any]) -> str:
        x, y = layout["cube_xy_m"]
        h = CUBE_HALF_M
        t = 0.004
        # top plate: a frame around the bore's elliptic mouth (semi-axes (R + wall) / cos 30 in x, R + wall in y)
        ox, oy = (BORE.radius_m + BORE.wall_thickness_m) / math.cos(TILT_RAD), BORE.radius_m + BORE.wall_thickness_m
        parts = [
            ((h - t / 2, 0, h), (t / 2, h, h)), ((-h + t / 2, 0, h), (t / 2, h, h)),
            ((0, h - t / 2, h), (h, t / 2, h)), ((0, -h + t / 2, h), (h, t / 2, h)),
            ((0, 0, t / 2), (h, h, t / 2)),
            (((h + ox) / 2, 0, 2 * h - t / 2), ((h - ox) / 2, h, t / 2)),
            ((-(h + ox) / 2, 0, 2 * h - t / 2), ((h - ox) / 2, h, t / 2)),
            ((0, (h + oy) / 2, 2 * h - t / 2), (ox, (h - oy) / 2, t / 2)),
            ((0, -(h + oy) / 2, 2 * h - t / 2), (ox, (h - oy) / 2, t / 2)),
        ]
        geoms = "\n      ".join(
            f'<geom name="cube{k}" type="box" pos="{p[0]:.5f} {p[1]:.5f} {p[2]:.5f}" size="{s[0]:.5f} {s[1]:.5f} '
            f'{s[2]:.5f}" rgba="0.85 0.62 0.35 1"{HOLE_CONTACT}/>' for k, (p, s) in enumerate(parts))
        return f'<body name="cube" pos="{x} {y} 0">\n      {geoms}\n    </body>'

    def scene_xml(self, layout: dict[str, Any]) -> str:
        pos, quat = hole_pose(layout)
        start = self.start_pose(layout)
        q = " ".join(f"{v:.9f}" for v in quat)
        # each wall ends where it meets the cube's top face (the plane z = 0 of the world through the entrance)
        normal = quat_to_mat(quat).T @ np.array([0.0, 0.0, 1.0])
        r = BORE.radius_m + BORE.wall_thickness_m / 2
        tops = [-(normal[0] * r * math.cos(a) + normal[1] * r * math.sin(a)) / normal[2]
                for a in np.linspace(0, 2 * math.pi, BORE.n_walls, endpoint=False)]
        params = GripperParams(mount="welded")
        return f"""<mujoco model="insert_hole">
  <compiler angle="radian" autolimits="true"/>
  {TASK_OPTION_XML}
  <asset>{STAGE_ASSETS_XML}
  </asset>
  <worldbody>{stage_xml()}
    {self._cube_xml(layout)}
    <body name="hole" pos="{pos[0]} {pos[1]} {pos[2]}" quat="{q}">
      {BORE.walls_xml("bore", tops, attrs=HOLE_CONTACT)}
    </body>
    <body name="tube" pos="{start[0]} {start[1]} {start[2]}">
      <freejoint name="tube_free"/>
      <geom name="tube" type="cylinder" size="{TUBE_RADIUS_M} {TUBE_HALF_M}" mass="{TUBE_MASS_KG}"
            rgba="0.85 0.9 0.95 1" condim="4"{HOLE_CONTACT}/>
    </body>
    {gripper_body_xml(self.profile, params, tuple(start[:3]))}
  </worldbody>
  <contact>{PAD_CONTACT.pair_xml("tube")}</contact>
  <actuator>{gripper_actuator_xml(params)}</actuator>
  <equality>{gripper_equality_xml(params)}</equality>
</mujoco>"""

    def expert(self, ctx: ExpertContext) -> Iterator[Step]:
        shear = PadShear(ctx)
        entrance = self.seen_entrance(ctx.layout)
        turn = 0.0
        for action in move_to(ctx, ctx.target[:3] - np.array([0.0, 0.0, EXPLORE_M]), speed_m_s=EXPLORE_SPEED_M_S,
                              primitive="explore"):
            yield action
            turn = shear.turn_rad()
            if abs(turn) >= EXPLORE_TURN_RAD:  # the lean is clear: stop before the tube wedges across the bore
                break
        ctx.memory.update(explored_turn_deg=math.degrees(turn), lean_from_touch=0.0, pivots=0)
        corrections = self.corrections and ctx.corrections_enabled
        if abs(turn) > PIVOT_MIN_RAD and corrections:
            yield from self._pivot(ctx, shear, turn, entrance)
        for part in range(PUSH_PARTS):
            mat = quat_to_mat(ctx.target[3:7])
            # push along the tube as the pads have it (the bore steers it in the grasp); without corrections
            # along the gripper's axis, as an expert blind to the turn would
            along = self._tube_axis(ctx, shear) if corrections else mat[:, 2]
            end = ctx.target[:3] + mat @ shear.end_in_hand_m(TUBE_HALF_M)
            remaining = max(0.0, PUSH_DEPTH_M - float((entrance - end) @ along))
            yield from move_to(ctx, ctx.target[:3] - along * remaining / (PUSH_PARTS - part),
                               speed_m_s=PUSH_SPEED_M_S, primitive="push")
        yield from wait(ctx, 0.2)

    @staticmethod
    def _tube_axis(ctx: ExpertContext, shear: PadShear) -> np.ndarray:
        """(3,) the tube's axis (up, world) as the pads read it: the gripper's axis turned about the pads'
        normal by the marker field's rotation."""
        mat = quat_to_mat(ctx.target[3:7])
        turn = shear.turn_rad()
        return mat @ np.array([0.0, -math.sin(turn), math.cos(turn)])

    def _pivot(self, ctx: ExpertContext, shear: PadShear, turn: float, entrance: np.ndarray) -> Iterator[Step]:
        """The correction: the tube turned toward the bore's lean (the sign of ``turn``); the hole is at 60 or
        120 deg, so the bore's axis is 30 deg from the vertical on that side. Swing the gripper, tube held, about
        the point where the tube crosses the entrance plane until the tube lies on that axis."""
        # the bore pushed the tube's lower end toward its lean: that end moved along the gripper's y by sin(turn)
        toward = quat_to_mat(ctx.target[3:7]) @ np.array([0.0, math.sin(turn), 0.0])
        lean = math.copysign(1.0, float(toward[0]))
        ctx.memory["lean_from_touch"] = lean
        bore_up = np.array([-lean * math.sin(TILT_RAD), 0.0, math.cos(TILT_RAD)])
        tube_up = self._tube_axis(ctx, shear)
        normal = quat_to_mat(ctx.target[3:7])[:, 0]  # the pads' normal (world y)
        angle = math.atan2(float(np.cross(tube_up, bore_up) @ normal), float(tube_up @ bore_up))
        centre = ctx.target[:3] + quat_to_mat(ctx.target[3:7]) @ shear.end_in_hand_m(TUBE_HALF_M)
        crossing = centre + tube_up * (entrance[2] - centre[2]) / tube_up[2]
        ctx.correction("pivot onto the bore's axis", "marker field rotation about the pads' normal: the tube turned "
                       "in the grasp toward the bore's lean", turn_deg=math.degrees(turn), lean=lean,
                       pivot_deg=math.degrees(angle))
        ctx.memory["pivots"] += 1
        yield from rotate_about(ctx, normal, angle, crossing, turn_rad_s=0.6, primitive="pivot")

    def safety(self, state: TaskState) -> SafetyCheck:
        """The kit's rules plus rotational slip: the tube (upright in the grasp at the start, and never
        released) turns at most 15 deg in the grasp, the angle between its axis and the gripper's."""
        check = super().safety(state)
        if not check.ok:
            return check
        tube_axis = quat_to_mat(state.objects["tube"][3:])[:, 2]
        turn = math.acos(min(1.0, abs(float(tube_axis @ quat_to_mat(state.ee_pose[3:])[:, 2]))))
        if turn > MAX_IN_HAND_TURN_RAD:
            return SafetyCheck(False, f"tube turned {math.degrees(turn):.1f} deg in the grasp > "
                                      f"{math.degrees(MAX_IN_HAND_TURN_RAD):.0f} deg")
        return check

    def success(self, state: TaskState) -> bool:
        pos, quat = hole_pose(state.layout)
        tube = state.objects["tube"]
        mat = quat_to_mat(tube[3:])
        end = in_hole_frame(pos, quat, tube[:3] - mat[:, 2] * TUBE_HALF_M)
        aligned = abs(float(mat[:, 2] @ quat_to_mat(quat)[:, 2])) > SUCCESS_AXIS_DOT
        return bool(-end[2] >= SUCCESS_DEPTH_M and math.hypot(end[0], end[1]) < SUCCESS_RADIUS_M and aligned
                    and state.in_hand_slip_mm < SUCCESS_SLIP_MM)
