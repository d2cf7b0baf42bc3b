"""Insert Tube: push a held 2.0 cm tube into a 2.05 cm hole in a surface tilted 30 deg, finding the hole by touch.

Description
    A plate tilted 30 deg (its normal leans toward -x) has a 2.05 cm hole bored along its normal; the
    gripper holds a 2.0 cm tube on the hole's axis direction from the start (the set-up, not recorded,
    grasps it at its centre and leaves its end 2 mm above the plate), but off the hole's centre by 1-4 mm
    (the deliberate error of the first attempt). The expert probes along the axis; when the plate blocks
    the tube, the tube slides up the pads and the pads' shear says so; the expert lifts, steps to the next
    point of a search ring around the first attempt and probes again, until a probe goes through; then it
    pushes the tube 3.5 cm deep.
Objects (procedural, boxes; sizes of a lab test tube and a rack)
    ``tube``: a cylinder of diameter 2.0 cm and length 12 cm, 60 g (a thick-walled tube part filled), origin
    at its centre, local +z along its axis, held at its centre (pads' contact pair 3e5 /s^2: a firm grip on a
    light tube). The hole (static, ``holes.Bore``): radius 10.25 mm (0.25 mm radial clearance, 2.05 cm), 5 cm
    deep, a ring of 24 box walls 14 mm thick whose inner faces are a 24-gon with that inscribed radius (the
    corners 0.09 mm wider), a 45 deg chamfer 2 mm wide at the entrance (the capture range: a tube within
    about 2 mm of the axis slides in), in a 9 x 9 cm plate 12 mm thick; entrance centre at (0, 0, 0.10) m
    moved by the layout. Hole frame: origin at the entrance centre, +z the hole's axis out of the plate (world
    turned -30 deg about y), x and y across it. Tube-wall contact: solref 0.002 s, solimp 0.95-0.99, no
    margin (chosen by ``benchmarks/insertion_stability.py``: peak penetration 0.14 mm, under the clearance).
Randomisation (seeded)
    hole x U(-5, 5) mm, y U(-10, 10) mm (UniVTAC's); the first attempt's offset from the hole's axis, in the
    hole frame: a distance U(1, 4) mm in a uniform direction.
Expert (closed loop; corrections in ``memory['corrections']``)
    **probe**: from the tube's end 1.5 mm above the entrance, 5 mm along the axis at 1 cm/s; the signal is the
    pads' axial shear, the mean marker displacement along the pads (the gripper's z) since the probe began
    (``PadShear``: the tangential motion of the tube's surface under each pad centre, the quantity the tactile
    model turns into the shear field): over 0.75 mm means the plate blocks the tube (sliding down the chamfer
    mostly stays under 0.6 mm). **retry** (the correction, after a blocked probe): lift 2 mm, move to the next
    point of a ring of 6 points 3 mm around the first attempt (each a 3 mm step from the last), probe again; recorded with
    the shear and the step (``shear_mm``, ``step_x_mm``, ``step_y_mm``, ``move_mm``). Every aim is for the
    tube's end where the pads place it in the hand (their shear along and across the pads and the marker
    field's rotation: the tube slides about 0.8 mm up the pads and turns a little at each miss).
    **step across the grasp** (once, a correction): the grip holds the tube rigidly along the pads' normal (the
    hole frame's x), so a probe more than about 1.3 mm off that way catches on the chamfer instead of sliding
    in; its end then stops 1.0-1.9 mm below the entrance (the flat plate stops it at about 0.1 mm). When a ring
    point's probe is blocked with the end ``CHAMFER_MISS_M`` or more below the entrance (the hand's travel
    less the slide up the pads), the next probes are ``CHAMFER_STEP_M`` to either side of it along the pads'
    normal, the side nearer the first attempt first, then the rest of the ring (recorded with
    ``end_depth_mm``, the step and ``move_mm``).
    **straighten** (before the push): when the marker field's rotation says the tube turned in the grasp by
    more than 1.5 deg (the chamfer turns it, up to about 5 deg), turn the gripper back by that angle about the
    pads' normal through the tube's end, at 0.3 rad/s (recorded with ``turn_deg``, ``pivot_deg``): pushed
    crooked, the tube wedged in the bore and slid up to 9 mm up the pads, short of 3 cm.
    **insert**: push until the end is 3.5 cm deep, 2 cm/s, once a probe went through (never on a blocked tube,
    which would only slide up the pads); hold 0.2 s. ``corrections=False`` never retries nor straightens.
Success
    the tube's lower end within 5 mm of the hole's axis (hole frame x, y) and at least 3 cm deep.
Safety (per step)
    pad indentation <= the sensor's safe limit; the tube moves at most 10 mm in the gripper frame (each miss
    slides it about 0.8 mm up the pads; UniVTAC allows 30 mm). The validators hold the pads' recorded slip
    (``tactile/{pad}/slip_mm``, the sliding path) to 20 mm (``max_pad_slip_mm``) instead of their 1 mm default.
Step limit
    300 policy steps (6 s at 50 Hz); the expert takes 110-293 (seeds 0-99: 293 is seed 14, whose first ring
    point read as on the chamfer, both steps across it were blocked and the ring's last point went in; up to
    284 on the GF225's development seeds 300-699).
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
from univtac_data.generators.tasks.base import ExpertContext, Step, Task, TaskConfig, TaskState
from univtac_data.generators.tasks.holes import Bore, HoleContact, in_hole_frame, square_plate_xml
from univtac_data.generators.tasks.motions import held_opening_m, move_to, rotate_about, wait
from univtac_data.schema.sensors import SensorProfile

TUBE_RADIUS_M = 0.010
TUBE_HALF_M = 0.06
TUBE_MASS_KG = 0.06
# MuJoCo scales a contact's stiffness by the bodies' effective mass: the kit's pair (1e5 /s^2, tuned on 60-300 g
# cans held across the pad) let a pushed 25-60 g tube sink 4 mm into one pad and slide out; 3e5 holds it
PAD_CONTACT = PadContact(stiffness=3e5, damping=1100.0)
BORE = Bore(radius_m=0.01025, depth_m=0.05, chamfer_m=0.002)  # 2.05 cm: 0.25 mm radial clearance
HOLE_CONTACT = HoleContact().attrs()
TILT_RAD = math.radians(30.0)  # the plate's tilt (the hole's axis from the vertical)
HOLE_XYZ_M = (0.0, 0.0, 0.10)  # entrance centre before the layout moves it, world m
PLATE_HALF_M = 0.045
PLATE_OPENING_HALF_M = 0.016  # the plate's square opening, filled to the bore by the ring's walls
PLATE_THICKNESS_M = 0.012

PROBE_START_M = 0.0015  # the tube's end this far above the entrance before each probe
PROBE_TRAVEL_M = 0.005  # a probe ends 3.5 mm below the entrance: past the chamfer, in the bore proper
PROBE_SPEED_M_S = 0.01
BLOCKED_SHEAR_MM = 0.75  # axial shear during one probe that means the surface blocks the tube
SEARCH_RADIUS_M = 0.003
SEARCH_POINTS = 6
# a blocked probe whose tube end got this far below the entrance was on the chamfer (the flat plate stops it
# at about 0.1 mm; the chamfer, at 1.0-1.9 mm when the hole is 1.3-2.4 mm off along the pads' normal)
CHAMFER_MISS_M = 0.0007
CHAMFER_STEP_M = 0.0015  # the step along the pads' normal to either side of a probe that ended on the chamfer
INSERT_DEPTH_M = 0.035
INSERT_SPEED_M_S = 0.02
STRAIGHTEN_TURN_RAD = math.radians(1.5)  # a larger turn in the grasp is straightened before the push
STRAIGHTEN_RATE_RAD_S = 0.3


def grip_opening_m(profile: SensorProfile) -> float:
    """The opening the set-up leaves the fingers at on the 2.0 cm tube: the kit's grasp depth on each pad."""
    return held_opening_m(profile, 2 * TUBE_RADIUS_M)


def search_ring() -> list[np.ndarray]:
    """The retry points (hole frame x, y m, around the first attempt): a ring of ``SEARCH_POINTS`` at
    ``SEARCH_RADIUS_M``, visited in order around it (neighbours are a short step apart)."""
    return [SEARCH_RADIUS_M * np.array([math.cos(a), math.sin(a)])
            for a in np.linspace(0.0, 2 * math.pi, SEARCH_POINTS, endpoint=False)]


class PadShear:
    """The pads' mean marker displacement since the expert started: the tangential motion (gel-pad frame, mm)
    of the tube's surface point that sat at each pad's centre, as the tactile model computes the shear field
    from it (``GripperSim._motion_since_onset``). ``axial_mm``: along the pads' y (the gripper's z), positive
    when the tube slides up the fingers. It reads the simulation through the expert's session: the kit's
    ``touch()`` summarises the contact patch only, and a real sensor reads this from its markers."""

    def __init__(self, ctx: ExpertContext, body: str = "tube") -> None:
        self._sim = ctx._session.sim
        self._body = self._sim.model.body(body).id
        self._anchor = {pad: self._frames(pad) for pad in ("left", "right")}

    def _frames(self, pad: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        site = self._sim.model.site(f"{pad}_pad").id
        data = self._sim.data
        pad_pos, pad_mat = data.site_xpos[site].copy(), data.site_xmat[site].reshape(3, 3).copy()
        obj_pos, obj_mat = data.xpos[self._body].copy(), data.xmat[self._body].reshape(3, 3).copy()
        return pad_pos, pad_mat, obj_pos, obj_mat

    def tangential_mm(self, pad: str) -> np.ndarray:
        """(2,) the pad's shear displacement now, pad x and y, mm."""
        pad_pos0, _, obj_pos0, obj_mat0 = self._anchor[pad]
        anchor = obj_mat0.T @ (pad_pos0 - obj_pos0)  # the tube's point under the pad centre at the start
        pad_pos, pad_mat, obj_pos, obj_mat = self._frames(pad)
        return (pad_mat.T @ (obj_pos + obj_mat @ anchor - pad_pos))[:2] * 1000.0

    def axial_mm(self) -> float:
        return float(np.mean([self.tangential_mm(pad)[1] for pad in ("left", "right")]))

    def twist_rad(self, pad: str) -> float:
        """The tube's turn about the pad's normal since the start, rad (the marker field's rotation)."""
        _, pad_mat0, _, obj_mat0 = self._anchor[pad]
        _, pad_mat, _, obj_mat = self._frames(pad)
        turn = (pad_mat.T @ obj_mat) @ (pad_mat0.T @ obj_mat0).T
        return float(math.atan2(turn[1, 0] - turn[0, 1], turn[0, 0] + turn[1, 1]))

    def turn_rad(self) -> float:
        """The tube's turn about the gripper's x (the left pad's normal) since the start, rad."""
        return 0.5 * (self.twist_rad("left") - self.twist_rad("right"))

    def rebase(self) -> None:
        """Measure from now on (after the gripper turned around the tube on purpose)."""
        self._anchor = {pad: self._frames(pad) for pad in ("left", "right")}

    def end_in_hand_m(self, half_length_m: float) -> np.ndarray:
        """(3,) where the tube's lower end is in the gripper frame, m, as the pads tell it: the tube's centre
        (at the gripper origin when the expert started) slid by the shear (left pad x is gripper +y, right
        pad x is gripper -y, both pads' y is gripper +z), its axis turned about the pads' normal (left pad +z is
        gripper +x, the right pad's is -x) by the marker field's rotation."""
        left, right = self.tangential_mm("left"), self.tangential_mm("right")
        centre = np.array([0.0, 0.5 * (left[0] - right[0]), 0.5 * (left[1] + right[1])]) / 1000.0
        turn = self.turn_rad()
        return centre + half_length_m * np.array([0.0, math.sin(turn), -math.cos(turn)])


def hole_quat() -> np.ndarray:
    """The hole frame: world turned -30 deg about y (the axis leans toward -x)."""
    return quat_from_axis_angle((0.0, 1.0, 0.0), -TILT_RAD)


class InsertTube(Task):
    __doc__ = __doc__
    name = "insert_tube"
    gym_id = "univtac/InsertTube-v0"
    max_steps = 300
    primitive_names = ["probe", "retry", "insert", "hold", "straighten"]
    # each miss slides the tube up the pads by about 0.8 mm (the probe stops on that shear); UniVTAC allows 30 mm
    max_in_hand_slip_mm = 10.0
    # the pads' recorded slip (tactile/{pad}/slip_mm) adds up the sliding of every miss: 13 mm after
    # six misses (seed 78)
    max_pad_slip_mm = 20.0

    def __init__(self, config: TaskConfig, profile: SensorProfile, *, corrections: bool = True,
                 hole_contact: HoleContact | None = None, collider: str = "boxes", solver: str = "Newton") -> None:
        super().__init__(config, profile)
        self.corrections = corrections  # False: no retries after a miss (to measure what they are worth)
        # the stability study's knobs (benchmarks/insertion_stability.py); the defaults are the task's
        self.hole_contact = hole_contact or HoleContact()
        if collider not in ("boxes", "convex"):
            raise ValueError(f"collider must be 'boxes' or 'convex' (got {collider!r})")
        self.collider = collider
        self.solver = solver

    def sample_layout(self, rng: np.random.Generator) -> dict[str, Any]:
        x = HOLE_XYZ_M[0] + float(rng.uniform(-0.005, 0.005))
        y = HOLE_XYZ_M[1] + float(rng.uniform(-0.01, 0.01))
        r, a = float(rng.uniform(0.001, 0.004)), float(rng.uniform(-math.pi, math.pi))
        off = [r * math.cos(a), r * math.sin(a)]
        return {"hole_m": [x, y, HOLE_XYZ_M[2]], "first_offset_m": off}

    def objects(self) -> list[str]:
        return ["tube"]

    def hole_pose(self, layout: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        return np.asarray(layout["hole_m"], float), hole_quat()

    def start_pose(self, layout: dict[str, Any]) -> np.ndarray:
        pos, quat = self.hole_pose(layout)
        mat = quat_to_mat(quat)
        dx, dy = layout["first_offset_m"]
        centre = pos + mat @ np.array([dx, dy, TUBE_HALF_M + 0.002])
        return np.array([*centre, *quat, grip_opening_m(self.profile)])

    def scene_xml(self, layout: dict[str, Any]) -> str:
        pos, quat = self.hole_pose(layout)
        start = self.start_pose(layout)
        q = " ".join(f"{v:.9f}" for v in quat)
        params = GripperParams(mount="welded")
        attrs = self.hole_contact.attrs()
        if self.collider == "convex":
            assets, walls = BORE.convex_walls("bore", 48, attrs)
        else:
            assets, walls = "", BORE.walls_xml("bore", attrs=attrs)
        options = TASK_OPTION_XML.replace('noslip_iterations="4"', f'noslip_iterations="4" solver="{self.solver}"')
        return f"""<mujoco model="insert_tube">
  <compiler angle="radian" autolimits="true"/>
  {options}
  <asset>{STAGE_ASSETS_XML}
    {assets}
  </asset>
  <worldbody>{stage_xml()}
    <body name="hole" pos="{pos[0]} {pos[1]} {pos[2]}" quat="{q}">
      {walls}
      {square_plate_xml("surface", PLATE_HALF_M, PLATE_OPENING_HALF_M, PLATE_THICKNESS_M, "0.7 0.72 0.75 1", attrs)}
    </body>
    <body name="stand" pos="{pos[0]} {pos[1]} {pos[2] / 2 - 0.03}">
      <geom name="stand" type="box" size="0.03 0.03 {pos[2] / 2 - 0.03}" rgba="0.45 0.45 0.5 1" contype="0" conaffinity="0"/>
    </body>
    <body name="tube" pos="{start[0]} {start[1]} {start[2]}" quat="{q}">
      <freejoint name="tube_free"/>
      <geom name="tube" type="cylinder" size="{TUBE_RADIUS_M} {TUBE_HALF_M}" mass="{TUBE_MASS_KG}"
            rgba="0.85 0.9 0.95 1" condim="4"{attrs}/>
    </body>
    {gripper_body_xml(self.profile, params, tuple(start[:3]))}
  </worldbody>
  <contact>{PAD_CONTACT.pair_xml("tube")}</contact>
  <actuator>{gripper_actuator_xml(params)}</actuator>
  <equality>{gripper_equality_xml(params)}</equality>
</mujoco>"""

    def expert(self, ctx: ExpertContext) -> Iterator[Step]:
        pos, quat = self.hole_pose(ctx.layout)
        mat = quat_to_mat(quat)
        axis = mat[:, 2]
        first = ctx.target[:3].copy()
        offset = in_hole_frame(pos, quat, first)[:2]  # where the set-up aimed (the camera's estimate)
        shear = PadShear(ctx)
        across = np.array([1.0, 0.0])  # hole frame x: the gripper's x, the pads' normal, where the grip cannot give
        # (point in the hole frame relative to the first attempt, why it is probed); a point is dropped once probed
        plan: list[tuple[np.ndarray, str]] = [(np.zeros(2), "first")] + [(p, "ring") for p in search_ring()]
        stepped_across = False  # the steps across the grasp are made once, after the first miss on the chamfer
        ctx.memory.update(attempts=0, inside=False)
        blocked_by = 0.0  # the last probe's axial shear, mm
        last = np.zeros(2)
        chamfer_depth_m = 0.0  # how far below the entrance the tube's end got on the chamfer, m
        while plan:
            step, why = plan.pop(0)
            if ctx.memory["attempts"] > 0:
                if not (self.corrections and ctx.corrections_enabled):
                    break
                if why == "ring":
                    ctx.correction("search step after a miss", "axial shear: the tube slid up the pads by more "
                                   f"than {BLOCKED_SHEAR_MM} mm during the probe (blocked by the surface)",
                                   shear_mm=blocked_by, step_x_mm=step[0] * 1000, step_y_mm=step[1] * 1000,
                                   move_mm=float(np.linalg.norm(step - last) * 1000))
                else:
                    ctx.correction("step across the grasp after a miss on the chamfer",
                                   f"axial shear over {BLOCKED_SHEAR_MM} mm after the tube's end went "
                                   f"{CHAMFER_MISS_M * 1000:.1f} mm or more below the entrance (hand travel less "
                                   "the slide up the pads): on the chamfer, the hole across the grasp",
                                   shear_mm=blocked_by, end_depth_mm=chamfer_depth_m * 1000, step_x_mm=step[0] * 1000,
                                   step_y_mm=step[1] * 1000, move_mm=float(np.linalg.norm(step - last) * 1000))
            # aim the tube's end, wherever the pads say it has moved to in the hand
            end = pos + mat @ np.array([*(offset + step), PROBE_START_M])
            above = end - mat @ shear.end_in_hand_m(TUBE_HALF_M)
            if ctx.memory["attempts"] > 0:
                yield from move_to(ctx, ctx.target[:3] + axis * 0.002, speed_m_s=0.04, primitive="retry")
                yield from move_to(ctx, above + axis * 0.002, speed_m_s=0.04, primitive="retry")
            yield from move_to(ctx, above, speed_m_s=0.04, primitive="probe")
            ctx.memory["attempts"] += 1
            last = step
            before = shear.axial_mm()
            blocked_by = 0.0
            for probe in move_to(ctx, above - axis * PROBE_TRAVEL_M, speed_m_s=PROBE_SPEED_M_S, primitive="probe"):
                yield probe
                blocked_by = shear.axial_mm() - before
                if blocked_by > BLOCKED_SHEAR_MM:
                    break
            if blocked_by <= BLOCKED_SHEAR_MM:
                ctx.memory["inside"] = True
                break
            # how far below the entrance the tube's end got: the hand's travel less the slide up the pads
            end_depth_m = float((above - ctx.target[:3]) @ axis) - PROBE_START_M - blocked_by / 1000.0
            if end_depth_m >= CHAMFER_MISS_M and why == "ring" and not stepped_across:
                stepped_across, chamfer_depth_m = True, end_depth_m
                # the chamfer let the tube in partly: the hole is within about 2.5 mm, and along the pads'
                # normal, where the grip holds the tube rigidly (across it the tube turns in the grasp and
                # slides in from 2.2 mm); probe either side, first the one nearer the first attempt (whose
                # error is 1-4 mm, any distance as likely: the nearer ring is the denser)
                sides = [step + side * CHAMFER_STEP_M * across for side in (1.0, -1.0)]
                sides.sort(key=lambda p: float(np.linalg.norm(p)))
                plan[:0] = [(p, "across") for p in sides]
        if not ctx.memory["inside"]:  # every probe was blocked: pushing on would only drive the tube up the pads
            yield from wait(ctx, 0.2)
            return
        hand = mat  # the gripper's orientation (world), the hole frame's until the tube is straightened
        turn = shear.turn_rad()
        if abs(turn) > STRAIGHTEN_TURN_RAD and self.corrections and ctx.corrections_enabled:
            # the chamfer turned the tube in the grasp: pushed crooked it wedges in the bore and slides up the pads
            ctx.correction("straighten the tube", "marker field's rotation: the tube turned in the grasp by more "
                           f"than {math.degrees(STRAIGHTEN_TURN_RAD):.1f} deg", turn_deg=math.degrees(turn),
                           pivot_deg=-math.degrees(turn))
            tip = ctx.target[:3] + mat @ shear.end_in_hand_m(TUBE_HALF_M)
            yield from rotate_about(ctx, mat[:, 0], -turn, tip, turn_rad_s=STRAIGHTEN_RATE_RAD_S, primitive="straighten")
            hand = quat_to_mat(ctx.target[3:7])
        # push until the tube's end (the hand's travel less what the tube slid up the pads) is INSERT_DEPTH_M deep
        end = pos + mat @ np.array([*in_hole_frame(pos, quat, ctx.target[:3] + hand @ shear.end_in_hand_m(TUBE_HALF_M))[:2],
                                    -INSERT_DEPTH_M])
        goal = end - hand @ shear.end_in_hand_m(TUBE_HALF_M)
        yield from move_to(ctx, goal, speed_m_s=INSERT_SPEED_M_S, primitive="insert")
        yield from wait(ctx, 0.2)

    def tube_end_in_hole(self, layout: dict[str, Any], tube_pose: np.ndarray) -> np.ndarray:
        """(3,) the tube's lower end in the hole frame, m, for the tube at ``tube_pose`` (7,) world."""
        pos, quat = self.hole_pose(layout)
        return in_hole_frame(pos, quat, tube_pose[:3] - quat_to_mat(tube_pose[3:])[:, 2] * TUBE_HALF_M)

    def success(self, state: TaskState) -> bool:
        end = self.tube_end_in_hole(state.layout, state.objects["tube"])
        return bool(math.hypot(end[0], end[1]) < 0.005 and -end[2] >= 0.03)
