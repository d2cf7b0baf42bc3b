"""What a pad's force reading gives: the contact force between each gel pad and the objects it touches.

A visuo-tactile sensor's pressure and shear fields, summed over the gel, are the force the object exerts
on the pad; this reads that force from MuJoCo's contact solver (the same contacts that hold the object),
expressed in the gel-pad-centre frame: normal (N, >= 0 pressing, along -z of the pad frame, i.e. the object
pushes the gel back) and shear along the pad's x and y (N, the force on the gel). Unlike the tactile images'
shear, which follows the object's displacement on the gel, this also shows a load that the gel holds
without slipping (a plug pushed up by a jammed tip, a key pressed against its stop). Pure read of the
current state.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from univtac_data.generators.scene.gripper import PADS


@dataclass(frozen=True)
class PadForce:
    """One pad's summed contact force, gel-pad-centre frame, N: normal (pressing, >= 0), shear x, shear y;
    and the moment of the contact forces about the gripper origin, gripper frame, N m."""

    normal_n: float
    shear_n: tuple[float, float]
    moment_nm: tuple[float, float, float]


def pad_forces(model: mujoco.MjModel, data: mujoco.MjData) -> dict[str, PadForce]:
    """Per pad, the force all contacts of its gel geom exert on it now (see the module docstring)."""
    out = {}
    ee = model.site("ee").id
    ee_pos, ee_mat = data.site_xpos[ee], data.site_xmat[ee].reshape(3, 3)
    wrench = np.zeros(6)
    for pad in PADS:
        gel = model.geom(f"{pad}_gel").id
        site = model.site(f"{pad}_pad").id
        pad_mat = data.site_xmat[site].reshape(3, 3)
        force_w, moment_w = np.zeros(3), np.zeros(3)
        for i in range(data.ncon):
            con = data.contact[i]
            if gel not in (con.geom1, con.geom2) or con.efc_address < 0:
                continue
            mujoco.mj_contactForce(model, data, i, wrench)
            # contact frame rows: normal (geom1 -> geom2), two tangents; the solver's force acts on geom2
            f = con.frame.reshape(3, 3).T @ wrench[:3]
            on_pad = f if con.geom2 == gel else -f
            force_w += on_pad
            moment_w += np.cross(con.pos - ee_pos, on_pad)
        local = pad_mat.T @ force_w
        moment = ee_mat.T @ moment_w
        out[pad] = PadForce(float(max(0.0, -local[2])), (float(local[0]), float(local[1])),
                            (float(moment[0]), float(moment[1]), float(moment[2])))
    return out


__all__ = ["PadForce", "pad_forces"]
