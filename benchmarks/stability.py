"""Where does the simulation fail? A sweep of the MuJoCo timestep, the pad contact stiffness, the closing
speed and the grasp law (closed loop versus an open-loop squeeze), plus the elastic solver on grazing and
multi-patch contacts.

For each setting a gripper closes on the sphere indenter and holds for 0.3 s. Recorded: the deepest gel
indentation (against the sensor's safe limit), whether any state went non-finite, whether the fingers'
kinetic energy grows while the gripper holds still (energy injected without work done), and MuJoCo's own
warnings. The open-loop squeeze is what a parallel gripper does without touch: close until the motor's
force limit (5 N here, a light grasp), with no tactile feedback.

    python benchmarks/stability.py

Writes benchmarks/results/stability.json and docs/figures/stability.png.
"""

from __future__ import annotations

import json
import math
import sys
from dataclasses import replace

import matplotlib
import mujoco
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from common import FIGURES, RESULTS, machine  # noqa: E402

from univtac_data.generators.scene.gripper import MIN_OPENING_M, PADS, GripperParams  # noqa: E402
from univtac_data.generators.indenters.scene import (  # noqa: E402
    PAD_SIDE,
    SceneConfig,
    indenter_geom_names,
    indenter_scene_xml,
)
from univtac_data.generators.indenters.shapes import INDENTERS  # noqa: E402
from univtac_data.generators.scene.primitives import (  # noqa: E402
    PRIMITIVE_NAMES,
    GraspParams,
    grasp,
    squeeze_open_loop,
)
from univtac_data.generators.scene.sim import GripperSim, SimConfig  # noqa: E402
from univtac_data.generators.tactile import ContactConfig, TactileConfig, demo_gap, simulate_frame  # noqa: E402
from univtac_data.schema.sensors import get_sensor  # noqa: E402

SENSOR = "gelsight_mini"
TIMESTEPS_S = [0.00025, 0.0005, 0.001, 0.002, 0.004, 0.008, 0.016, 0.032]
STIFFNESSES = [150.0, 500.0, 1500.0, 5000.0, 15000.0, 50000.0, 5e5, 5e6]
SPEEDS_M_S = [0.02, 0.06, 0.2, 0.6, 2.0]
DEFAULTS = {"timestep_s": 0.001, "stiffness": 1500.0, "v_fast_m_s": 0.06}
THRESHOLD_MM = 0.5
FORCE_LIMIT_N = 5.0


def run_case(timestep_s: float, stiffness: float, v_fast: float, mode: str) -> dict[str, object]:
    profile, indenter = get_sensor(SENSOR), INDENTERS["sphere"]
    gripper = replace(GripperParams(), pad_solref=(-stiffness, -2 * math.sqrt(stiffness) * 3),
                      finger_force_limit_n=FORCE_LIMIT_N)
    xml = indenter_scene_xml(profile, indenter, config=SceneConfig(timestep_s=timestep_s, gripper=gripper),
                             gripper_pos=(0.0, 0.0, 0.081))
    model = mujoco.MjModel.from_xml_string(xml)
    # the controller ticks at 500 Hz whatever the physics step (at least one step a tick)
    period = max(1, round(0.002 / timestep_s))
    sim = GripperSim(model, profile, {p: indenter_geom_names(indenter, PAD_SIDE[p]) for p in PADS}, "indenter",
                     PRIMITIVE_NAMES, SimConfig(record_rate_hz=None, control_period_steps=period))
    sim.set_opening(0.030)
    for _ in range(round(2.0 / sim.dt_s)):  # the fingers, force-limited, take a while to get there
        sim.tick()
        if abs(sim.opening_m - 0.030) < 5e-4:
            break
    deepest, finite = 0.0, True
    tick = sim.tick

    def observed_tick() -> None:  # every primitive steps through here: record the deepest press
        nonlocal deepest, finite
        tick()
        finite = finite and sim.finite()
        if finite:
            deepest = max(deepest, max(-g for g in sim.gap_mm().values()))

    sim.tick = observed_tick  # type: ignore[method-assign]
    energies: list[float] = []
    try:
        if mode == "closed":
            grasp(sim, GraspParams(threshold_mm=THRESHOLD_MM, v_fast_m_s=v_fast, timeout_s=1.5))
        else:
            n = max(1, math.ceil((sim.opening_m - MIN_OPENING_M) / 2 / (v_fast * sim.dt_s)))
            start = sim.finger_setpoints_m.copy()
            for k in range(1, n + 1):  # ramp the command at the closing speed, then hold it
                sim.finger_setpoints_m[:] = start + (0.038 - start) * k / n
                sim.tick()
            squeeze_open_loop(sim, MIN_OPENING_M, 0.0)
        previous = sim.finger_positions_m()
        for _ in range(round(0.3 / sim.dt_s)):
            sim.tick()
            if not finite:
                break
            velocity = (sim.finger_positions_m() - previous) / sim.dt_s
            previous = sim.finger_positions_m()
            energies.append(0.5 * GripperParams().finger_mass_kg * float(np.sum(velocity**2)))
    except (FloatingPointError, ValueError):
        finite = False
    warnings = int(sum(w.number for w in sim.data.warning))
    half = len(energies) // 2
    growing = bool(finite and half > 2 and max(energies[half:]) > 10 * max(max(energies[:half]), 1e-9))
    deepest = deepest if finite and math.isfinite(deepest) else float("nan")
    safe = profile.safe_indentation_mm
    return {
        "timestep_s": timestep_s, "stiffness": stiffness, "v_fast_m_s": v_fast, "mode": mode,
        "max_indentation_mm": round(deepest, 4) if finite else None, "finite": finite, "energy_growth": growing,
        "mujoco_warnings": warnings,
        "stable": bool(finite and not growing and warnings == 0 and deepest <= safe),
    }


def elastic_convergence() -> list[dict[str, object]]:
    """The elastic solver on grazing to deep presses, with the half-space and the bonded-layer gel."""
    profile = get_sensor(SENSOR)
    rows = []
    for gel in ("half_space", "layer"):
        config = TactileConfig(contact=ContactConfig(method="elastic", gel=gel))  # type: ignore[arg-type]
        for name in ("sphere", "cylinder", "cross", "two_spheres"):
            for depth in (0.0005, 0.002, 0.01, 0.05, 0.2, 0.5, 1.0, 1.4):
                frame = simulate_frame(profile, demo_gap(profile, name, depth), config=config)
                rows.append({"gel": gel, "shape": name, "depth_mm": depth, "iterations": frame.iterations,
                             "converged": frame.converged, "force_n": round(float(frame.normal_force_n), 5)})
    return rows


def chart(result: dict, path) -> None:  # type: ignore[no-untyped-def,type-arg]
    safe = result["safe_indentation_mm"]
    fig, axes = plt.subplots(1, 4, figsize=(20, 4.6))
    for ax, mode in zip(axes[:2], ("closed", "open")):
        grid = np.full((len(STIFFNESSES), len(TIMESTEPS_S)), np.nan)
        for row in result["grid"]:
            if row["mode"] == mode:
                i, j = STIFFNESSES.index(row["stiffness"]), TIMESTEPS_S.index(row["timestep_s"])
                grid[i, j] = row["max_indentation_mm"] / safe if row["max_indentation_mm"] is not None else np.nan
        image = ax.imshow(grid, origin="lower", cmap="RdYlGn_r", vmin=0, vmax=2, aspect="auto")
        for row in result["grid"]:
            if row["mode"] != mode:
                continue
            i, j = STIFFNESSES.index(row["stiffness"]), TIMESTEPS_S.index(row["timestep_s"])
            mark = "ok" if row["stable"] else ("NaN" if not row["finite"] else "E" if row["energy_growth"]
                                                else "W" if row["mujoco_warnings"] else ">")
            ax.text(j, i, mark, ha="center", va="center", fontsize=8)
        ax.set_xticks(range(len(TIMESTEPS_S)), [f"{t * 1000:g}" for t in TIMESTEPS_S])
        ax.set_yticks(range(len(STIFFNESSES)), [f"{s:g}" for s in STIFFNESSES])
        ax.set_xlabel("MuJoCo timestep (ms)")
        ax.set_ylabel("pad contact stiffness (solref, direct)")
        ax.set_title(f"{'closed-loop grasp' if mode == 'closed' else 'open-loop squeeze (5 N)'}: "
                     f"max depth / safe limit", fontsize=9)
        i, j = STIFFNESSES.index(DEFAULTS["stiffness"]), TIMESTEPS_S.index(DEFAULTS["timestep_s"])
        ax.add_patch(plt.Rectangle((j - 0.5, i - 0.5), 1, 1, fill=False, lw=2, ec="blue"))
    fig.colorbar(image, ax=axes[1], label="max indentation / safe limit (>1 unsafe)")
    ax = axes[2]
    for mode, style in (("closed", "o-"), ("open", "s--")):
        rows = [r for r in result["speed"] if r["mode"] == mode]
        ax.plot([r["v_fast_m_s"] * 1000 for r in rows], [r["max_indentation_mm"] or np.nan for r in rows], style,
                label=f"{mode} loop")
    ax.axhline(safe, color="r", lw=1, label="safe limit")
    ax.axhline(THRESHOLD_MM, color="g", lw=1, ls=":", label="grasp threshold")
    ax.set_xscale("log")
    ax.set_xticks([v * 1000 for v in SPEEDS_M_S], [f"{v * 1000:g}" for v in SPEEDS_M_S])
    ax.minorticks_off()
    ax.set_xlabel("closing speed (mm/s)")
    ax.set_ylabel("max indentation (mm)")
    ax.set_title("closing speed, default timestep and stiffness", fontsize=9)
    ax.legend(fontsize=8)
    ax = axes[3]
    for (gel, style), shape in ((g, s) for g in (("half_space", "o-"), ("layer", "^--"))
                                for s in sorted({r["shape"] for r in result["elastic"]})):
        rows = [r for r in result["elastic"] if r["shape"] == shape and r.get("gel", "half_space") == gel]
        ax.plot([r["depth_mm"] for r in rows], [r["iterations"] for r in rows], style,
                label=f"{shape}, {gel.replace('_', '-')}")
        for r in rows:
            if not r["converged"]:
                ax.plot(r["depth_mm"], r["iterations"], "rx", ms=10)
    ax.set_xscale("log")
    ax.set_xlabel("press depth (mm)")
    ax.set_ylabel("Polonsky-Keer CG iterations")
    ax.set_title("elastic solver (red x: not converged)", fontsize=9)
    ax.legend(fontsize=6, ncol=2)
    fig.suptitle("Stability: where the simulation fails (markers: ok, > past the safe limit, E energy growth, "
                 "W MuJoCo warning, NaN non-finite; blue box: defaults)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def main() -> None:
    grid = []
    for mode in ("closed", "open"):
        for timestep in TIMESTEPS_S:
            for stiffness in STIFFNESSES:
                grid.append(run_case(timestep, stiffness, DEFAULTS["v_fast_m_s"], mode))
                print(json.dumps(grid[-1]), file=sys.stderr)
    speed = [run_case(DEFAULTS["timestep_s"], DEFAULTS["stiffness"], v, mode)
             for mode in ("closed", "open") for v in SPEEDS_M_S]
    result = {
        "machine": machine(), "sensor": SENSOR, "indenter": "sphere", "threshold_mm": THRESHOLD_MM,
        "safe_indentation_mm": get_sensor(SENSOR).safe_indentation_mm, "defaults": DEFAULTS,
        "grid": grid, "speed": speed, "elastic": elastic_convergence(),
        "stable_closed_loop": [(r["timestep_s"], r["stiffness"]) for r in grid if r["mode"] == "closed" and r["stable"]],
        "stable_open_loop": [(r["timestep_s"], r["stiffness"]) for r in grid if r["mode"] == "open" and r["stable"]],
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "stability.json").write_text(json.dumps(result, indent=2) + "\n")
    chart(result, FIGURES / "stability.png")
    print(json.dumps({k: result[k] for k in ("defaults", "stable_closed_loop", "stable_open_loop")}, indent=1))


if __name__ == "__main__":
    main()
