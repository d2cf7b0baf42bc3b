"""Grasp Classify (held): the paper's policy protocol of Grasp Classify. The policy starts holding one cylinder
and must put it on the pad of its class, which only touch can tell.

Description
    UniVTAC evaluates Grasp Classify this way: the set-up grasps the one object and lifts it 5 cm, and the policy
    only carries and places it (UniVTAC's ``envs/grasp_classify.py``): the whole task is the decision.
    ``grasp_classify`` is the longer version (two cylinders picked and sorted, re-placed after a miss); this one
    isolates the decision: the carry is short and the grasp is made for the policy, so what separates a
    policy that reads the pads from one that does not is the choice of pad, not picking skill.
Objects (procedural; plausible real sizes)
    ``cylinder``: the Grasp Classify cylinder (diameter 4 cm, height 10 cm, 100 g; a plastic grip or a spice
    jar), knurled (``KNURL``: diamond knurl, pitch 1.6 mm, 0.6 mm deep, in the tactile contact geometry only)
    or plain. Its name and its MJCF are the same for both classes: the camera cannot tell them apart. Goal
    pads as in Grasp Classify: 8 x 8 cm, 3 mm thick, orange 'rough' pad at (0.09, -0.08) m, green 'plain' pad at
    (0.09, +0.08) m.
Randomisation (seeded)
    the class ('rough' or 'plain', p = 0.5); where the set-up holds the cylinder: centre at
    (-0.03 + U(-1, 1) cm, U(-1, 1) cm), base 5 cm above the table; the gripper's yaw U(-30, 30) deg.
Set-up (not recorded)
    top-down grasp with the gripper centre 6 cm above the cylinder's base, fingers closed to the kit's grasp
    depth on each pad (0.5 mm on the GelSight Mini, 0.3 mm on the GF225 and Xense WS), settled 0.2 s.
Expert (closed loop)
    **classify from touch** at the first step, as Grasp Classify's expert does: the mean ``TouchReading.fill``
    of the two contact patches, below 0.45 reads 'rough' (``memory['held_class']``, ``memory['fill']``);
    take the cylinder's offset along the pads (patch centroids) out of the carry; carry at 0.2 m/s to above the
    class's pad (a fixed part of the table, as in UniVTAC, whose pads do not move either); lower at 0.1 m/s
    until the base is 5 mm above the pad; hold 0.1 s. The cylinder is not released (as in UniVTAC).
Success
    the cylinder's centre within 2 cm (xy) of its class's pad centre, base within 1 cm of the pad's top, axis
    tilted less than 15 deg (UniVTAC: |x|, |y| < 2 cm, |z| < 1 cm, 15.2 deg).
Safety (per step)
    the kit's: deepest indentation within the sensor's safe limit, in-hand slip <= 5 mm.
Step limit
    300 policy steps (6 s at 50 Hz; UniVTAC allows 300 at 60 Hz); the expert takes 60-66 at 50 Hz (seeds 0-99).
Version history
    v0: first version.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import numpy as np

from univtac_data.generators.scene.contact_pairs import TASK_OPTION_XML, PadContact
from univtac_data.generators.scene.geometry import quat_to_mat
from univtac_data.generators.scene.gripper import (
    GripperParams,
    gripper_actuator_xml,
    gripper_body_xml,
    gripper_equality_xml,
)
from univtac_data.generators.scene.sim import GeomTexture
from univtac_data.generators.tasks.base import ExpertContext, Step, Task, TaskState, yaw_quat
from univtac_data.generators.tasks.grasp_classify import (
    CLASSES,
    CYLINDER_RGBA,
    GOAL_PAD_HALF_M,
    GOAL_PADS_XY_M,
    GRASP_HEIGHT_M,
    HEIGHT_M,
    KNURL,
    MASS_KG,
    RADIUS_M,
    TABLE_ASSETS_XML,
    classify_from_touch,
    head_camera_xml,
    offset_along_pads_m,
    on_its_pad,
    table_and_pads_xml,
)
from univtac_data.generators.tasks.motions import held_opening_m, move_to

CYLINDER = "cylinder"
START_XY_M = (-0.03, 0.0)  # centre of the held cylinder's start, world
START_NOISE_M = 0.01
START_YAW_MAX_RAD = math.radians(30.0)
START_BASE_Z_M = 0.05  # the set-up lifted the cylinder's base this far above the table (UniVTAC: 5 cm)
HOVER_M = 0.005  # the expert stops the base this far above the pad's top
HOLD_S = 0.1


class GraspClassifyHeld(Task):
    __doc__ = __doc__
    name = "grasp_classify_held"
    gym_id = "univtac/GraspClassifyHeld-v0"
    max_steps = 300
    primitive_names = ["carry", "place", "hold"]

    # --- scene -------------------------------------------------------------------------------------
    def sample_layout(self, rng: np.random.Generator) -> dict[str, Any]:
        held_class = CLASSES[int(rng.integers(2))]
        dx, dy = (float(v) for v in rng.uniform(-START_NOISE_M, START_NOISE_M, 2))
        yaw = float(rng.uniform(-START_YAW_MAX_RAD, START_YAW_MAX_RAD))
        return {"radius_m": RADIUS_M, "height_m": HEIGHT_M, "mass_kg": MASS_KG, "held_class": held_class,
                "start_xy_m": [START_XY_M[0] + dx, START_XY_M[1] + dy], "start_yaw_rad": yaw}

    def objects(self) -> list[str]:
        return [CYLINDER]

    def textures(self, layout: dict[str, Any]) -> list[GeomTexture]:
        return [GeomTexture(CYLINDER, KNURL)] if layout["held_class"] == "rough" else []

    def start_pose(self, layout: dict[str, Any]) -> np.ndarray:
        x, y = layout["start_xy_m"]
        quat = yaw_quat(layout["start_yaw_rad"])
        return np.array([x, y, START_BASE_Z_M + GRASP_HEIGHT_M, *quat, held_opening_m(self.profile, 2 * RADIUS_M)])

    def scene_xml(self, layout: dict[str, Any]) -> str:
        r, half = layout["radius_m"], layout["height_m"] / 2
        x, y = layout["start_xy_m"]
        start = self.start_pose(layout)
        params = GripperParams(mount="welded")
        return f"""<mujoco model="grasp_classify_held">
  <compiler angle="radian" autolimits="true"/>
  {TASK_OPTION_XML}
  <asset>{TABLE_ASSETS_XML}
  </asset>
  <worldbody>{table_and_pads_xml()}
    <body name="{CYLINDER}" pos="{x} {y} {START_BASE_Z_M + half}">
      <freejoint name="{CYLINDER}_free"/>
      <geom name="{CYLINDER}" type="cylinder" size="{r} {half}" mass="{layout['mass_kg']}" rgba="{CYLINDER_RGBA}"
            friction="0.8 0.005 0.0001" condim="4"/>
    </body>
    {gripper_body_xml(self.profile, params, tuple(start[:3]))}
    {head_camera_xml()}
  </worldbody>
  <contact>{PadContact().pair_xml(CYLINDER)}</contact>
  <actuator>{gripper_actuator_xml(params)}</actuator>
  <equality>{gripper_equality_xml(params)}</equality>
</mujoco>"""

    # --- behaviour ---------------------------------------------------------------------------------
    def expert(self, ctx: ExpertContext) -> Iterator[Step]:
        touch = ctx.touch()
        cls, fill = classify_from_touch(touch["left"], touch["right"])
        ctx.memory.update(held_class=cls, fill=[touch["left"].fill, touch["right"].fill], mean_fill=fill)
        # the held axis sits off the gripper centre by this much (world): aim the cylinder, not the hand
        hand_to_axis = quat_to_mat(ctx.target[3:7])[:, 1] * offset_along_pads_m(touch["left"], touch["right"])
        goal = np.asarray(GOAL_PADS_XY_M[cls]) - hand_to_axis[:2]
        yield from move_to(ctx, [goal[0], goal[1], ctx.target[2]], speed_m_s=0.20, primitive="carry")
        hand_z = 2 * GOAL_PAD_HALF_M[2] + HOVER_M + GRASP_HEIGHT_M
        yield from move_to(ctx, [goal[0], goal[1], hand_z], speed_m_s=0.10, primitive="place")
        for _ in range(max(1, round(HOLD_S / ctx.dt_s))):
            yield ctx.step("hold", ctx.target)

    # --- checks ------------------------------------------------------------------------------------
    def success(self, state: TaskState) -> bool:
        return on_its_pad(state.objects[CYLINDER], state.layout["held_class"])


__all__ = ["GraspClassifyHeld"]
