"""Insert HDMI: a plug held crooked in the gripper is read straight from touch and pushed into its socket.

Description
    The gripper holds an HDMI plug by its grip, turned in the grasp by an unknown angle about the pad normal
    (the plug's axis tilted sideways in the plane of its wide faces), a centimetre above a fixed socket. The
    expert reads the plug's tilt from the orientation of the contact patches on the pads, turns the gripper
    to stand the plug upright, places the tip above the socket the camera sees, and pushes down. When the tip
    catches (the load on the pads rises before the plug is in) it lifts, steps the way the pads felt the
    socket push the tip, and tries again.
Objects (procedural; HDMI type A sizes)
    ``plug`` (free body, 15 g; origin at the centre of the shell's tip, local +z along the plug axis away from
    the tip, local x along the 14 mm width): metal shell 14.0 x 4.5 x 10 mm (MJCF ``plug_shell``), overmold
    20 x 8 x 22 mm above it (``plug_body``), and on the overmold's wide faces a grip 20 x 9.2 x 14 mm
    (``plug``, the geom the pads hold: the only part they touch; its patch is a rectangle well inside the
    25.25 x 20.75 mm gel whatever the tilt, so the patch shows the tilt as its orientation).
    ``socket`` (fixed; top face 30 mm above the table): a receptacle 14.4 x 4.9 mm (0.4 mm total clearance on
    each axis), 12 mm deep, with a 1 mm x 45 deg lead-in on all four edges, built from boxes (walls, a top
    layer, four rotated chamfer boxes, a floor). The shell and the socket collide (contype 2); the pads touch
    only the grip.
Randomisation (seeded)
    socket centre x, y U(-5, 5) mm; the plug's turn in the grasp about the pad normal +-U(5, 15) deg; its
    offset along the pad U(-1, 1) mm. The camera's estimate of the socket centre is off by U(0, 2) mm in a
    uniform direction (the lead-in catches 1.2); the set-up places the gripper above that estimate (the tip then misses by up to
    about 6 mm because of the plug's tilt).
Expert (closed loop; the signal and size of each correction are in ``memory['corrections']``)
    **straighten the plug**: each pad's contact patch is the grip's rectangle, its long axis along the plug's
    width; the patch's direction on the two pads (mirror images) gives the plug's tilt in the grasp; turn the
    gripper by minus that angle about the pad normal through the gripper centre; the patch centroids give
    the plug's offset along the pads, taken out of the target. Move the tip 3 mm above the seen socket;
    **push** down at 10 mm/s while watching the pads. **Nudge when it jams** (force rise without
    progress): the load on the pads (their summed shear along the plug axis, ``scene.pad_forces``) above
    1.5 N before the tip is 8 mm in (a free plug loads them with its weight, 0.15 N). The pads also feel
    which way the socket pushes the tip: along the plug's width as shear along the pads, across it as the
    difference of the two pads' normal forces. Where it caught tells whether to believe them: with the tip
    at least 0.3 mm below the face (the gripper's height less the grip's offset) it is on the 1 mm lead-in,
    whose slope pushes it towards the slot, so a push above 0.3 N is followed: lift 1 mm and step 0.3 mm
    (the clearance is 0.2 mm a side) that way on that axis, halved each time the push on an axis turns
    round, down to 0.1 mm; with no such push the tip is within the clearance, and the step goes to the next
    point of a 0.2 mm ring around it. With the tip on the face the lateral readings point nowhere (a load
    there keeps its sign while the tip wanders millimetres off), so the step goes to the next point of a
    ring (1.2 mm, then 2.4 mm, golden-angle spaced) around where the first attempt or the last push led,
    never more than 2.5 mm from the first attempt. At most 14 nudges; the plug's turn in the grasp (from
    the patches) is read each time and straightened if it changed. Recorded per nudge: the load and the
    pushes (N), the tip's depth below the face (mm), the turn (deg), the step along and across the plug
    (mm).
    With corrections switched off the expert neither straightens the plug nor nudges.
Success
    the plug's tip within 5 mm (x, y) of the receptacle's centre and less than 5 mm above full depth (at
    least 5 mm in), its axis within 15 deg of vertical.
Safety (per step; a violation makes the rollout invalid)
    deepest pad indentation <= the sensor's safe limit (1.5 mm Mini, 0.8 mm GF225 / Xense WS); the plug moves
    at most 5 mm in the gripper frame once both pads grip it.
Step limit
    600 policy steps (12 s at 50 Hz), UniVTAC's; the expert takes about 100-250.
Version history
    v0: first version (the environment). Its expert since: the nudges follow the pads' lateral push only
    with the tip on the lead-in, in steps of the clearance's size (0.3 mm, was 0.8 from anywhere), and
    search a 0.2 mm ring there; on seeds 100-599 it went from 470 to 500 of 500.
"""

from __future__ import annotations

import math
from collections.abc import Generator, Iterator
from typing import Any

import numpy as np

from univtac_data.generators.scene.contact_pairs import TASK_OPTION_XML, PadContact
from univtac_data.generators.scene.geometry import quat_from_axis_angle, quat_mul, quat_to_mat
from univtac_data.generators.scene.gripper import GripperParams, gripper_actuator_xml, gripper_body_xml, gripper_equality_xml
from univtac_data.generators.scene.stage import STAGE_ASSETS_XML, stage_xml
from univtac_data.generators.scene.touch import TouchReading
from univtac_data.generators.tasks.base import ExpertContext, Step, Task, TaskState, yaw_quat
from univtac_data.generators.tasks.motions import held_opening_m, move_to, rotate_about, wait

SHELL_HALF_M = (0.0070, 0.00225, 0.0050)
BODY_HALF_M = (0.010, 0.0040, 0.011)
GRIP_HALF_M = (0.010, 0.0046, 0.007)
GRIP_CENTRE_M = 0.021  # above the tip
MASS_KG = (0.005, 0.008, 0.002)  # shell, overmold, grip
SOCKET_TOP_M = 0.030
SLOT_HALF_M = (0.0072, 0.00245)
SLOT_DEPTH_M = 0.012
CHAMFER_M = 0.001
FULL_DEPTH_M = 2 * SHELL_HALF_M[2]  # the overmold meets the socket's face
TILT_RANGE_RAD = (math.radians(5.0), math.radians(15.0))
SEEN_ERROR_MAX_M = 0.002
APPROACH_M = 0.003  # tip above the socket face before pushing
PUSH_SPEED_M_S = 0.010
JAM_LOAD_N = 1.5
NUDGE_TURN_RAD = math.radians(0.4)
NUDGE_PUSH_N = 0.3
SEARCH_STEP_M = 0.0012  # a step of the search when the pads feel no lateral push
SEARCH_TURN_RAD = math.radians(137.5)  # successive search directions spread evenly (golden angle)
NUDGE_M = 0.0003  # the first step towards a push: the slot's clearance is 0.2 mm a side
LIFT_M = 0.001
MAX_NUDGES = 14
MAX_WANDER_M = 0.0025  # the nudges stay this close to the first attempt (the camera is off by 2 mm at most)
LEAD_IN_DEPTH_M = 0.0003  # a tip caught this far below the face is on the lead-in, within 1 mm of the slot
LEAD_IN_SEARCH_M = 0.0002  # a step of the search from there: the clearance a side
SUCCESS_XY_M = 0.005
SUCCESS_ABOVE_M = 0.005
MAX_TILT_RAD = math.radians(15.0)
# Plug-socket contact: MuJoCo's default (solref 0.02 s, solimp 0.9-0.95) scales with the 15 g plug and lets a
# 6 N push sink the overmold 1 mm into the socket's face; a 2 ms time constant and impedance 0.99 hold it
# to a few hundredths (benchmarks/key_detent_stability.py measures the same trade on the key's stop)
STIFF = 'solref="0.002 1" solimp="0.99 0.99 0.001"'
GRIPPER_YAW = math.pi / 2  # closing axis (gripper x) along world y = the plug's thin axis


def tilt_from_touch(left: TouchReading, right: TouchReading) -> float:
    """The plug's turn in the grasp about the pad normal (gripper +x), rad, from the two patches' long axes.

    The grip's face is a 20 x 14 mm rectangle whose long side runs along the plug's width; upright it lies
    along each pad's x. The pads face each other, so a turn shows with opposite signs in their frames
    (``axis_angle_rad`` is measured from each pad's own +x, and the left pad's +x is the right pad's -x)."""
    return 0.5 * (left.axis_angle_rad - right.axis_angle_rad)


def offset_along_pads_m(left: TouchReading, right: TouchReading) -> float:
    """Where the grip's centre sits along gripper +y, m: left pad x is gripper +y, right pad x is gripper -y."""
    return 0.5 * (left.centroid_mm[0] - right.centroid_mm[0]) / 1000.0


class InsertHDMI(Task):
    __doc__ = __doc__
    name = "insert_hdmi"
    gym_id = "univtac/InsertHDMI-v0"
    max_steps = 600
    primitive_names = ["move", "align", "push", "nudge", "hold"]

    def sample_layout(self, rng: np.random.Generator) -> dict[str, Any]:
        lo, hi = TILT_RANGE_RAD
        r, a = float(rng.uniform(0.0, SEEN_ERROR_MAX_M)), float(rng.uniform(-math.pi, math.pi))
        return {"socket_xy_m": [float(v) for v in rng.uniform(-0.005, 0.005, 2)],
                "tilt_rad": float(rng.uniform(lo, hi) * rng.choice((-1.0, 1.0))),
                "along_pad_m": float(rng.uniform(-0.001, 0.001)),
                "seen_socket_error_m": [r * math.cos(a), r * math.sin(a)]}

    def objects(self) -> list[str]:
        return ["plug"]

    # --- scene -------------------------------------------------------------------------------------
    @staticmethod
    def seen_socket(layout: dict[str, Any]) -> np.ndarray:
        return np.add(layout["socket_xy_m"], layout["seen_socket_error_m"])

    def start_pose(self, layout: dict[str, Any]) -> np.ndarray:
        seen = self.seen_socket(layout)
        opening = held_opening_m(self.profile, 2 * GRIP_HALF_M[1])
        z = SOCKET_TOP_M + 0.010 + GRIP_CENTRE_M
        return np.array([seen[0], seen[1], z, *yaw_quat(GRIPPER_YAW), opening])

    def _plug_pose(self, layout: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
        """World pose of the plug in the set-up's grasp: position (3,) m, quaternion (4,)."""
        start = self.start_pose(layout)
        grip = quat_to_mat(start[3:7])
        # the turn is about the pad normal, gripper +x; the grip sits along gripper +y by along_pad_m
        quat = quat_mul(quat_from_axis_angle(grip[:, 0], layout["tilt_rad"]), start[3:7])
        # the plug's own axes: x (width) along -gripper y, y (thickness) along gripper x, z up
        plug_q = quat_mul(quat, quat_from_axis_angle((0, 0, 1), -math.pi / 2))
        centre = start[:3] + grip[:, 1] * layout["along_pad_m"]
        return centre - quat_to_mat(plug_q)[:, 2] * GRIP_CENTRE_M, plug_q

    def scene_xml(self, layout: dict[str, Any]) -> str:
        pos, quat = self._plug_pose(layout)
        sx, sy = layout["socket_xy_m"]
        params = GripperParams(mount="welded")
        return f"""<mujoco model="insert_hdmi">
  <compiler angle="radian" autolimits="true"/>
  {TASK_OPTION_XML}
  <asset>{STAGE_ASSETS_XML}
  </asset>
  <worldbody>{stage_xml(head_target=(0.0, 0.0, SOCKET_TOP_M))}
    <body name="socket" pos="{sx} {sy} {SOCKET_TOP_M}">{socket_geoms_xml()}
    </body>
    <body name="plug" pos="{pos[0]} {pos[1]} {pos[2]}" quat="{' '.join(f'{v:.9f}' for v in quat)}">
      <freejoint name="plug_free"/>
      <geom name="plug_shell" type="box" pos="0 0 {SHELL_HALF_M[2]}" size="{' '.join(map(str, SHELL_HALF_M))}"
            mass="{MASS_KG[0]}" rgba="0.75 0.75 0.78 1" contype="2" conaffinity="2" friction="0.3 0.005 0.0001" {STIFF}/>
      <geom name="plug_body" type="box" pos="0 0 {2 * SHELL_HALF_M[2] + BODY_HALF_M[2]}"
            size="{' '.join(map(str, BODY_HALF_M))}" mass="{MASS_KG[1]}" rgba="0.1 0.1 0.12 1" contype="2"
            conaffinity="2" friction="0.3 0.005 0.0001" {STIFF}/>
      <geom name="plug" type="box" pos="0 0 {GRIP_CENTRE_M}" size="{' '.join(map(str, GRIP_HALF_M))}"
            mass="{MASS_KG[2]}" rgba="0.15 0.15 0.18 1" contype="0" conaffinity="0"/>
    </body>
    {gripper_body_xml(self.profile, params, (0.0, 0.0, 0.3))}
  </worldbody>
  <contact>{PadContact().pair_xml("plug")}</contact>
  <actuator>{gripper_actuator_xml(params)}</actuator>
  <equality>{gripper_equality_xml(params)}</equality>
</mujoco>"""

    # --- behaviour ---------------------------------------------------------------------------------
    def expert(self, ctx: ExpertContext) -> Iterator[Step]:
        yield from wait(ctx, 0.04)
        offset_y = 0.0
        if ctx.corrections_enabled:
            offset_y = yield from self._straighten(ctx, "in-hand turn")
        seen = self.seen_socket(ctx.layout)
        grip = quat_to_mat(ctx.target[3:7])
        # the tip sits below the grip's centre, which is offset_y along gripper y from the gripper centre
        hand = np.array([seen[0], seen[1], SOCKET_TOP_M + APPROACH_M + GRIP_CENTRE_M]) - grip[:, 1] * offset_y
        yield from move_to(ctx, hand, speed_m_s=0.05)
        reference = self._patch_tilt(ctx)  # the patch's direction with the plug upright
        first = ctx.target[:3].copy()
        origin = first.copy()
        nudges = searched = 0
        size, last = [NUDGE_M, NUDGE_M], [0.0, 0.0]  # per axis (along, across the plug): step m, last sign
        while True:
            jammed = yield from self._push(ctx)
            if not jammed or not ctx.corrections_enabled or nudges >= MAX_NUDGES:
                break
            nudges += 1
            touch = ctx.touch()
            forces = ctx.pad_forces()
            # where it caught: the socket's lead-in pushes the tip towards the slot, and the pads feel that push
            # (``_lateral_push``); a tip caught on one end also turns the plug in the grasp
            load = abs(forces["left"].shear_n[1] + forces["right"].shear_n[1])
            push_y, push_x = self._lateral_push(forces)
            turn = tilt_from_touch(touch["left"], touch["right"]) - reference
            # only a tip below the face is on the lead-in, whose slope pushes it towards the slot; on the face
            # the pads read a lateral load that does not point anywhere (it keeps its sign while the tip
            # wanders millimetres off), so from there the expert searches
            tip_depth = SOCKET_TOP_M - (ctx.ee_pose()[2] - GRIP_CENTRE_M)
            on_lead_in = tip_depth >= LEAD_IN_DEPTH_M
            along = self._nudge_axis(size, last, 0, push_y) if on_lead_in else 0.0
            across = self._nudge_axis(size, last, 1, push_x) if on_lead_in else 0.0
            frame = quat_to_mat(ctx.target[3:7])
            goal = ctx.target[:3] + frame[:, 1] * along + frame[:, 0] * across
            if np.linalg.norm((goal - origin)[:2]) > MAX_WANDER_M:
                along = across = 0.0  # the camera is not that far off: a push that leads there is friction
            if along or across:  # a push to follow: the search, if it comes to that, centres on where it leads
                first, searched = goal.copy(), 0
            elif on_lead_in:
                # in the lead-in's mouth with nothing to follow, the tip is within the clearance of the slot (or
                # it would be pushed): the next point of a small ring around here
                goal = _ring_point(ctx.target[:3], frame, LEAD_IN_SEARCH_M, SEARCH_TURN_RAD * nudges)
            else:
                # the tip sits flat on the face: try the points of a ring around where the first attempt (or the
                # last push) led, in turn
                goal = _ring_point(first, frame, SEARCH_STEP_M * (1 + searched // 6), SEARCH_TURN_RAD * searched)
                searched += 1
                if np.linalg.norm((goal - origin)[:2]) > MAX_WANDER_M:
                    goal = origin + (goal - origin) * MAX_WANDER_M / np.linalg.norm((goal - origin)[:2])
            goal[2] = ctx.target[2]
            along, across = (float(frame[:, k] @ (goal - ctx.target[:3])) for k in (1, 0))
            ctx.correction("nudge after a jam", "pad load (shear along the plug) above 1.5 N before the tip is "
                           "in (force rise without progress); direction from the lateral push on the pads "
                           "(shear along the pads, difference of their normal forces), followed only with the tip "
                           "below the face", load_n=load, tip_depth_mm=tip_depth * 1000, push_along_n=push_y,
                           push_across_n=push_x, turn_deg=math.degrees(turn), step_along_mm=along * 1000,
                           step_across_mm=across * 1000, nudge=nudges)
            yield from move_to(ctx, ctx.target[:3] + [0.0, 0.0, LIFT_M], speed_m_s=0.02, primitive="nudge")
            if abs(turn) > NUDGE_TURN_RAD:
                axis = quat_to_mat(ctx.target[3:7])[:, 0]
                yield from rotate_about(ctx, axis, -turn, turn_rad_s=0.5, primitive="nudge")
                reference = self._patch_tilt(ctx)
            goal[2] = ctx.target[2]
            yield from move_to(ctx, goal, speed_m_s=0.02, primitive="nudge")
        ctx.memory["nudges"] = nudges
        yield from wait(ctx, 0.2)

    def _straighten(self, ctx: ExpertContext, what: str, primitive: str = "align") -> Generator[Step, None, float]:
        """Turn the gripper about the pad normal so that the plug stands upright; returns the grip's offset
        along gripper y (m)."""
        touch = ctx.touch()
        left, right = touch["left"], touch["right"]
        if not (left.touching and right.touching):
            return 0.0
        tilt = tilt_from_touch(left, right)
        offset = offset_along_pads_m(left, right)
        if abs(tilt) > math.radians(0.3):
            ctx.correction(what, "orientation of the contact patches on the two pads", tilt_deg=math.degrees(tilt),
                           turn_deg=-math.degrees(tilt), offset_mm=offset * 1000)
            axis = quat_to_mat(ctx.target[3:7])[:, 0]
            yield from rotate_about(ctx, axis, -tilt, turn_rad_s=0.5, primitive=primitive)
        return offset

    @staticmethod
    def _nudge_axis(size: list[float], last: list[float], axis: int, push_n: float) -> float:
        """The step (m) along one axis towards a felt push above ``NUDGE_PUSH_N``; the step halves each time
        the push turns round (the tip went past the slot), down to 0.1 mm."""
        if abs(push_n) <= NUDGE_PUSH_N:
            return 0.0
        sign = math.copysign(1.0, push_n)
        if last[axis] and sign != last[axis]:
            size[axis] = max(0.0001, size[axis] / 2)
        last[axis] = sign
        return sign * size[axis]

    @staticmethod
    def _lateral_push(forces: dict[str, Any]) -> tuple[float, float]:
        """The lateral load the pads feel, N: along the plug's width (shear along the pads: left pad x is
        gripper +y, right pad x gripper -y) and across it (the difference of the pads' normal forces: the
        right pad's normal is gripper -x)."""
        return (float(forces["left"].shear_n[0] - forces["right"].shear_n[0]),
                float(forces["right"].normal_n - forces["left"].normal_n))

    @staticmethod
    def _patch_tilt(ctx: ExpertContext) -> float:
        touch = ctx.touch()
        return tilt_from_touch(touch["left"], touch["right"])

    def _push(self, ctx: ExpertContext) -> Generator[Step, None, bool]:
        """Push down until full depth (returns False) or until the plug jams (returns True)."""
        bottom = SOCKET_TOP_M - FULL_DEPTH_M - 0.0005 + GRIP_CENTRE_M
        step = PUSH_SPEED_M_S * ctx.dt_s
        while ctx.target[2] > bottom:
            action = ctx.target.copy()
            action[2] = max(bottom, action[2] - step)
            yield ctx.step("push", action)
            tip_depth = SOCKET_TOP_M - (ctx.ee_pose()[2] - GRIP_CENTRE_M)
            forces = ctx.pad_forces()
            load = abs(forces["left"].shear_n[1] + forces["right"].shear_n[1])
            if load > JAM_LOAD_N and tip_depth < FULL_DEPTH_M - 0.002:
                return True
        yield from wait(ctx, 0.1, primitive="push")
        return False

    # --- checks ------------------------------------------------------------------------------------
    def success(self, state: TaskState) -> bool:
        tip = state.objects["plug"][:3]
        centre = np.array([*state.layout["socket_xy_m"], SOCKET_TOP_M - FULL_DEPTH_M])
        tilt = math.acos(min(1.0, abs(float(state.axis("plug")[2]))))
        return bool(np.linalg.norm(tip[:2] - centre[:2]) < SUCCESS_XY_M and tip[2] - centre[2] < SUCCESS_ABOVE_M
                    and tilt < MAX_TILT_RAD)


def _ring_point(centre: np.ndarray, frame: np.ndarray, radius_m: float, angle_rad: float) -> np.ndarray:
    """The point ``radius_m`` from ``centre`` (3,) m at ``angle_rad`` from the gripper's y axis towards its x
    axis (``frame``: the gripper's rotation matrix, columns its axes in the world)."""
    return centre + radius_m * (frame[:, 1] * math.cos(angle_rad) + frame[:, 0] * math.sin(angle_rad))


def socket_geoms_xml() -> str:
    """The receptacle in the socket's frame (origin at the slot's centre on the top face): walls up to the
    lead-in, a top layer set back by the lead-in, four 45 deg chamfer boxes, a floor."""
    hx, hy = SLOT_HALF_M
    c, wall, depth = CHAMFER_M, 0.004, SLOT_DEPTH_M
    geoms = []

    def box(name: str, pos: tuple[float, ...], size: tuple[float, ...], extra: str = "") -> None:
        geoms.append(f'\n      <geom name="{name}" type="box" pos="{" ".join(f"{v:.6f}" for v in pos)}" '
                     f'size="{" ".join(f"{v:.6f}" for v in size)}" {extra}contype="2" conaffinity="2" '
                     f'rgba="0.2 0.2 0.22 1" friction="0.3 0.005 0.0001" {STIFF}/>')

    low_h = (depth - c) / 2
    for sign in (1, -1):
        box(f"wall_y{sign:+d}", (0, sign * (hy + wall / 2), -c - low_h), (hx + wall, wall / 2, low_h))
        box(f"wall_x{sign:+d}", (sign * (hx + wall / 2), 0, -c - low_h), (wall / 2, hy, low_h))
        box(f"top_y{sign:+d}", (0, sign * (hy + c + wall / 2), -c / 2), (hx + c + wall, wall / 2, c / 2))
        box(f"top_x{sign:+d}", (sign * (hx + c + wall / 2), 0, -c / 2), (wall / 2, hy + c, c / 2))
        # chamfer: its inner face is the plane through the slot edge at depth c and the top edge set back by c
        h = 0.0005
        n = np.array([0.0, -sign, 1.0]) / math.sqrt(2)
        mid = np.array([0.0, sign * (hy + c / 2), -c / 2]) - n * h
        box(f"lead_y{sign:+d}", tuple(mid), (hx + c, h, 0.75 * c), f'xyaxes="1 0 0 {n[0]} {n[1]} {n[2]}" ')
        n = np.array([-sign, 0.0, 1.0]) / math.sqrt(2)
        mid = np.array([sign * (hx + c / 2), 0.0, -c / 2]) - n * h
        box(f"lead_x{sign:+d}", tuple(mid), (hy + c, h, 0.75 * c), f'xyaxes="0 1 0 {n[0]} {n[1]} {n[2]}" ')
    box("floor", (0, 0, -depth - 0.001), (hx + wall, hy + wall, 0.001))
    return "".join(geoms) + (f'\n      <geom name="socket_block" type="box" pos="0 0 {-(SOCKET_TOP_M + depth) / 2 - 0.0005}" '
                             f'size="0.014 0.008 {(SOCKET_TOP_M - depth) / 2 - 0.0005}" contype="0" conaffinity="0" '
                             f'rgba="0.3 0.3 0.33 1"/>')


__all__ = ["InsertHDMI", "offset_along_pads_m", "tilt_from_touch"]
