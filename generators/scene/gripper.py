"""A floating parallel gripper with one visuo-tactile sensor per finger, as MJCF pieces.

Two mounts (``GripperParams.mount``). ``"mocap"``: the gripper base is a mocap body whose 6-DoF pose is
commanded directly; enough to press and shear a fixed indenter. ``"welded"``: the base is a free body with
gravity compensation, welded by a soft equality constraint to a mocap target that carries the command.
Tasks need this one: a mocap body has no velocity in the solver, so pad friction never drags a held object
and nothing can be carried (../shared/design/scenes-and-tasks.md, "MuJoCo contact ... measured"). Either
way a policy acts in end-effector space and no arm is modelled. Two fingers ride on slide
joints driven by position servos. Each finger carries a rigid gel pad the size of the sensor's gel; the gel's
elastic response is computed after the step by the tactile module, from the pad's penetration. Finger links
and sensor cases are visual only (they never touch anything in these scenes), which keeps the contact set to
what the tactile model reads.

Gripper frame: origin halfway between the two gel surfaces at the pad centres' height; +x from the left
pad to the right pad (the closing axis of the right finger is -x), +z up toward the palm (the fingers point
along -z). Gel-pad-centre frames: +z the pad normal toward the other pad, +x horizontal, +y = +z of the gripper.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from univtac_data.schema.sensors import SensorProfile

MAX_OPENING_M = 0.080  # distance between the gel surfaces when fully open (Panda: 2 x 39 mm)
MIN_OPENING_M = 0.004
FINGER_TRAVEL_M = (MAX_OPENING_M - MIN_OPENING_M) / 2
PADS = ("left", "right")


@dataclass(frozen=True)
class GripperParams:
    """Servo and contact settings of the fingers (the stability study chooses the defaults)."""

    finger_kp_n_per_m: float = 20000.0  # position servo, ~10x stiffer than the gel: the finger sits at its set-point
    finger_damping_ns_per_m: float = 63.0  # 2 sqrt(kp m): critically damped, no ringing at contact
    finger_force_limit_n: float = 40.0  # maximum actuator force
    finger_mass_kg: float = 0.05
    # Direct-format contact (-stiffness, -damping) with a constant impedance d: rest penetration is
    # F (1 - d) / (m stiffness), i.e. a spring of m * stiffness / (1 - d) N/m for a finger of mass m. The
    # default makes that spring about the gel's (benchmarks/contact_calibration.py).
    pad_solref: tuple[float, float] = (-1500.0, -230.0)
    pad_solimp: tuple[float, float, float] = (0.5, 0.5, 0.001)
    pad_friction: float = 1.0
    # Torsional friction of the pads, m: a flat gel patch of length L holding a line contact resists a twist
    # about its normal with about mu * N * L / 4 (L ~ 25 mm); MuJoCo's default of 0.005 m is that order.
    pad_torsional_friction_m: float = 0.005
    mount: Literal["mocap", "welded"] = "mocap"
    # Weld of the free gripper to its mocap target (direct time constant, s, and damping ratio): 0.01-0.02 s
    # carries a held object through friction; 0.002-0.004 s explodes at 1 ms and 0.05 s is too soft to push.
    weld_solref: tuple[float, float] = (0.01, 1.0)
    gripper_mass_kg: float = 0.6  # the free base (palm); gravity-compensated, it only sets the weld's inertia


def _pad_axes(pad: str) -> str:
    # xyaxes of the gel-pad-centre frame in the finger (= gripper) frame
    return "0 1 0 0 0 1" if pad == "left" else "0 -1 0 0 0 1"


def gripper_body_xml(profile: SensorProfile, params: GripperParams, pos: tuple[float, float, float]) -> str:
    """The mocap gripper body with its fingers, pads and tactile sites."""
    t = profile.gel_thickness_mm / 1000
    half_w, half_h = profile.gel_width_mm / 2000, profile.gel_height_mm / 2000
    solref = " ".join(map(str, params.pad_solref))
    solimp = " ".join(map(str, params.pad_solimp))
    grav = ' gravcomp="1"' if params.mount == "welded" else ""
    fingers = []
    for pad, sign in (("left", -1), ("right", 1)):
        x0 = sign * MAX_OPENING_M / 2
        axis = -sign
        fingers.append(f"""
      <body name="{pad}_finger" pos="{x0} 0 0"{grav}>
        <joint name="{pad}_slide" type="slide" axis="{axis} 0 0" range="0 {FINGER_TRAVEL_M}"
               damping="{params.finger_damping_ns_per_m}" limited="true"/>
        <inertial pos="{sign * 0.01} 0 0.02" mass="{params.finger_mass_kg}" diaginertia="1e-5 1e-5 1e-5"/>
        <geom name="{pad}_gel" type="box" pos="{sign * t / 2} 0 0" xyaxes="{_pad_axes(pad)}"
              size="{half_w} {half_h} {t / 2}" rgba="0.85 0.85 0.8 1" friction="{params.pad_friction} {params.pad_torsional_friction_m} 0.0001"
              solref="{solref}" solimp="{solimp}" solmix="1000" condim="4"/>
        <geom name="{pad}_case" type="box" pos="{sign * (t + 0.012)} 0 0" size="0.012 0.016 0.014"
              rgba="0.2 0.2 0.22 1" contype="0" conaffinity="0"/>
        <geom name="{pad}_link" type="box" pos="{sign * (t + 0.016)} 0 0.04" size="0.006 0.01 0.03"
              rgba="0.6 0.6 0.65 1" contype="0" conaffinity="0"/>
        <site name="{pad}_pad" pos="0 0 0" xyaxes="{_pad_axes(pad)}" size="0.001" group="4"/>
      </body>""")
    palm = f"""
      <geom name="palm" type="box" pos="0 0 0.075" size="0.05 0.02 0.006" rgba="0.3 0.3 0.35 1"
            contype="0" conaffinity="0"/>
      <site name="ee" pos="0 0 0" size="0.002" group="4"/>{''.join(fingers)}"""
    x, y, z = pos
    if params.mount == "mocap":
        return f"""
    <body name="gripper" mocap="true" pos="{x} {y} {z}">{palm}
    </body>"""
    # the wrist camera rides on the palm, behind the fingers, looking down between them
    return f"""
    <body name="gripper_target" mocap="true" pos="{x} {y} {z}"/>
    <body name="gripper" pos="{x} {y} {z}" gravcomp="1">
      <freejoint name="gripper_free"/>
      <inertial pos="0 0 0.05" mass="{params.gripper_mass_kg}" diaginertia="2e-3 2e-3 2e-3"/>{palm}
      <camera name="wrist" pos="0 -0.075 0.045" xyaxes="1 0 0 0 0.8 0.6" fovy="75"/>
    </body>"""


def gripper_equality_xml(params: GripperParams) -> str:
    """The weld of a ``"welded"`` gripper to its mocap target (empty for the mocap mount)."""
    if params.mount == "mocap":
        return ""
    solref = " ".join(map(str, params.weld_solref))
    return f'<weld name="gripper_weld" body1="gripper" body2="gripper_target" solref="{solref}"/>'


def gripper_actuator_xml(params: GripperParams) -> str:
    lines = [
        f'<position name="{pad}_finger" joint="{pad}_slide" kp="{params.finger_kp_n_per_m}" '
        f'ctrlrange="0 {FINGER_TRAVEL_M}" forcerange="-{params.finger_force_limit_n} {params.finger_force_limit_n}"/>'
        for pad in PADS
    ]
    return "\n    ".join(lines)


def opening_to_finger_pos(opening_m: float) -> float:
    """Slide-joint position of each finger (m, 0 = fully open) for a distance ``opening_m`` between gels."""
    return min(max((MAX_OPENING_M - opening_m) / 2, 0.0), FINGER_TRAVEL_M)


def finger_pos_to_opening(finger_pos_m: float) -> float:
    return MAX_OPENING_M - 2 * finger_pos_m
