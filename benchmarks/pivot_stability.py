"""Where does the pivot in a loosened grasp fail? Put Bottle in Shelf's swing, swept over the MuJoCo timestep,
the solver (noslip iterations, friction cone, impratio) and the grip (the press the pads are held at).

Each case builds the task's scene (seeds 0 and 1), grasps the bottle with the task's tactile law, lifts it and
tilts the hand 60-71.5 deg about the closing axis as the expert does, then holds the hand still for 1.5 s
while a press regulator keeps the shallower pad at the case's press depth (the loosened grasp; "tight" keeps
the grasp as made). Recorded per case (mean over the seeds, worst for the failure measures):

- pivot angle, deg: how far the bottle turned towards upright (ground truth);
- penetration, mm: the deepest pad-bottle overlap during the hold (against the Mini's 1.5 mm safe limit);
- energy gain, mJ: the largest rise of the bottle's mechanical energy (kinetic + potential) above its value
  when the hold began. The hand is still, so contact can only take energy out: a rise is energy the solver
  made up;
- drift, mm: how far the bottle's origin moved in the gripper frame (it sinks along the pads, and the turn
  moves it when it sits off the pads' centre line: the task's in-hand slip);
- wall time per physics step, us, and per policy step (20 ms simulated: what a finer timestep costs), ms.

Under every solver case (timestep, noslip, cone, impratio; the grip cases are the swing's press, which the
expert regulates itself) the task's whole expert also runs on ``--expert-seeds`` seeds (default 20: grasp,
lift, tilt, swing upright in the loosened grasp, re-grasp, place): its success rate with a 95 % Wilson interval
and its safety say whether the task survives the setting, not only the swing.

A case **breaks** when the state goes non-finite, its pivot angle is more than 10 deg off the 0.25 ms case's (the
finest timestep is the reference), the energy gain exceeds 5 mJ (a 0.275 kg bottle lifted 2 mm),
the penetration exceeds 1.5 mm, or the bottle drifts more than 10 mm in the hand (the task's in-hand slip limit).

    python benchmarks/pivot_stability.py [--expert-seeds 20]

Writes benchmarks/results/pivot_stability.json and docs/figures/pivot_stability.png.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass, replace

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from common import FIGURES, RESULTS, machine  # noqa: E402
from expert_runs import swept_config, whole_expert  # noqa: E402

from univtac_data.envs.evaluate import wilson_interval  # noqa: E402
from univtac_data.generators.scene.contact_pairs import TASK_OPTION_XML  # noqa: E402
from univtac_data.generators.scene.geometry import quat_from_axis_angle, quat_mul, quat_to_mat  # noqa: E402
from univtac_data.generators.tasks.base import ExpertContext, TaskConfig  # noqa: E402
from univtac_data.generators.tasks.motions import close_until, move_to  # noqa: E402
from univtac_data.generators.tasks.put_bottle_in_shelf import PIVOT_MIN_DEPTH_MM, PutBottleInShelf, grasp_law  # noqa: E402
from univtac_data.generators.tasks.session import TaskSession  # noqa: E402
from univtac_data.schema.sensors import get_sensor  # noqa: E402

SEEDS = (0, 1)
HOLD_S = 1.5
GRAVITY = 9.81
BREAK_ENERGY_MJ = 5.0
BREAK_PENETRATION_MM = 1.5
BREAK_DRIFT_MM = 10.0
BREAK_PIVOT_OFF_DEG = 10.0
DEFAULT_PRESS_MM = PIVOT_MIN_DEPTH_MM  # 0.09 mm: where the task's swing spends most of its time
REGULATOR_STEP_M = 0.00003  # opening change a policy step while regulating the press, m


@dataclass(frozen=True)
class Case:
    """One setting: MuJoCo timestep (s), noslip iterations, cone, impratio, press held during the swing (mm;
    None: the grasp as made)."""

    sweep: str
    timestep_s: float = 0.001
    noslip: int = 4
    cone: str = "elliptic"
    impratio: float = 1.0
    press_mm: float | None = 0.09  # DEFAULT_PRESS_MM

    @property
    def option_xml(self) -> str:
        return (f'<option timestep="{self.timestep_s}" integrator="implicitfast" cone="{self.cone}" '
                f'noslip_iterations="{self.noslip}" impratio="{self.impratio}"/>')


class SweptTask(PutBottleInShelf):
    """Put Bottle in Shelf with the case's solver options in place of the kit's."""

    def __init__(self, case: Case, config: TaskConfig | None = None) -> None:
        super().__init__(config or TaskConfig(cameras=False, timestep_s=case.timestep_s), get_sensor("gelsight_mini"))
        self.case = case

    def scene_xml(self, layout):  # type: ignore[no-untyped-def]
        option = TASK_OPTION_XML.split("\n")[0]
        xml = super().scene_xml(layout)
        if option not in xml:
            raise RuntimeError(f"the task scene no longer holds the kit's {option}: update this benchmark")
        return xml.replace(option, self.case.option_xml)


def run_expert_seed(case: Case, seed: int) -> dict[str, object]:
    """The task's whole expert under ``case``'s solver options from ``seed``, not recorded; the controller ticks
    every 2 ms whatever the timestep, as in the task."""
    run = whole_expert(SweptTask(case, swept_config(case.timestep_s)), seed)
    return {"seed": seed, "success": run.success, "safe": run.safe, "finite": run.finite,
            "first_violation": run.first_violation}


def bottle_energy_j(session: TaskSession) -> float:
    """Kinetic + potential energy of the bottle, J (world frame, table height 0)."""
    model, data = session.sim.model, session.sim.data
    body = model.body("bottle").id
    mass = float(model.body_mass[body])
    omega_world, v_origin = data.cvel[body][:3], data.cvel[body][3:]
    # cvel is about the subtree's centre of mass; the bottle is a leaf, so that is its own centre of mass
    rot = data.ximat[body].reshape(3, 3)
    omega_local = rot.T @ omega_world
    kinetic = 0.5 * mass * float(v_origin @ v_origin) + 0.5 * float(model.body_inertia[body] @ omega_local ** 2)
    return kinetic + mass * GRAVITY * float(data.xipos[body][2])


def tilt_deg(session: TaskSession) -> float:
    axis = quat_to_mat(session.sim.object_pose("bottle")[3:])[:, 2]
    return math.degrees(math.acos(max(-1.0, min(1.0, float(axis[2])))))


def run(case: Case, seed: int) -> dict[str, float | bool]:
    task = SweptTask(case)
    session = TaskSession(task)
    try:
        session.reset(seed)
        ctx = ExpertContext(session, session.rng)
        law = grasp_law(task.profile)

        def drive(steps):  # type: ignore[no-untyped-def]
            for step in steps:
                session.step(step.action, step.primitive)
                if not session.sim.finite():
                    raise FloatingPointError

        drive(move_to(ctx, task.seen_bottle(session.layout), speed_m_s=0.35))
        drive(close_until(ctx, law))
        closing = quat_to_mat(ctx.target[3:7])[:, 0]
        tilted = quat_mul(quat_from_axis_angle(closing, session.layout["tilt_rad"]), ctx.target[3:7])
        drive(move_to(ctx, ctx.target[:3] + [0.0, 0.0, session.layout["lift_m"]], tilted, speed_m_s=0.4,
                      turn_rad_s=3.0, primitive="tilt"))
        start_tilt, start_energy = tilt_deg(session), bottle_energy_j(session)
        ee = session.sim.ee_pose()
        start_in_hand = quat_to_mat(ee[3:]).T @ (session.sim.object_pose("bottle")[:3] - ee[:3])
        gain = penetration = sink = 0.0
        physics_steps = 0
        wall = 0.0
        for _ in range(round(HOLD_S * task.config.rate_hz)):
            action = ctx.target.copy()
            if case.press_mm is not None:
                depth = min(ctx.indentation_mm().values())
                action[7] += float(np.clip((depth - case.press_mm) * 1e-3, -REGULATOR_STEP_M, 3 * REGULATOR_STEP_M))
            ctx.target = action
            began = time.perf_counter()
            state = session.step(action, "swing")
            wall += time.perf_counter() - began
            physics_steps += task.config.ticks_per_step * task.config.control_period_steps
            if not session.sim.finite():
                raise FloatingPointError
            gain = max(gain, (bottle_energy_j(session) - start_energy) * 1000.0)
            penetration = max(penetration, state.indentation_mm)
            ee = state.ee_pose
            in_hand = quat_to_mat(ee[3:]).T @ (state.objects["bottle"][:3] - ee[:3])
            sink = max(sink, float(np.linalg.norm(in_hand - start_in_hand)) * 1000.0)
        policy_steps = round(HOLD_S * task.config.rate_hz)
        return {"finite": True, "pivot_deg": start_tilt - tilt_deg(session), "end_tilt_deg": tilt_deg(session),
                "penetration_mm": penetration, "energy_gain_mj": gain, "drift_mm": sink,
                "us_per_step": wall / physics_steps * 1e6, "ms_per_policy_step": wall / policy_steps * 1e3}
    except FloatingPointError:
        return {"finite": False, "pivot_deg": float("nan"), "end_tilt_deg": float("nan"),
                "penetration_mm": float("nan"), "energy_gain_mj": float("nan"), "drift_mm": float("nan"),
                "us_per_step": float("nan"), "ms_per_policy_step": float("nan")}
    finally:
        session.close()


def broken(row: dict[str, float | bool], reference_pivot_deg: float) -> str | None:
    if not row["finite"]:
        return "non-finite state"
    if row["press_mm"] == DEFAULT_PRESS_MM and abs(row["pivot_deg"] - reference_pivot_deg) > BREAK_PIVOT_OFF_DEG:
        return f"pivot {row['pivot_deg']:.0f} deg against {reference_pivot_deg:.0f} at 0.25 ms"
    if row["energy_gain_mj"] > BREAK_ENERGY_MJ:
        return f"energy gain {row['energy_gain_mj']:.1f} mJ"
    if row["penetration_mm"] > BREAK_PENETRATION_MM:
        return f"penetration {row['penetration_mm']:.2f} mm"
    if row["drift_mm"] > BREAK_DRIFT_MM:
        return f"drifted {row['drift_mm']:.1f} mm"
    return None


def cases() -> list[Case]:
    base = Case("default")
    out = [base]
    out += [replace(base, sweep="timestep", timestep_s=dt) for dt in (0.00025, 0.0005, 0.002)]
    out += [replace(base, sweep="noslip", noslip=n) for n in (0, 1, 10)]
    out += [replace(base, sweep="cone", cone="pyramidal")]
    out += [replace(base, sweep="impratio", impratio=r) for r in (3.0, 10.0)]
    out += [replace(base, sweep="grip", press_mm=p) for p in (None, 0.3, 0.15, 0.05, 0.02)]
    return out


def label(case: Case) -> str:
    if case.sweep == "default":
        return "default (1 ms, noslip 4, elliptic, impratio 1, press 0.09 mm)"
    value = {"timestep": f"{case.timestep_s * 1000:g} ms", "noslip": f"noslip {case.noslip}", "cone": case.cone,
             "impratio": f"impratio {case.impratio:g}",
             "grip": "tight (as grasped)" if case.press_mm is None else f"press {case.press_mm:g} mm"}[case.sweep]
    return value


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--expert-seeds", type=int, default=20,
                        help="seeds of the task's whole expert per solver case (0: none)")
    parser.add_argument("--plot-only", action="store_true", help="redraw the chart from the stored JSON")
    args = parser.parse_args()
    if args.plot_only:
        plot(json.loads((RESULTS / "pivot_stability.json").read_text())["rows"])
        return 0
    rows = []
    for case in cases():
        runs = [run(case, seed) for seed in SEEDS]
        finite = all(r["finite"] for r in runs)
        row: dict[str, object] = {"sweep": case.sweep, "label": label(case), "timestep_s": case.timestep_s,
                                  "noslip_iterations": case.noslip, "cone": case.cone, "impratio": case.impratio,
                                  "press_mm": case.press_mm, "finite": finite}
        for key in ("pivot_deg", "end_tilt_deg", "us_per_step", "ms_per_policy_step"):
            row[key] = float(np.mean([r[key] for r in runs]))
        for key in ("penetration_mm", "energy_gain_mj", "drift_mm"):
            row[key] = float(np.max([r[key] for r in runs]))
        if case.sweep != "grip" and args.expert_seeds > 0:
            experts = [run_expert_seed(case, seed) for seed in range(args.expert_seeds)]
            wins = sum(bool(e["success"]) for e in experts)
            row.update(expert_seeds=len(experts), expert_success=wins / len(experts),
                       expert_success_95=[round(v, 3) for v in wilson_interval(wins, len(experts))],
                       expert_safe=sum(bool(e["safe"]) for e in experts) / len(experts), expert_runs=experts)
        rows.append(row)
    reference = next(r["pivot_deg"] for r in rows if r["sweep"] == "timestep" and r["timestep_s"] == 0.00025)
    for row in rows:
        row["breaks"] = broken(row, reference)  # type: ignore[arg-type]
        print(f"{row['label']:<58} pivot {row['pivot_deg']:6.1f} deg  pen {row['penetration_mm']:.3f} mm  "
              f"gain {row['energy_gain_mj']:7.2f} mJ  drift {row['drift_mm']:5.1f} mm  {row['us_per_step']:6.1f} us/step"
              f"  {row['ms_per_policy_step']:5.2f} ms/policy step"
              + (f"  expert {row['expert_success']:.0%} ({row['expert_safe']:.0%} safe)" if "expert_success" in row
                 else ""), flush=True)
    for row in rows:
        print(f"{row['label']:<58} {row['breaks'] or 'ok'}")
    RESULTS.mkdir(parents=True, exist_ok=True)
    out = {"machine": machine(threads_used=1), "seeds": list(SEEDS), "expert_seeds": args.expert_seeds,
           "hold_s": HOLD_S,
           "break_rules": {"energy_gain_mj": BREAK_ENERGY_MJ, "penetration_mm": BREAK_PENETRATION_MM,
                           "drift_mm": BREAK_DRIFT_MM, "pivot_off_reference_deg": BREAK_PIVOT_OFF_DEG,
                           "finite": True},
           "rows": rows}
    (RESULTS / "pivot_stability.json").write_text(json.dumps(out, indent=1))
    plot(rows)
    return 0


def plot(rows: list[dict[str, object]]) -> None:
    fig, axes = plt.subplots(1, 4, figsize=(20, 4.8))
    metrics = (("pivot_deg", "pivot angle towards upright, deg"), ("penetration_mm", "deepest pad penetration, mm"),
               ("energy_gain_mj", "bottle energy gain, mJ"),
               ("expert_success", "the task's whole expert: success, 95 % interval"))
    colours = {"default": "k", "timestep": "tab:blue", "noslip": "tab:orange", "cone": "tab:green",
               "impratio": "tab:purple", "grip": "tab:red"}
    for ax, (key, title) in zip(axes, metrics):
        for row in rows:
            x = row["ms_per_policy_step"] if row["finite"] else np.nan
            y = row.get(key)
            if not row["finite"] or y is None or not np.isfinite(y):  # type: ignore[arg-type]
                continue
            marker = "x" if row["breaks"] else "o"
            ax.scatter(x, y, c=colours[row["sweep"]], marker=marker, s=50)
            if key == "expert_success":
                low, high = row["expert_success_95"]  # type: ignore[misc]
                ax.errorbar(x, y, yerr=[[y - low], [high - y]], fmt="none", ecolor=colours[row["sweep"]],
                            elinewidth=1, capsize=2)
            ax.annotate(str(row["label"]).split(" (")[0], (x, y), fontsize=7, xytext=(3, 3), textcoords="offset points")
        ax.set_xlabel("wall time per policy step (20 ms simulated), ms, one core")
        ax.set_title(title)
        ax.grid(alpha=0.3)
    axes[1].axhline(BREAK_PENETRATION_MM, color="r", lw=0.8, ls="--")
    axes[2].axhline(BREAK_ENERGY_MJ, color="r", lw=0.8, ls="--")
    handles = [plt.Line2D([], [], color=c, marker="o", ls="", label=k) for k, c in colours.items()]
    handles.append(plt.Line2D([], [], color="grey", marker="x", ls="", label="breaks"))
    axes[0].legend(handles=handles, fontsize=8)
    broken_rows = [r["label"] for r in rows if not r["finite"]]
    seeds = next((r["expert_seeds"] for r in rows if "expert_seeds" in r), 0)
    fig.suptitle("Put Bottle in Shelf: the bottle's swing in a loosened grasp (1.5 s hold, seeds 0-1)"
                 + (f"; the whole expert on seeds 0-{seeds - 1} under each solver case" if seeds else "")
                 + (f"; non-finite: {', '.join(map(str, broken_rows))}" if broken_rows else ""), fontsize=10)
    fig.tight_layout()
    FIGURES.mkdir(parents=True, exist_ok=True)
    fig.savefig(FIGURES / "pivot_stability.png", dpi=110)


if __name__ == "__main__":
    sys.exit(main())
