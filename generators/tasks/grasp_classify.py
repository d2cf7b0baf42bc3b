"""Grasp Classify: touch two look-alike cylinders, tell the knurled one from the plain one, sort them onto pads.

Description
    Two upright cylinders stand side by side on the table: the same size, mass and colour, so the cameras
    cannot tell them apart; one has a knurled surface (a diamond knurl, modelled in the tactile contact
    geometry only), the other is plain. Two goal pads lie 16 cm apart beyond them: knurled ('rough') goes on
    the orange pad, plain on the green one. The expert picks each cylinder in turn with the closed-loop
    tactile grasp, classifies it from its contact patches alone, carries it to its class's pad, places and
    releases it, and re-places it if the head camera sees it standing off the pad's centre.
Objects (procedural; plausible real sizes)
    ``cylinder_0``, ``cylinder_1`` (named by the spot they start on, not by class): cylinders of diameter
    4 cm and height 10 cm, 100 g (a plastic grip or a spice jar), grey-blue, origin at the centre, local +z
    along the axis. The knurl:
    ``CylinderGrooves`` of pitch 1.6 mm and depth 0.6 mm (half of each pitch cut, rings and axial
    grooves), deeper than the grasp presses, so the gel touches only the diamond ridges. The first object is
    the tactile object (``cylinder_0``: its pose in each pad frame is recorded as
    ``tactile/{pad}/object_pose``); the other's pad-frame pose follows from its world pose
    (``scene/objects/cylinder_1/pose``) and the pad's (``tactile/{pad}/pad_pose``).
    Goal pads (fixed, part of the table): 8 x 8 cm, 3 mm thick; orange 'rough' pad centred at
    (0.09, -0.08) m, green 'plain' pad at (0.09, +0.08) m. Ground: a plane, friction 0.8.
Randomisation (seeded)
    which cylinder stands on which spot (p = 0.5); spot 0 at (-0.07, +0.05) m and spot 1 at (-0.07, -0.05)
    m, each moved by U(-1, 1) cm in x and y. The camera's estimate of each cylinder's position is off by
    U(-4, 4) mm in x and y; its estimate of each pad's centre is off by U(0, 3) cm in a uniform direction
    (the pads are seen from afar and lie flat), the error a placement from that estimate inherits.
Expert (closed loop; the decisions are recorded in ``memory``, corrections in ``memory['corrections']``)
    for spot 0, then spot 1: move above the seen cylinder (top-down, the fingers closing across the line to
    the other cylinder), descend to 6 cm above its base, tactile grasp to 0.5 mm (0.3 mm on the GF225 and
    Xense WS); **classify from touch**, never from the layout: the mean over both pads of
    ``TouchReading.fill`` (contact cells over the patch's oriented bounding box) is 0.66-0.92 on the plain
    cylinder and 0.16-0.36 on the knurled one (ridges only; seeds 0-99); below 0.45 reads 'rough'.
    ``memory['classes']`` maps spot to class and ``memory['fill']`` spot to both pads' fill. The cylinder's
    offset along the pads (from the patch centroids) is taken out of the place target. Lift 7 cm,
    carry above the seen centre of the class's pad, lower until the base is 2 mm above the pad, release, lift
    away 6 cm. **Re-place after a miss**: the head camera then sees the cylinder standing ``miss`` from its
    pad's centre (the offset of a placed object from the pad it stands on is seen well, unlike the pad's
    position from afar); if ``miss > 1.2 cm``, re-grasp it, lift 2 cm, move it by the seen offset, place and
    release again (at most twice; recorded with ``miss_mm`` and the offset). ``ctx.corrections_enabled =
    False`` (``run_expert(..., corrections=False)``) skips the re-place.
Success
    both cylinders stand on their class's pad: centre within 2 cm (xy) of the pad's centre, base within 1 cm
    of the pad's top, axis tilted less than 15 deg from vertical.
Safety (per step; a violation makes the rollout invalid)
    deepest pad indentation <= the sensor's safe limit (1.5 mm Mini, 0.8 mm GF225 / Xense WS); a held cylinder
    moves at most 5 mm in the gripper frame once both pads grip it (the kit measures it on whichever cylinder
    both pads touch).
Step limit
    1250 policy steps (25 s at 50 Hz): the expert takes 480-530 steps for its two pick-and-places and about
    170 more for each re-place (at most four: 1210; 480-875 steps on seeds 0-99). UniVTAC's single-object
    version (the policy starts holding the one prism 5 cm up and only places it) allows 300 at 60 Hz.
Version history
    v0: first version.
"""

from __future__ import annotations

import math
from collections.abc import Generator, Iterator
from typing import Any

import numpy as np

from univtac_data.generators.scene.cameras import look_at_xyaxes
from univtac_data.generators.scene.contact_pairs import TASK_OPTION_XML, PadContact
from univtac_data.generators.scene.geometry import quat_to_mat
from univtac_data.generators.scene.gripper import (
    MAX_OPENING_M,
    GripperParams,
    gripper_actuator_xml,
    gripper_body_xml,
    gripper_equality_xml,
)
from univtac_data.generators.scene.sim import GeomTexture
from univtac_data.generators.scene.texture import CylinderGrooves
from univtac_data.generators.scene.touch import TouchReading
from univtac_data.generators.tasks.base import ExpertContext, Step, Task, TaskState, yaw_quat
from univtac_data.generators.tasks.motions import GraspLaw, close_until, grasp_depth_mm, move_to, open_to
from univtac_data.schema.sensors import SensorProfile

RADIUS_M = 0.02
HEIGHT_M = 0.10
MASS_KG = 0.10
CYLINDER_RGBA = "0.35 0.45 0.6 1"
KNURL = CylinderGrooves(pitch_mm=1.6, depth_mm=0.6, duty=0.5, axial=True)
CLASSES = ("rough", "plain")
# bodies named by the spot they start on, not by class: the metadata must not give away what only touch can tell
CYLINDER_NAMES = ("cylinder_0", "cylinder_1")
GOAL_PADS_XY_M = {"rough": (0.09, -0.08), "plain": (0.09, 0.08)}  # centres, 16 cm apart
GOAL_PAD_HALF_M = (0.04, 0.04, 0.0015)  # half sizes: 8 x 8 cm, 3 mm thick
GOAL_PAD_RGBA = {"rough": "0.95 0.5 0.1 1", "plain": "0.2 0.65 0.3 1"}
SPOTS_XY_M = ((-0.07, 0.05), (-0.07, -0.05))
SPOT_NOISE_M = 0.01
SEEN_CYLINDER_ERROR_M = 0.004
SEEN_PAD_ERROR_MAX_M = 0.03
# mean patch fill under this reads 'rough': a convex patch (a plain cylinder, square or tilted in the grasp)
# fills at least about half its bounding box, the knurl's ridges (a quarter of its surface) about a quarter
FILL_ROUGH_BELOW = 0.45
GRASP_HEIGHT_M = 0.06  # gripper centre above the cylinder's base when grasping
LIFT_M = 0.07  # the carry paths pass no standing cylinder: the base only has to clear the pads
AWAY_M = 0.06
PLACE_CLEARANCE_M = 0.002
MISS_TOLERANCE_M = 0.012  # re-place when the camera sees the cylinder this far from its pad's centre
MAX_REPLACES = 2
OPEN_MARGIN_M = 0.012  # opening beyond the diameter when approaching or releasing
SUCCESS_RADIUS_M = 0.02
SUCCESS_HEIGHT_M = 0.01
MAX_TILT_RAD = math.radians(15.0)


TABLE_ASSETS_XML = """
    <texture name="grid" type="2d" builtin="checker" rgb1="0.82 0.82 0.84" rgb2="0.74 0.74 0.77" width="256" height="256"/>
    <material name="table" texture="grid" texrepeat="8 8"/>"""
HEAD_EYE_M = (0.42, 0.0, 0.27)


def table_and_pads_xml() -> str:
    """MJCF (world body children) of the scene's lights, the table (material ``table`` of ``TABLE_ASSETS_XML``)
    and the two goal pads."""
    pads = []
    for cls in CLASSES:
        px, py = GOAL_PADS_XY_M[cls]
        hx, hy, hz = GOAL_PAD_HALF_M
        pads.append(f'\n    <geom name="{cls}_pad" type="box" pos="{px} {py} {hz}" size="{hx} {hy} {hz}" '
                    f'rgba="{GOAL_PAD_RGBA[cls]}" friction="0.8 0.005 0.0001"/>')
    return f"""
    <light pos="0.3 -0.4 1.0" dir="-0.3 0.4 -1"/>
    <light pos="-0.4 0.3 0.8" dir="0.4 -0.3 -1" diffuse="0.4 0.4 0.4"/>
    <geom name="ground" type="plane" size="0.6 0.6 0.01" material="table" friction="0.8 0.005 0.0001"/>
    {''.join(pads)}"""


def head_camera_xml() -> str:
    """The head camera, looking at the table between the cylinders and the pads."""
    eye = HEAD_EYE_M
    return (f'<camera name="head" pos="{eye[0]} {eye[1]} {eye[2]}" '
            f'xyaxes="{look_at_xyaxes(eye, (0.0, 0.0, 0.04))}" fovy="45"/>')


def grasp_law(profile: SensorProfile) -> GraspLaw:
    """The kit's tactile grasp to 0.5 mm on the GelSight Mini, 0.3 mm on the sensors whose safe limit is 0.8 mm.
    Its slow phase also pushes a cylinder that one pad reached first across to the other (the camera's centre
    is off by up to 4 mm): 12 mm/s rather than UniVTAC's 6 halves that push."""
    return GraspLaw(threshold_mm=grasp_depth_mm(profile), v_slow_m_s=0.012)


def current_yaw(quat: np.ndarray) -> float:
    """Yaw (rad) of a top-down gripper orientation ``yaw_quat(yaw)``."""
    return 2.0 * math.atan2(float(quat[3]), float(quat[0]))


def closing_yaw(at_xy: np.ndarray, other_xy: np.ndarray, near_yaw: float) -> float:
    """Gripper yaw (rad) that closes the fingers perpendicular to the line from ``at_xy`` to ``other_xy``
    (m, world); of the two such yaws (the gripper is symmetric), the one nearer ``near_yaw``."""
    d = np.asarray(other_xy, float) - np.asarray(at_xy, float)
    yaw = math.atan2(d[1], d[0]) + math.pi / 2
    return yaw + math.pi * round((near_yaw - yaw) / math.pi)


def classify_from_touch(left: TouchReading, right: TouchReading) -> tuple[str, float]:
    """('rough' or 'plain', mean fill of the two contact patches): a knurl leaves cells without contact
    inside the patch (its grooves), a plain surface fills the patch's bounding box."""
    fill = 0.5 * (left.fill + right.fill)
    return ("rough" if fill < FILL_ROUGH_BELOW else "plain"), fill


def offset_along_pads_m(left: TouchReading, right: TouchReading) -> float:
    """Where the held cylinder's axis sits along the gripper's y axis, m: the left pad's x is gripper +y,
    the right pad's x is gripper -y, so half the difference of the two patch centroids."""
    return 0.5 * (left.centroid_mm[0] - right.centroid_mm[0]) / 1000.0


class GraspClassify(Task):
    __doc__ = __doc__
    name = "grasp_classify"
    gym_id = "univtac/GraspClassify-v0"
    max_steps = 1250
    primitive_names = ["move", "grasp", "lift", "carry", "place", "release", "regrasp"]

    # --- scene -------------------------------------------------------------------------------------
    def sample_layout(self, rng: np.random.Generator) -> dict[str, Any]:
        rough_spot = int(rng.integers(2))
        spots = [[x + float(dx), y + float(dy)]
                 for (x, y), (dx, dy) in zip(SPOTS_XY_M, rng.uniform(-SPOT_NOISE_M, SPOT_NOISE_M, (2, 2)))]
        seen_spot_error = [[float(v) for v in rng.uniform(-SEEN_CYLINDER_ERROR_M, SEEN_CYLINDER_ERROR_M, 2)]
                           for _ in spots]
        seen_pad_error = {}
        for cls in CLASSES:
            r, a = float(rng.uniform(0.0, SEEN_PAD_ERROR_MAX_M)), float(rng.uniform(-math.pi, math.pi))
            seen_pad_error[cls] = [r * math.cos(a), r * math.sin(a)]
        return {"radius_m": RADIUS_M, "height_m": HEIGHT_M, "mass_kg": MASS_KG, "rough_spot": rough_spot,
                "spots_m": spots, "seen_spot_error_m": seen_spot_error, "seen_pad_error_m": seen_pad_error}

    def objects(self) -> list[str]:
        return list(CYLINDER_NAMES)

    def textures(self, layout: dict[str, Any]) -> list[GeomTexture]:
        return [GeomTexture(self.cylinder_of(layout, "rough"), KNURL)]

    @staticmethod
    def cylinder_of(layout: dict[str, Any], cls: str) -> str:
        """The body of class ``cls`` ('rough' or 'plain') in ``layout``."""
        spot = layout["rough_spot"] if cls == "rough" else 1 - layout["rough_spot"]
        return CYLINDER_NAMES[spot]

    @staticmethod
    def true_classes(layout: dict[str, Any]) -> dict[str, str]:
        """Ground truth per spot ('0', '1') -> 'rough' or 'plain', in the form of the expert's
        ``memory['classes']``, to score its classification (the expert itself never reads it)."""
        return {str(spot): "rough" if spot == layout["rough_spot"] else "plain" for spot in (0, 1)}

    @staticmethod
    def cylinder_xy(layout: dict[str, Any], cls: str) -> tuple[float, float]:
        """Where the layout stands the cylinder of class ``cls`` (x, y m, world)."""
        spot = layout["rough_spot"] if cls == "rough" else 1 - layout["rough_spot"]
        x, y = layout["spots_m"][spot]
        return float(x), float(y)

    def scene_xml(self, layout: dict[str, Any]) -> str:
        r, half = layout["radius_m"], layout["height_m"] / 2
        cylinders = []
        for cls in CLASSES:
            name = self.cylinder_of(layout, cls)
            x, y = self.cylinder_xy(layout, cls)
            # identical MJCF apart from the name: the knurl lives only in the tactile gap field
            cylinders.append(f"""
    <body name="{name}" pos="{x} {y} {half + 0.0005}">
      <freejoint name="{name}_free"/>
      <geom name="{name}" type="cylinder" size="{r} {half}" mass="{layout['mass_kg']}" rgba="{CYLINDER_RGBA}"
            friction="0.8 0.005 0.0001" condim="4"/>
    </body>""")
        params = GripperParams(mount="welded")
        contacts = "".join(PadContact().pair_xml(name) for name in self.objects())
        return f"""<mujoco model="grasp_classify">
  <compiler angle="radian" autolimits="true"/>
  {TASK_OPTION_XML}
  <asset>{TABLE_ASSETS_XML}
  </asset>
  <worldbody>{table_and_pads_xml()}{''.join(cylinders)}
    {gripper_body_xml(self.profile, params, (0.0, 0.0, 0.3))}
    {head_camera_xml()}
  </worldbody>
  <contact>{contacts}</contact>
  <actuator>{gripper_actuator_xml(params)}</actuator>
  <equality>{gripper_equality_xml(params)}</equality>
</mujoco>"""

    # --- what the camera estimates -----------------------------------------------------------------
    @staticmethod
    def seen_spot(layout: dict[str, Any], spot: int) -> np.ndarray:
        """The camera's estimate of the cylinder centre on ``spot``, (3,) m world."""
        x, y = layout["spots_m"][spot]
        ex, ey = layout["seen_spot_error_m"][spot]
        return np.array([x + ex, y + ey, layout["height_m"] / 2])

    @staticmethod
    def seen_pad(layout: dict[str, Any], cls: str) -> np.ndarray:
        """The camera's estimate of the centre of ``cls``'s goal pad, (2,) m world."""
        return np.add(GOAL_PADS_XY_M[cls], layout["seen_pad_error_m"][cls])

    def start_pose(self, layout: dict[str, Any]) -> np.ndarray:
        above, other = self.seen_spot(layout, 0), self.seen_spot(layout, 1)
        quat = yaw_quat(closing_yaw(above[:2], other[:2], 0.0))
        return np.array([above[0], above[1], GRASP_HEIGHT_M + 0.10, *quat, MAX_OPENING_M])

    # --- behaviour ---------------------------------------------------------------------------------
    def expert(self, ctx: ExpertContext) -> Iterator[Step]:
        layout = ctx.layout
        ctx.memory.update(classes={}, fill={}, replaces=0)
        for spot in (0, 1):
            seen = self.seen_spot(layout, spot)
            touch = yield from self._pick(ctx, seen, "grasp")
            cls, _ = classify_from_touch(touch["left"], touch["right"])
            ctx.memory["classes"][str(spot)] = cls
            ctx.memory["fill"][str(spot)] = [touch["left"].fill, touch["right"].fill]
            # the held axis sits off the gripper centre by this much (world): aim the cylinder, not the hand
            hand_to_axis = quat_to_mat(ctx.target[3:7])[:, 1] * offset_along_pads_m(touch["left"], touch["right"])
            yield from move_to(ctx, ctx.target[:3] + [0.0, 0.0, LIFT_M], speed_m_s=0.12, primitive="lift")
            goal = self.seen_pad(layout, cls)
            yield from move_to(ctx, [goal[0] - hand_to_axis[0], goal[1] - hand_to_axis[1], ctx.target[2]],
                               speed_m_s=0.20, primitive="carry")
            yield from self._place(ctx)
            for _ in range(MAX_REPLACES):
                if not ctx.corrections_enabled:
                    break
                placed = self._seen_near(ctx, ctx.target[:2] + hand_to_axis[:2])
                offset = np.asarray(GOAL_PADS_XY_M[cls]) - placed[:2]
                miss = float(np.linalg.norm(offset))
                if miss <= MISS_TOLERANCE_M:
                    break
                ctx.correction("re-place after a miss", "head camera: placed cylinder centre to its pad's centre",
                               miss_mm=miss * 1000, dx_mm=offset[0] * 1000, dy_mm=offset[1] * 1000, spot=spot)
                ctx.memory["replaces"] += 1
                touch = yield from self._pick(ctx, placed[:3] + [0.0, 0.0, 2 * GOAL_PAD_HALF_M[2]], "regrasp")
                hand_to_axis = quat_to_mat(ctx.target[3:7])[:, 1] * offset_along_pads_m(touch["left"], touch["right"])
                yield from move_to(ctx, ctx.target[:3] + [0.0, 0.0, 0.02], speed_m_s=0.05, primitive="lift")
                yield from move_to(ctx, ctx.target[:3] + [offset[0], offset[1], 0.0], speed_m_s=0.05,
                                   primitive="carry")
                yield from self._place(ctx)

    def _pick(self, ctx: ExpertContext, centre_m: np.ndarray,
              primitive: str) -> Generator[Step, None, dict[str, TouchReading]]:
        """Approach the cylinder whose centre the camera sees at ``centre_m`` (3,) m (its base at
        ``centre_m[2] - height / 2``) from above and grasp it with the tactile law; returns the touch.

        The fingers close perpendicular to the line to the other cylinder, so that they sweep no closer to it.
        """
        layout = ctx.layout
        base_z = float(centre_m[2]) - layout["height_m"] / 2
        other = max((ctx.object_pose(name)[:2] for name in self.objects()),
                    key=lambda xy: float(np.linalg.norm(xy - centre_m[:2])))
        quat = yaw_quat(closing_yaw(centre_m[:2], other, current_yaw(ctx.target[3:7])))
        width = 2 * layout["radius_m"] + OPEN_MARGIN_M
        above_z = max(ctx.target[2], base_z + GRASP_HEIGHT_M + 0.07)
        yield from move_to(ctx, [centre_m[0], centre_m[1], above_z], quat, width=width, speed_m_s=0.20, turn_rad_s=3.0,
                           primitive="move" if primitive == "grasp" else primitive)
        yield from move_to(ctx, [centre_m[0], centre_m[1], base_z + GRASP_HEIGHT_M], speed_m_s=0.12,
                           primitive="move" if primitive == "grasp" else primitive)
        yield from close_until(ctx, grasp_law(self.profile), primitive=primitive)
        return ctx.touch()

    def _place(self, ctx: ExpertContext) -> Iterator[Step]:
        """Lower the held cylinder until its base is ``PLACE_CLEARANCE_M`` above the pad, release it, and
        lift away."""
        hand_z = 2 * GOAL_PAD_HALF_M[2] + GRASP_HEIGHT_M + PLACE_CLEARANCE_M
        yield from move_to(ctx, [ctx.target[0], ctx.target[1], hand_z], speed_m_s=0.10, primitive="place")
        yield from open_to(ctx, 2 * ctx.layout["radius_m"] + OPEN_MARGIN_M, primitive="release")
        yield from move_to(ctx, ctx.target[:3] + [0.0, 0.0, AWAY_M], speed_m_s=0.15)

    def _seen_near(self, ctx: ExpertContext, xy_m: np.ndarray) -> np.ndarray:
        """The head camera's view of the cylinder standing nearest ``xy_m``: (7,) pose. The two look the same,
        so the camera can only tell which one it is by where it stands."""
        poses = [ctx.object_pose(name) for name in self.objects()]
        return min(poses, key=lambda p: float(np.linalg.norm(p[:2] - xy_m)))

    # --- checks ------------------------------------------------------------------------------------
    def success(self, state: TaskState) -> bool:
        return all(on_its_pad(state.objects[self.cylinder_of(state.layout, cls)], cls) for cls in CLASSES)


def on_its_pad(pose: np.ndarray, cls: str) -> bool:
    """Whether a cylinder at ``pose`` (7,) world is on ``cls``'s pad: centre within ``SUCCESS_RADIUS_M`` (xy) of
    the pad's centre, base within ``SUCCESS_HEIGHT_M`` of its top, axis tilted less than ``MAX_TILT_RAD``."""
    axis = quat_to_mat(pose[3:])[:, 2]
    tilt = math.acos(min(1.0, abs(float(axis[2]))))
    base_z = pose[2] - abs(float(axis[2])) * HEIGHT_M / 2
    return bool(np.linalg.norm(pose[:2] - np.asarray(GOAL_PADS_XY_M[cls])) < SUCCESS_RADIUS_M
                and abs(base_z - 2 * GOAL_PAD_HALF_M[2]) < SUCCESS_HEIGHT_M and tilt < MAX_TILT_RAD)


__all__ = ["GraspClassify", "classify_from_touch", "closing_yaw", "grasp_law", "offset_along_pads_m", "on_its_pad"]
