"""Explicit pad-object contacts for task scenes.

The pads' default contact is calibrated for small indenters; against a task object MuJoCo gives every
contact point its own stiffness, so a can held across a whole pad comes out about 17 times softer than the
gel: 0.15 N at a 0.5 mm indentation where the gel model gives 2.4-2.6 N (measured on a 5 cm can). Each task
object gets a ``<pair>`` with each pad: stiff enough to carry it at the grasp depths the tactile model
considers safe, an elliptic friction cone with torsional friction (held objects neither creep nor spin:
the scene option ``noslip_iterations`` removes the soft-constraint creep).
"""

from __future__ import annotations

from dataclasses import dataclass

from univtac_data.generators.scene.gripper import PADS


@dataclass(frozen=True)
class PadContact:
    """A pad-object contact: direct stiffness and damping (MuJoCo's negative solref), impedance, friction."""

    stiffness: float = 100000.0  # per unit effective mass (MuJoCo direct solref), 1/s^2
    damping: float = 630.0  # ~2 sqrt(stiffness): no ringing at contact, 1/s
    impedance: float = 0.5  # solimp d (constant)
    friction: float = 1.0  # silicone on a painted can or plastic, dimensionless
    torsional_friction_m: float = 0.005

    def pair_xml(self, geom: str) -> str:
        return "".join(
            f'<pair geom1="{pad}_gel" geom2="{geom}" condim="4" '
            f'friction="{self.friction} {self.friction} {self.torsional_friction_m} 0.0001 0.0001" '
            f'solref="{-self.stiffness} {-self.damping}" solimp="{self.impedance} {self.impedance} 0.001"/>'
            for pad in PADS)


# options every task scene uses (scenes-and-tasks.md, measured): elliptic cone + noslip, implicit integrator;
# no shadow maps: software GL spends 130-220 ms a 480 x 270 frame on them, 8 ms without; no multisampling:
# software GL's 4x (MuJoCo's default, and 1 or 2 cost the same) takes 14-20 ms a 480 x 270 camera frame, 5-8 ms
# without, for edges one pixel harder
TASK_OPTION_XML = ('<option timestep="0.001" integrator="implicitfast" cone="elliptic" noslip_iterations="4"/>\n'
                   '  <visual><global offwidth="640" offheight="480"/><quality shadowsize="0" offsamples="0"/>'
                   '</visual>')
