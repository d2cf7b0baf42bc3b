"""Why the pad contact stiffness is 1500: MuJoCo's rigid-pad contact against the elastic gel model.

The gripper presses the right pad into an indenter with a constant finger force F (the actuator saturates at
its force limit); once at rest we read the penetration d that MuJoCo settles at and the normal force the
elastic tactile model computes for that same geometry. Where the two agree, the closed-loop grasp reads the
indentation a real gel would show under the same squeeze.

    python benchmarks/contact_calibration.py

Writes benchmarks/results/contact_calibration.json and docs/figures/contact_calibration.png.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace

import matplotlib
import mujoco

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from common import FIGURES, RESULTS, machine  # noqa: E402

from univtac_data.generators.scene.gripper import PADS, GripperParams  # noqa: E402
from univtac_data.generators.indenters.scene import (  # noqa: E402
    PAD_SIDE,
    SceneConfig,
    indenter_geom_names,
    indenter_scene_xml,
)
from univtac_data.generators.indenters.shapes import INDENTERS  # noqa: E402
from univtac_data.generators.scene.primitives import PRIMITIVE_NAMES  # noqa: E402
from univtac_data.generators.scene.sim import GripperSim, SimConfig  # noqa: E402
from univtac_data.generators.tactile import gap_field, pad_pose, sensor_grid, simulate_frame  # noqa: E402
from univtac_data.schema.sensors import get_sensor  # noqa: E402

SENSOR = "gelsight_mini"
SHAPES = ("sphere", "cylinder")
STIFFNESSES = (500.0, 1500.0, 5000.0)
FORCES_N = (0.3, 0.5, 0.75, 1.0, 1.5, 2.0)


def press(shape: str, stiffness: float, force_n: float) -> dict[str, float]:
    profile, indenter = get_sensor(SENSOR), INDENTERS[shape]
    gripper = replace(GripperParams(), finger_force_limit_n=force_n,
                      pad_solref=(-stiffness, -2 * math.sqrt(stiffness) * 3))
    model = mujoco.MjModel.from_xml_string(indenter_scene_xml(
        profile, indenter, config=SceneConfig(gripper=gripper), gripper_pos=(0.0, 0.0, 0.081)))
    sim = GripperSim(model, profile, {p: indenter_geom_names(indenter, PAD_SIDE[p]) for p in PADS}, "indenter",
                     PRIMITIVE_NAMES, SimConfig(record_rate_hz=None))
    for pad in PADS:  # start 0.5 mm short of the indenter: a finger at a low force limit crawls
        sim.data.qpos[model.joint(f"{pad}_slide").qposadr[0]] = 0.0295
    mujoco.mj_forward(model, sim.data)
    sim.finger_setpoints_m[:] = 0.035  # far past the object: the actuator pushes with its force limit
    for _ in range(1500):
        sim.tick()
    gap = gap_field(model, sim.data, pad_pose(model, sim.data, "right_pad"), indenter_geom_names(indenter, "pos"),
                    sensor_grid(profile, 1))
    frame = simulate_frame(profile, gap, method="elastic")
    return {"shape": shape, "stiffness": stiffness, "finger_force_n": force_n,
            "penetration_mm": round(float(-gap.min()), 4), "elastic_force_n": round(float(frame.normal_force_n), 4)}


def main() -> None:
    rows = [press(shape, k, f) for shape in SHAPES for k in STIFFNESSES for f in FORCES_N]
    result = {"machine": machine(), "sensor": SENSOR, "chosen_stiffness": GripperParams().pad_solref[0] * -1,
              "rows": rows}
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "contact_calibration.json").write_text(json.dumps(result, indent=2) + "\n")
    fig, axes = plt.subplots(1, len(SHAPES), figsize=(11, 4.2))
    for ax, shape in zip(axes, SHAPES):
        for k in STIFFNESSES:
            sel = [r for r in rows if r["shape"] == shape and r["stiffness"] == k]
            ax.plot([r["penetration_mm"] for r in sel], [r["finger_force_n"] for r in sel], "o-",
                    label=f"MuJoCo pad, stiffness {k:g}")
        sel = sorted((r for r in rows if r["shape"] == shape), key=lambda r: r["penetration_mm"])
        ax.plot([r["penetration_mm"] for r in sel], [r["elastic_force_n"] for r in sel], "k--",
                label="elastic gel model at the same depth")
        ax.set_xlabel("indentation (mm)")
        ax.set_ylabel("normal force (N)")
        ax.set_title(f"{shape} indenter, {SENSOR}", fontsize=9)
        ax.set_xlim(0, 2.0)
        ax.legend(fontsize=7)
    fig.suptitle("Pad contact stiffness against the elastic gel (the default is 1500)", fontsize=10)
    fig.tight_layout()
    fig.savefig(FIGURES / "contact_calibration.png", dpi=100)
    print(json.dumps(rows))


if __name__ == "__main__":
    main()
