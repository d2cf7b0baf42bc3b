"""The indenter scene: ground, a prism base with the same indenter on both faces, and the gripper.

Left out, on purpose: an arm (the gripper pose is commanded directly), the sensor's optics hardware (the
tactile module renders images from the contact), a deformable gel (rigid pads + the elastic contact model),
and lighting beyond what a preview needs. The base is static: indenter episodes press and shear a fixed
shape, as in UniVTAC's indenter stand.

Object frame ``indenter``: origin at the centre of the base plate, +x toward the right pad. The indenter on
the +x face is pressed by the right pad, the one on the -x face by the left pad.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from univtac_data.generators.scene.geometry import quat_from_axis_angle, quat_mul, quat_to_mat
from univtac_data.generators.scene.gripper import GripperParams, gripper_actuator_xml, gripper_body_xml
from univtac_data.generators.indenters.shapes import Indenter
from univtac_data.schema.sensors import SensorProfile

BASE_HALF_THICKNESS_M = 0.005
BASE_CENTRE_M = (0.0, 0.0, 0.081)  # UniVTAC grasps its indenter stand at 81 mm
OBJECT_NAME = "indenter"


@dataclass(frozen=True)
class SceneConfig:
    """Physics settings of the scene (defaults from the stability study, benchmarks/stability.py)."""

    timestep_s: float = 0.001
    gripper: GripperParams = field(default_factory=GripperParams)


def _f(values: np.ndarray | tuple[float, ...]) -> str:
    return " ".join(f"{v:.9g}" for v in np.asarray(values, float).ravel())


def indenter_scene_xml(profile: SensorProfile, indenter: Indenter, *, yaw_rad: float = 0.0,
                       config: SceneConfig | None = None,
                       gripper_pos: tuple[float, float, float] = (0.0, 0.0, 0.2)) -> str:
    """MJCF of the scene; ``yaw_rad`` turns the indenter about its own axis (the pad normal)."""
    config = config or SceneConfig()
    assets, geoms = [], []
    for side, normal in (("pos", 1.0), ("neg", -1.0)):
        # indenter z onto the face normal (+x or -x of the object frame), then the yaw about it
        face = quat_from_axis_angle((0, 1, 0), normal * np.pi / 2)
        turn = quat_mul(face, quat_from_axis_angle((0, 0, 1), yaw_rad))
        rot = quat_to_mat(turn)
        offset = np.array([normal * BASE_HALF_THICKNESS_M, 0.0, 0.0])
        for k, part in enumerate(indenter.parts):
            pos = offset + rot @ np.asarray(part.pos)
            quat = quat_mul(turn, np.asarray(part.quat))
            name = f"indenter_{side}_{k}"
            common = f'name="{name}" pos="{_f(pos)}" quat="{_f(quat)}" rgba="0.75 0.55 0.3 1" condim="4"'
            if part.kind == "mesh":
                assert part.vertices is not None
                assets.append(f'<mesh name="{name}_mesh" vertex="{_f(part.vertices)}"/>')
                geoms.append(f'<geom {common} type="mesh" mesh="{name}_mesh"/>')
            else:
                geoms.append(f'<geom {common} type="{part.kind}" size="{_f(part.size)}"/>')
    bx, by, bz = BASE_CENTRE_M
    return f"""<mujoco model="indenter_{indenter.name}_{profile.name}">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{config.timestep_s}" integrator="implicitfast"/>
  <visual><global offwidth="640" offheight="480"/></visual>
  <asset>
    {chr(10).join('    ' + a for a in assets).strip()}
  </asset>
  <worldbody>
    <light pos="0.2 -0.3 0.6" dir="-0.3 0.5 -1"/>
    <geom name="ground" type="plane" size="0.5 0.5 0.01" rgba="0.9 0.9 0.92 1"/>
    <body name="{OBJECT_NAME}" pos="{bx} {by} {bz}">
      <geom name="base_plate" type="box" size="{BASE_HALF_THICKNESS_M} 0.02 0.02" rgba="0.5 0.5 0.55 1"/>
      <geom name="base_post" type="box" pos="0 0 {-(bz - 0.02) / 2 - 0.02}" size="{BASE_HALF_THICKNESS_M} 0.008 {(bz - 0.02) / 2}"
            rgba="0.5 0.5 0.55 1"/>
      {chr(10).join('      ' + g for g in geoms).strip()}
    </body>
    {gripper_body_xml(profile, config.gripper, gripper_pos).strip()}
    <camera name="head" pos="0.25 -0.25 0.2" xyaxes="0.707 0.707 0 -0.25 0.25 0.93" fovy="45"/>
  </worldbody>
  <actuator>
    {gripper_actuator_xml(config.gripper)}
  </actuator>
</mujoco>
"""


def indenter_geom_names(indenter: Indenter, side: str) -> list[str]:
    """Geoms of the indenter on one face: ``side`` is 'pos' (pressed by the right pad) or 'neg' (left)."""
    return [f"indenter_{side}_{k}" for k in range(len(indenter.parts))]


PAD_SIDE = {"left": "neg", "right": "pos"}
