"""The stage every task scene shares: a checkered table plane, two lights, a gradient sky, the head camera.

Cameras only see; nothing here changes the physics of the objects a task adds.
"""

from __future__ import annotations

from univtac_data.generators.scene.cameras import look_at_xyaxes

STAGE_ASSETS_XML = """
    <texture name="sky" type="skybox" builtin="gradient" rgb1="0.62 0.70 0.80" rgb2="0.93 0.94 0.96" width="64" height="64"/>
    <texture name="grid" type="2d" builtin="checker" rgb1="0.82 0.82 0.84" rgb2="0.74 0.74 0.77" width="256" height="256"/>
    <material name="table" texture="grid" texrepeat="8 8"/>"""


def stage_xml(head_eye: tuple[float, float, float] = (0.0, 0.45, 0.32),
              head_target: tuple[float, float, float] = (0.0, 0.0, 0.08), head_fovy_deg: float = 45.0) -> str:
    """World-body MJCF of the stage: table plane (friction 0.8), lights, and the ``head`` camera at
    ``head_eye`` (m) looking at ``head_target`` (m)."""
    return f"""
    <light pos="0.3 -0.4 1.0" dir="-0.3 0.4 -1"/>
    <light pos="-0.4 0.3 0.8" dir="0.4 -0.3 -1" diffuse="0.4 0.4 0.4"/>
    <geom name="ground" type="plane" size="0.6 0.6 0.01" material="table" friction="0.8 0.005 0.0001"/>
    <camera name="head" pos="{head_eye[0]} {head_eye[1]} {head_eye[2]}" xyaxes="{look_at_xyaxes(head_eye, head_target)}"
            fovy="{head_fovy_deg}"/>"""


__all__ = ["STAGE_ASSETS_XML", "stage_xml"]
