"""Where does the key's end stop fail? A sweep of the MuJoCo timestep, the solver settings, the stop's
stiffness (the joint limit's time constant and the lock core's armature) and the key's turning damping,
each around the task's defaults, on Pull-out Key's own expert.

For each setting the expert runs on a few seeds. Recorded: whether the pads feel the stop (the expert's
indentation-rise signal fires before it has turned 25 deg past the release angle the camera sees), how far
the key goes past the stop (the limit's penetration, deg), how far the gripper overshoots where it first
felt the stop (deg), the largest pad indentation (mm, against the 1.5 mm safe limit), the key's peak kinetic
energy (J: energy the solver injects shows here; a key turned at 1.2 rad/s has under 1e-4 J), whether the
task succeeds, and the wall time per physics step (the whole rollout's wall time over its physics steps:
the expert's touch readings, one pair of gap fields a policy step, included). A setting breaks when the stop is not felt, a run goes
non-finite, or the task fails on a seed where the defaults succeed.

    python benchmarks/key_detent_stability.py              # about 3 minutes on one core
    python benchmarks/key_detent_stability.py --plot-only  # redraw the chart from the JSON

Writes benchmarks/results/key_detent_stability.json and docs/figures/key_detent_stability.png.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, replace
from typing import Any

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from common import FIGURES, RESULTS, machine  # noqa: E402
from expert_runs import swept_config  # noqa: E402

from univtac_data.generators.scene.threads import one_blas_thread  # noqa: E402
from univtac_data.generators.tasks.base import TaskConfig  # noqa: E402
from univtac_data.generators.tasks.expert_rollout import expert_rollout  # noqa: E402
from univtac_data.generators.tasks.pull_out_key import (  # noqa: E402
    STOP_RAD,
    STOP_SOLREF,
    TURN_ARMATURE_KGM2,
    TURN_DAMPING_NMS,
    PullOutKey,
)
from univtac_data.schema.sensors import get_sensor  # noqa: E402

SEEDS = (0, 1, 2, 3, 4, 5)
DEFAULT_OPTION = 'cone="elliptic" noslip_iterations="4"'


@dataclass(frozen=True)
class Setting:
    timestep_s: float = 0.001
    solver: str = "elliptic, noslip 4"
    stop_timeconst_s: float = STOP_SOLREF[0]
    armature_kgm2: float = TURN_ARMATURE_KGM2
    damping_nms: float = TURN_DAMPING_NMS


SOLVERS = {  # label -> the option attributes that replace the task's cone and noslip
    "elliptic, noslip 4": DEFAULT_OPTION,
    "elliptic, noslip 0": 'cone="elliptic" noslip_iterations="0"',
    "pyramidal, noslip 0": 'cone="pyramidal" noslip_iterations="0"',
    "elliptic, noslip 4, 10 iterations": 'cone="elliptic" noslip_iterations="4" iterations="10"',
}
SWEEPS: dict[str, tuple[str, list[Any]]] = {
    "timestep (ms)": ("timestep_s", [0.0005, 0.001, 0.002]),
    "solver": ("solver", list(SOLVERS)),
    "stop time constant (s)": ("stop_timeconst_s", [0.002, 0.004, 0.01, 0.03, 0.1]),
    "stop armature (kg m^2)": ("armature_kgm2", [0.0, 2e-5, 2e-4, 2e-3]),
    "turning damping (N m s)": ("damping_nms", [1e-5, 1e-4, 1e-3, 1e-2]),
}


class SweptKey(PullOutKey):
    """Pull-out Key with a swept solver option."""

    def __init__(self, config: TaskConfig, setting: Setting) -> None:
        super().__init__(config, get_sensor("gelsight_mini"), stop_solref=(setting.stop_timeconst_s, 1.0),
                         turn_damping_nms=setting.damping_nms, turn_armature=setting.armature_kgm2)
        self.option = SOLVERS[setting.solver]

    def scene_xml(self, layout: dict[str, Any]) -> str:
        return super().scene_xml(layout).replace(DEFAULT_OPTION, self.option)


def run_seed(setting: Setting, seed: int) -> dict[str, Any]:
    config = swept_config(setting.timestep_s)
    task = SweptKey(config, setting)
    with expert_rollout(task, seed) as run:
        session, ctx, state = run.session, run.ctx, run.state
        model, data = session.sim.model, session.sim.data
        turn, pull = model.joint("key_turn"), model.joint("key_pull")
        qadr, dadr, padr = turn.qposadr[0], turn.dofadr[0], pull.dofadr[0]
        body = model.body("key").id
        # kinetic energy of the key's two joints: its inertia about the axis plus the armatures
        inertia = float(model.body_inertia[body][2] + model.dof_armature[dadr])
        mass = float(model.body_subtreemass[body] + model.dof_armature[padr])
        peak_angle, peak_energy, deepest, finite = -math.inf, 0.0, 0.0, True
        start = time.perf_counter()
        for step in run.steps():
            state = run.take(step)
            if not session.sim.finite():
                finite = False
                break
            peak_angle = max(peak_angle, float(data.qpos[qadr]))
            energy = 0.5 * inertia * float(data.qvel[dadr]) ** 2 + 0.5 * mass * float(data.qvel[padr]) ** 2
            peak_energy = max(peak_energy, energy)
            deepest = max(deepest, state.indentation_mm)
        wall = time.perf_counter() - start
        corrections = ctx.memory["corrections"]
        return {"seed": seed, "finite": finite, "felt": bool(ctx.memory.get("stop_felt")),
                "success": bool(finite and task.success(state)),
                "stop_penetration_deg": math.degrees(peak_angle - STOP_RAD) if finite else None,
                "overshoot_deg": corrections[0]["overshoot_deg"] if corrections else None,
                "rise_mm": corrections[0]["rise_mm"] if corrections else None,
                "max_indentation_mm": deepest, "peak_energy_j": peak_energy,
                "us_per_physics_step": wall / max(1, session.steps * config.ticks_per_step
                                                  * config.control_period_steps) * 1e6}


def summarise(runs: list[dict[str, Any]]) -> dict[str, Any]:
    def worst(key: str) -> float | None:
        values = [r[key] for r in runs if r[key] is not None]
        return max(values) if values else None

    out = {"felt": sum(r["felt"] for r in runs) / len(runs), "success": sum(r["success"] for r in runs) / len(runs),
           "finite": all(r["finite"] for r in runs), "stop_penetration_deg": worst("stop_penetration_deg"),
           "overshoot_deg": worst("overshoot_deg"), "max_indentation_mm": worst("max_indentation_mm"),
           "peak_energy_j": worst("peak_energy_j"),
           "us_per_physics_step": float(np.median([r["us_per_physics_step"] for r in runs]))}
    out["broken"] = bool(out["felt"] < 1 or not out["finite"] or out["success"] < 1)
    return out


def main() -> None:
    results: dict[str, Any] = {"machine": machine(threads_used=1), "seeds": list(SEEDS),
                               "defaults": Setting().__dict__, "sweeps": {}}
    with one_blas_thread():
        for title, (field, values) in SWEEPS.items():
            rows = []
            for value in values:
                setting = replace(Setting(), **{field: value})
                runs = [run_seed(setting, seed) for seed in SEEDS]
                row = {"value": value, **summarise(runs), "runs": runs}
                rows.append(row)
                print(f"{title:26s} {value!s:36s} felt {row['felt']:.0%} success {row['success']:.0%} "
                      f"past stop {row['stop_penetration_deg']} overshoot {row['overshoot_deg']} "
                      f"{row['us_per_physics_step']:.1f} us/step{'  BROKEN' if row['broken'] else ''}", flush=True)
            results["sweeps"][title] = {"field": field, "rows": rows}
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "key_detent_stability.json").write_text(json.dumps(results, indent=1))
    plot(results)


def policy_step_ms(row: dict[str, Any], field: str) -> float:
    """Wall time of one 20 ms policy step, ms: the physics steps it takes at the row's timestep, touch included."""
    timestep = row["value"] if field == "timestep_s" else Setting().timestep_s
    return row["us_per_physics_step"] * (0.02 / timestep) / 1000.0


def plot(results: dict[str, Any]) -> None:
    sweeps = results["sweeps"]
    fig, axes = plt.subplots(3, len(sweeps), figsize=(4.2 * len(sweeps), 9.5), squeeze=False)
    for col, (title, sweep) in enumerate(sweeps.items()):
        rows = sweep["rows"]
        labels = [f"{v * 1000:g}" if sweep["field"] == "timestep_s" else str(v) for v in (r["value"] for r in rows)]
        x = np.arange(len(rows))
        default = Setting().__dict__[sweep["field"]]
        top, mid, bottom = axes[0, col], axes[1, col], axes[2, col]
        pen = [np.nan if r["stop_penetration_deg"] is None else r["stop_penetration_deg"] for r in rows]
        over = [np.nan if r["overshoot_deg"] is None else r["overshoot_deg"] for r in rows]
        top.plot(x, pen, "o-", label="key past the stop (deg)")
        top.plot(x, over, "s-", label="gripper past first felt (deg)")
        top.axhline(3.7, color="0.6", ls=":", lw=1)
        mid.plot(x, [r["max_indentation_mm"] for r in rows], "o-", color="tab:purple", label="max indentation (mm)")
        mid.plot(x, [r["success"] for r in rows], "^-", color="tab:green", label="success (fraction)")
        mid.plot(x, [r["felt"] for r in rows], "v--", color="tab:olive", label="stop felt (fraction)")
        mid.axhline(1.5, color="0.6", ls=":", lw=1)
        bottom.plot(x, [policy_step_ms(r, sweep["field"]) for r in rows], "o-", color="tab:gray",
                    label="wall ms / policy step")
        bottom.set_ylim(bottom=0)
        energy = bottom.twinx()
        energy.semilogy(x, [max(r["peak_energy_j"], 1e-9) for r in rows], "d--", color="tab:red", label="key peak KE (J)")
        energy.set_ylim(1e-5, 1e-1)
        energy.set_ylabel("key peak kinetic energy, J", color="tab:red")
        for ax in (top, mid, bottom):
            ax.set_xticks(x, labels, rotation=20, fontsize=8)
            for k, r in enumerate(rows):
                if r["broken"]:
                    ax.axvspan(k - 0.4, k + 0.4, color="tab:red", alpha=0.12)
                if r["value"] == default:
                    ax.axvspan(k - 0.4, k + 0.4, color="tab:green", alpha=0.10)
        top.set_title(title)
        bottom.set_xlabel(title)
        if col == 0:
            top.set_ylabel("deg")
            mid.set_ylabel("mm / fraction")
            bottom.set_ylabel("wall ms per 20 ms policy step")
            top.legend(fontsize=7)
            mid.legend(fontsize=7)
            bottom.legend(fontsize=7, loc="upper left")
            energy.legend(fontsize=7, loc="upper right")
    fig.suptitle("Pull-out Key's end stop: red = broken (stop not felt, non-finite, or a seed fails), green = chosen; "
                 "dotted: keyway window 3.7 deg, safe indentation 1.5 mm", fontsize=10)
    fig.tight_layout()
    FIGURES.mkdir(parents=True, exist_ok=True)
    fig.savefig(FIGURES / "key_detent_stability.png", dpi=110)


if __name__ == "__main__":
    import sys

    if "--plot-only" in sys.argv:  # redraw the chart from the saved results
        plot(json.loads((RESULTS / "key_detent_stability.json").read_text()))
    else:
        main()
