"""The bottle both bottle tasks use, and what the pads tell about its pose in the hand.

The bottle: a 50 cl plastic water bottle, half full. A composite of MuJoCo primitives: body cylinder of
diameter 6.5 cm and height 15 cm (a 15 g PET shell), a shoulder (diameter 4.4 cm, 2.5 cm), a neck (2.7 cm,
2.5 cm) and a cap (3.0 cm, 1.5 cm), 10 g together: 21.5 cm tall. The 25 cl of water (0.25 kg) is a solid
column 7.5 cm high at the bottom of the body (it does not slosh in the model); 0.275 kg in all, the centre
of mass 4.5 cm above the base.
The gripper opens to 8 cm, so the 6.5 cm body fits with 7.5 mm to spare on each side.

Body frame: origin on the axis at ``origin_height_m`` above the base (each task puts it where its expert
grips, so that a bottle turning about the pads' line stays put in the hand: the kit's in-hand slip is the
motion of the origin); local +z along the axis, from the base towards the cap.

The in-hand pose from touch (``in_hand_from_touch``): a cylinder pressed between two flat pads touches each
over a strip along its axis. In the gel-pad-centre frame (x along the pad's width, y up the finger, z the
normal towards the other pad) the strip's long axis is the bottle's axis projected on the pad, and its
centroid is where the axis crosses the pad. The left pad's x is gripper +y and the right pad's x is gripper
-y (the pads face each other), both pads' y are gripper +z; averaging the two pads cancels what one pad
alone gets wrong when the bottle is pressed harder into one of them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from univtac_data.generators.scene.geometry import quat_to_mat
from univtac_data.generators.scene.touch import TouchReading

BODY_RADIUS_M = 0.0325
BODY_HEIGHT_M = 0.15
SHOULDER = (0.022, 0.025)  # radius, height m
NECK = (0.0135, 0.025)
CAP = (0.015, 0.015)
HEIGHT_M = BODY_HEIGHT_M + SHOULDER[1] + NECK[1] + CAP[1]
SHELL_MASS_KG = 0.015  # the PET body
WATER_MASS_KG = 0.25  # 25 cl, a column 7.5 cm high at the bottom of the body
WATER_HEIGHT_M = 0.075
TOP_MASS_KG = 0.01  # shoulder, neck and cap together
MASS_KG = SHELL_MASS_KG + WATER_MASS_KG + TOP_MASS_KG
# centre of mass above the base, m: 4.5 cm (each part's mass at its centre)
COM_HEIGHT_M = (SHELL_MASS_KG * BODY_HEIGHT_M / 2 + WATER_MASS_KG * WATER_HEIGHT_M / 2
                + TOP_MASS_KG * (BODY_HEIGHT_M + 0.03)) / MASS_KG
FRICTION = "0.8 0.005 0.0001"  # PET on a table or a painted wall


def bottle_xml(name: str, pos: np.ndarray, quat: np.ndarray, origin_height_m: float, rgba: str = "0.55 0.75 0.9 0.9") -> str:
    """The bottle body (free joint) at ``pos`` (m, world) and ``quat`` (w, x, y, z), its origin
    ``origin_height_m`` above the base. The body geom is named ``name``: the one the pads touch."""
    z0 = -origin_height_m  # base, in the body frame
    parts = []
    top = z0 + BODY_HEIGHT_M
    for part, (radius, height), mass in (("shoulder", SHOULDER, 0.004), ("neck", NECK, 0.003), ("cap", CAP, 0.003)):
        rgba_part = "0.15 0.35 0.8 1" if part == "cap" else rgba
        parts.append(f'\n      <geom name="{name}_{part}" type="cylinder" size="{radius} {height / 2}" '
                     f'pos="0 0 {top + height / 2:.6f}" mass="{mass}" rgba="{rgba_part}" friction="{FRICTION}" condim="4"/>')
        top += height
    p = " ".join(f"{v:.9f}" for v in pos)
    q = " ".join(f"{v:.9f}" for v in quat)
    return f"""
    <body name="{name}" pos="{p}" quat="{q}">
      <freejoint name="{name}_free"/>
      <geom name="{name}" type="cylinder" size="{BODY_RADIUS_M} {BODY_HEIGHT_M / 2}" pos="0 0 {z0 + BODY_HEIGHT_M / 2:.6f}"
            mass="{SHELL_MASS_KG}" rgba="{rgba}" friction="{FRICTION}" condim="4"/>
      <geom name="{name}_water" type="cylinder" size="{BODY_RADIUS_M - 0.001} {WATER_HEIGHT_M / 2}"
            pos="0 0 {z0 + WATER_HEIGHT_M / 2:.6f}" mass="{WATER_MASS_KG}" rgba="0.3 0.5 0.95 0.6" contype="0" conaffinity="0"/>{''.join(parts)}
    </body>"""


@dataclass(frozen=True)
class InHandPose:
    """The bottle's axis in the gripper frame as the pads see it.

    ``angle_rad``: the axis line's angle in the gripper's y-z plane from gripper +z towards gripper +y, in
    (-pi/2, pi/2] (a strip has no arrow: ``axis_world`` picks the direction); ``point_m``: (y, z) m, the point
    of the axis nearest the gripper centre (where the pads' centre line meets the bottle: its grip point);
    ``both``: both pads touch.
    """

    angle_rad: float
    point_m: tuple[float, float]
    both: bool

    def axis_world(self, ee_quat: np.ndarray, towards: np.ndarray = np.array([0.0, 0.0, 1.0])) -> np.ndarray:
        """(3,) unit axis direction in the world for the gripper orientation ``ee_quat`` (w, x, y, z), the way
        that points less than 90 deg from ``towards`` (the cap's side, which the expert knows roughly)."""
        axis = quat_to_mat(ee_quat) @ np.array([0.0, math.sin(self.angle_rad), math.cos(self.angle_rad)])
        return axis if float(np.dot(axis, towards)) >= 0 else -axis

    def grip_point_world(self, ee_pose: np.ndarray) -> np.ndarray:
        """(3,) m world: the grip point on the axis for the gripper pose ``ee_pose`` (7,)."""
        return ee_pose[:3] + quat_to_mat(ee_pose[3:]) @ np.array([0.0, *self.point_m])


def _strip_angle_in_gripper(reading: TouchReading, pad: str) -> float:
    """Angle of a pad's contact strip from gripper +z towards gripper +y, in (-pi/2, pi/2]."""
    # pad frame -> gripper (y, z): left (x, y) -> (x, y); right (x, y) -> (-x, y)
    # the chords' midpoint line is the axis; the patch's principal direction tilts towards the deeper end
    a = reading.axis_angle_rad if reading.chord_line_angle_rad is None else reading.chord_line_angle_rad
    gy, gz = math.cos(a), math.sin(a)
    if pad == "right":
        gy = -gy
    angle = math.atan2(gy, gz)
    if angle > math.pi / 2:
        angle -= math.pi
    elif angle <= -math.pi / 2:
        angle += math.pi
    return angle


def in_hand_from_touch(left: TouchReading, right: TouchReading) -> InHandPose:
    """The bottle's axis in the gripper frame from the two pads' contact strips (see the module docstring).
    A pad that feels nothing contributes nothing; with neither pad touching, the axis is taken along gripper z."""
    angles, points = [], []
    for pad, reading in (("left", left), ("right", right)):
        if not reading.touching:
            continue
        angles.append(_strip_angle_in_gripper(reading, pad))
        x_mm, y_mm = reading.centroid_mm
        points.append(((x_mm if pad == "left" else -x_mm) / 1000.0, y_mm / 1000.0))
    if not angles:
        return InHandPose(0.0, (0.0, 0.0), False)
    # average directions, not angles: two strips near +-pi/2 are the same line
    c = sum(math.cos(2 * a) for a in angles)
    s = sum(math.sin(2 * a) for a in angles)
    angle = 0.5 * math.atan2(s, c)
    centroid = np.mean(points, axis=0)
    direction = np.array([math.sin(angle), math.cos(angle)])
    foot = centroid - float(np.dot(centroid, direction)) * direction  # nearest the gripper centre
    return InHandPose(angle, (float(foot[0]), float(foot[1])), len(angles) == 2)


def tilt_rad(axis: np.ndarray) -> float:
    """Angle between an axis (3,) and world +z, rad."""
    return math.acos(max(-1.0, min(1.0, float(axis[2]) / float(np.linalg.norm(axis)))))


__all__ = ["BODY_HEIGHT_M", "BODY_RADIUS_M", "COM_HEIGHT_M", "HEIGHT_M", "InHandPose", "MASS_KG", "bottle_xml",
           "in_hand_from_touch", "tilt_rad"]
