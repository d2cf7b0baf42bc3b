"""Where does MuJoCo's contact fail at Insert Tube's clearance? A sweep of the timestep, the contact margin,
the wall contact's stiffness and the solver, and the collider type (boxes, convex mesh pieces, SDF), on a
2.0 cm tube pushed into the task's 2.05 cm bore (0.25 mm radial clearance, 2 mm chamfer).

A trial: the Insert Tube scene, the tube held by the welded gripper with its end 2 mm above the entrance,
off the bore's axis by U(0, 1.5) mm in a random direction (inside the chamfer's reach), pushed 3.7 cm
along the axis at 2 cm/s, held 0.2 s. Recorded per trial: inserted (the task's success: the end 3 cm deep
and within 5 mm of the axis), peak penetration (the deepest tube-wall contact, MuJoCo's ``contact.dist``),
tunnelling (the tube's surface more than 1 mm inside solid material, ``holes.tube_in_solid_mm``),
jamming (stuck above 3 cm depth while the hand went on: the tube slid more than 3 mm up the pads), any
non-finite state; and the wall time of ``mj_step`` alone, per physics step. Per setting, the task's whole expert
(probe, detect the miss by touch, retry, insert; first attempts 1-4 mm off) also runs on ``--expert-seeds``
seeds (the task's own layouts), for its success rate with a 95 % Wilson interval and its safety: the straight
push says whether the contact holds, the expert whether the task does.

    python benchmarks/insertion_stability.py [--trials 8] [--expert-seeds 20]
    python benchmarks/insertion_stability.py --experts-only   # after an expert change: that column alone

Writes benchmarks/results/insertion_stability.json and docs/figures/insertion_stability.png. ``--experts-only``
reruns the expert's column of the stored JSON on its settings and seeds and keeps the push trials and their
timings as measured (they do not depend on the expert, and timings from another machine would not compare);
the JSON's ``experts_rerun`` says when.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import matplotlib
import mujoco
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib import ticker  # noqa: E402
from common import FIGURES, RESULTS, machine  # noqa: E402
from expert_runs import swept_config, whole_expert  # noqa: E402

from univtac_data.envs.evaluate import wilson_interval  # noqa: E402
from univtac_data.generators.scene.geometry import quat_to_mat  # noqa: E402
from univtac_data.generators.tasks.base import ExpertContext, TaskConfig  # noqa: E402
from univtac_data.generators.tasks.holes import HoleContact, tube_in_solid_mm  # noqa: E402
from univtac_data.generators.tasks.insert_tube import BORE, TUBE_HALF_M, TUBE_RADIUS_M, InsertTube  # noqa: E402
from univtac_data.generators.tasks.motions import move_to, wait  # noqa: E402
from univtac_data.generators.tasks.session import TaskSession  # noqa: E402
from univtac_data.schema.sensors import get_sensor  # noqa: E402

TASK = {"timestep_s": 0.001, "contact": HoleContact(), "collider": "boxes", "solver": "Newton",
        "option": 'cone="elliptic" noslip_iterations="4"'}
TASK_OPTION = TASK["option"]  # the cone and noslip attributes of the scenes' <option> (contact_pairs.TASK_OPTION_XML)
MUJOCO_DEFAULT_CONTACT = HoleContact(timeconst_s=0.02, solimp=(0.9, 0.95, 0.001))


def settings() -> list[dict[str, Any]]:
    """One change from the task's settings at a time (the task's row first)."""
    rows = [dict(TASK, group="task")]
    rows += [dict(TASK, group="timestep", timestep_s=dt) for dt in (0.00025, 0.0005, 0.002)]
    rows += [dict(TASK, group="margin", contact=replace(HoleContact(), margin_m=m)) for m in (0.0001, 0.0005)]
    rows += [dict(TASK, group="stiffness", contact=c) for c in
             (MUJOCO_DEFAULT_CONTACT, HoleContact(timeconst_s=0.01), HoleContact(timeconst_s=0.004))]
    rows += [dict(TASK, group="solver", solver=s) for s in ("CG", "PGS")]
    # noslip holds the tube in the pads: a fifth of a step here (its cost grows with the contacts)
    rows += [dict(TASK, group="solver", option=o) for o in
             ('cone="elliptic" noslip_iterations="0"', 'cone="elliptic" noslip_iterations="1"',
              'cone="pyramidal" noslip_iterations="4"')]
    rows += [dict(TASK, group="collider", collider="convex")]
    return rows


class SweptTube(InsertTube):
    """Insert Tube with one row's settings (``settings()``)."""

    def __init__(self, config: TaskConfig, row: dict[str, Any]) -> None:
        super().__init__(config, get_sensor("gelsight_mini"), hole_contact=row["contact"], collider=row["collider"],
                         solver=row["solver"])
        self.option = row["option"]

    def scene_xml(self, layout: dict[str, Any]) -> str:
        xml = super().scene_xml(layout)
        if TASK_OPTION not in xml:
            raise RuntimeError(f"the task scene's <option> no longer holds {TASK_OPTION}: update this benchmark")
        return xml.replace(TASK_OPTION, self.option)


class Trial(SweptTube):
    """Insert Tube with a small first offset (within the chamfer's reach) and a straight push."""

    def sample_layout(self, rng: np.random.Generator) -> dict[str, Any]:
        layout = super().sample_layout(rng)
        r, a = float(rng.uniform(0.0, 0.0015)), float(rng.uniform(-math.pi, math.pi))
        layout["first_offset_m"] = [r * math.cos(a), r * math.sin(a)]
        return layout


def run_trial(row: dict[str, Any], seed: int) -> dict[str, Any]:
    config = TaskConfig(cameras=False, timestep_s=row["timestep_s"])
    task = Trial(config, row)
    session = TaskSession(task)
    state = session.reset(seed)
    sim = session.sim
    model, data = sim.model, sim.data
    tube_geom = model.geom("tube").id
    wall_geoms = {g for g in range(model.ngeom) if model.body(model.geom_bodyid[g]).name == "hole"}
    pos, quat = task.hole_pose(session.layout)
    axis = quat_to_mat(quat)[:, 2]
    ctx = ExpertContext(session, session.rng)
    original, step_time = mujoco.mj_step, [0.0, 0]

    def timed_step(m: Any, d: Any) -> None:
        t0 = time.perf_counter()
        original(m, d)
        step_time[0] += time.perf_counter() - t0
        step_time[1] += 1

    penetration, tunnel, finite = 0.0, 0.0, True
    mujoco.mj_step = timed_step
    try:
        script = list(move_to(ctx, ctx.target[:3] - axis * 0.039, speed_m_s=0.02, primitive="insert"))
        script += list(wait(ctx, 0.2))
        for step in script:
            state = session.step(step.action, step.primitive)
            if not sim.finite():
                finite = False
                break
            for c in data.contact[:data.ncon]:
                if (c.geom1 == tube_geom and c.geom2 in wall_geoms) or (c.geom2 == tube_geom and c.geom1 in wall_geoms):
                    penetration = max(penetration, -float(c.dist) * 1000.0)
            tunnel = max(tunnel, tube_in_solid_mm(state.objects["tube"], TUBE_RADIUS_M, TUBE_HALF_M, pos, quat, BORE))
        # MuJoCo's own timers over the trial: where a step's time goes
        steps = max(1, data.timer[mujoco.mjtTimer.mjTIMER_STEP].number)
        anatomy = {part: 1e6 * data.timer[timer].duration / steps for part, timer in (
            ("collision", mujoco.mjtTimer.mjTIMER_POS_COLLISION), ("constraint", mujoco.mjtTimer.mjTIMER_CONSTRAINT))}
    finally:
        mujoco.mj_step = original
        session.close()
    inserted = finite and task.success(state)
    jammed = finite and not inserted and session.max_in_hand_slip_mm > 3.0
    return {"inserted": bool(inserted), "peak_penetration_mm": penetration, "tunnelled": bool(tunnel > 1.0),
            "jammed": bool(jammed), "finite": finite, "us_per_step": 1e6 * step_time[0] / max(1, step_time[1]),
            "us_per_step_collision": anatomy["collision"], "us_per_step_constraint": anatomy["constraint"]}


def run_expert_seed(row: dict[str, Any], seed: int) -> dict[str, Any]:
    """The task's expert under ``row``'s settings from ``seed`` (the task's own layouts), not recorded; the
    controller ticks every 2 ms whatever the timestep, as in the task."""
    run = whole_expert(SweptTube(swept_config(row["timestep_s"]), row), seed)
    # a run stopped before the expert's first move has no attempts in its memory
    return {"seed": seed, "success": run.success, "safe": run.safe, "attempts": int(run.memory.get("attempts", 0)),
            "found_the_hole": bool(run.memory.get("inside", False)),
            "max_in_hand_slip_mm": round(run.max_in_hand_slip_mm, 2), "first_violation": run.first_violation}


def label(row: dict[str, Any]) -> str:
    c: HoleContact = row["contact"]
    if row["group"] == "task":
        return "task (1 ms, boxes, solref 0.002 s, Newton)"
    if row["group"] == "timestep":
        return f"timestep {row['timestep_s'] * 1000:g} ms"
    if row["group"] == "margin":
        return f"margin {c.margin_m * 1000:g} mm"
    if row["group"] == "stiffness":
        return f"solref {c.timeconst_s:g} s" + (" (MuJoCo default)" if c == MUJOCO_DEFAULT_CONTACT else "")
    if row["group"] == "solver":
        if row["option"] != TASK_OPTION:
            cone = re.search(r'cone="(\w+)"', row["option"]).group(1)  # type: ignore[union-attr]
            noslip = re.search(r'noslip_iterations="(\d+)"', row["option"]).group(1)  # type: ignore[union-attr]
            return f"{cone} cone, noslip {noslip}"
        return f"solver {row['solver']}"
    return f"collider {row['collider']} ({'48 convex mesh pieces' if row['collider'] == 'convex' else '24 boxes'})"


def sdf_cost(steps: int = 1000) -> dict[str, Any]:
    """What an SDF collider costs: MuJoCo's wheel ships analytic SDF plugins only (bolt, nut, gear, torus,
    bowl; no mesh SDF), and the only round bore among them is the threaded nut, at its own scale (bore
    radius between 0.25 and 0.30 m). A cylinder resting in it gives the per-step cost of SDF contact."""
    xml = """<mujoco><extension><plugin plugin="mujoco.sdf.nut"><instance name="nut">
      <config key="radius" value="0.26"/></instance></plugin></extension>
      <asset><mesh name="nut"><plugin instance="nut"/></mesh></asset>
      <option sdf_iterations="10" sdf_initpoints="40"/>
      <worldbody><geom type="sdf" name="nut" mesh="nut"><plugin instance="nut"/></geom>
      <body pos="0 0 0.5"><freejoint/><geom type="cylinder" size="0.3 0.3" mass="0.06"/></body></worldbody></mujoco>"""
    box_xml = """<mujoco><worldbody><geom type="box" size="0.5 0.5 0.05"/>
      <body pos="0 0 0.5"><freejoint/><geom type="cylinder" size="0.3 0.3" mass="0.06"/></body></worldbody></mujoco>"""
    out = {}
    for name, text in (("sdf_nut", xml), ("box", box_xml)):
        model = mujoco.MjModel.from_xml_string(text)
        data = mujoco.MjData(model)
        for _ in range(300):  # settle into contact
            mujoco.mj_step(model, data)
        t0 = time.perf_counter()
        contacts = 0
        for _ in range(steps):
            mujoco.mj_step(model, data)
            contacts = max(contacts, data.ncon)
        out[name] = {"us_per_step": 1e6 * (time.perf_counter() - t0) / steps, "contacts": contacts}
    return out


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--trials", type=int, default=8)
    parser.add_argument("--expert-seeds", type=int, default=20,
                        help="seeds of the task's whole expert per setting (its success rate, with a 95 %% interval)")
    parser.add_argument("--plot-only", action="store_true", help="redraw the chart from the stored JSON")
    parser.add_argument("--experts-only", action="store_true",
                        help="rerun the stored JSON's expert column (its seeds per setting), keep the push trials")
    args = parser.parse_args()
    if args.plot_only:
        stored = json.loads((RESULTS / "insertion_stability.json").read_text())
        plot(stored["rows"], stored["sdf"])
        return
    if args.experts_only:
        rerun_experts(RESULTS / "insertion_stability.json")
        return
    info = machine(threads_used=1)
    rows = []
    for row in settings():
        trials = [run_trial(row, seed) for seed in range(args.trials)]
        experts = [run_expert_seed(row, seed) for seed in range(args.expert_seeds)]
        summary = {
            "label": label(row), "group": row["group"], "timestep_s": row["timestep_s"], "collider": row["collider"],
            "solver": row["solver"], "option": row["option"], "contact": {"timeconst_s": row["contact"].timeconst_s,
                                                 "solimp": list(row["contact"].solimp),
                                                 "margin_m": row["contact"].margin_m},
            "trials": len(trials), "inserted": sum(t["inserted"] for t in trials) / len(trials),
            "jammed": sum(t["jammed"] for t in trials) / len(trials),
            "tunnelled": sum(t["tunnelled"] for t in trials) / len(trials),
            "non_finite": sum(not t["finite"] for t in trials) / len(trials),
            "peak_penetration_mm": max(t["peak_penetration_mm"] for t in trials),
            "us_per_step": float(np.median([t["us_per_step"] for t in trials])),
            # of which MuJoCo's collision detection and its constraint solve (noslip included), medians
            "us_per_step_collision": float(np.median([t["us_per_step_collision"] for t in trials])),
            "us_per_step_constraint": float(np.median([t["us_per_step_constraint"] for t in trials])),
            **expert_column(experts),
        }
        summary["breaks"] = bool(summary["inserted"] < 0.9 or summary["tunnelled"] > 0 or summary["non_finite"] > 0
                                 or summary["peak_penetration_mm"] > 0.25)
        rows.append(summary)
        print(f"{summary['label']:40s} inserted {summary['inserted']:.0%} jammed {summary['jammed']:.0%} "
              f"tunnelled {summary['tunnelled']:.0%} non-finite {summary['non_finite']:.0%} peak penetration "
              f"{summary['peak_penetration_mm']:.3f} mm, {summary['us_per_step']:.0f} us/step (collision "
              f"{summary['us_per_step_collision']:.0f}, constraints {summary['us_per_step_constraint']:.0f}), expert "
              f"{summary['expert_success']:.0%} ({summary['expert_safe']:.0%} safe)"
              f"{'  <- breaks' if summary['breaks'] else ''}", flush=True)
    sdf = sdf_cost()
    print(f"SDF nut vs box, one cylinder in contact: {sdf['sdf_nut']['us_per_step']:.0f} vs "
          f"{sdf['box']['us_per_step']:.0f} us/step")
    result = {"machine": info, "trials_per_setting": args.trials, "expert_seeds_per_setting": args.expert_seeds,
              "clearance_radial_mm": 0.25,
              "breaks_when": "insertion < 90 %, any tunnelling or non-finite state, or peak penetration > 0.25 mm "
                             "(the radial clearance)", "rows": rows, "sdf": sdf}
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "insertion_stability.json").write_text(json.dumps(result, indent=1))
    plot(rows, sdf)


def expert_column(experts: list[dict[str, Any]]) -> dict[str, Any]:
    """A row's expert fields from its per-seed runs (``run_expert_seed``)."""
    wins = sum(e["success"] for e in experts)
    return {"expert_seeds": len(experts), "expert_success": wins / len(experts),
            "expert_success_95": [round(v, 3) for v in wilson_interval(wins, len(experts))],
            "expert_safe": sum(e["safe"] for e in experts) / len(experts),
            "expert_runs": experts}  # per seed: attempts, whether a probe went in, the tube's largest slip in the hand


def rerun_experts(path: Path) -> None:
    """Rerun the expert column of the JSON at ``path`` on each stored setting's seeds; the rest is kept."""
    stored = json.loads(path.read_text())
    by_label = {label(row): row for row in settings()}
    missing = [r["label"] for r in stored["rows"] if r["label"] not in by_label]
    if missing:
        raise SystemExit(f"{path}: settings no longer in settings(): {', '.join(missing)}; rerun the whole sweep")
    for summary in stored["rows"]:
        row = by_label[summary["label"]]
        before = summary["expert_success"]
        summary.update(expert_column([run_expert_seed(row, seed) for seed in range(summary["expert_seeds"])]))
        print(f"{summary['label']:40s} expert {before:.0%} -> {summary['expert_success']:.0%} "
              f"({summary['expert_safe']:.0%} safe)", flush=True)
    stored["experts_rerun"] = {"date": time.strftime("%Y-%m-%d"), "machine": machine(threads_used=1),
                               "note": "the expert column rerun alone after an expert change; the push trials "
                                       "and timings are the first run's (machine above them)"}
    path.write_text(json.dumps(stored, indent=1))
    plot(stored["rows"], stored["sdf"])


def plot(rows: list[dict[str, Any]], sdf: dict[str, Any]) -> None:
    fig, grid = plt.subplots(2, 3, figsize=(19, 10))
    axes = grid.ravel()
    colours = {"task": "black", "timestep": "tab:blue", "margin": "tab:orange", "stiffness": "tab:green",
               "solver": "tab:purple", "collider": "tab:brown"}
    panels = (("inserted", "straight push: insertion success"), ("peak_penetration_mm", "peak penetration, mm"),
              ("jammed", "jammed"), ("tunnelled", "tunnelled (tube surface > 1 mm in a wall)"),
              ("expert_success", "the task's expert (retries by touch): success, 95 % interval"))
    for ax, (key, title) in zip(axes, panels):
        named: list[tuple[float, float]] = []  # (us per step, value) of the labels placed on this panel
        for group, colour in colours.items():
            mine = [r for r in rows if r["group"] == group]
            if key not in (mine[0] if mine else {}):
                continue  # a JSON from before the column existed (--plot-only)
            ax.scatter([r["us_per_step"] for r in mine], [r[key] for r in mine], color=colour, s=55, label=group,
                       marker="o")
            if key == "expert_success":
                low, high = np.array([r["expert_success_95"] for r in mine]).T
                values = np.array([r[key] for r in mine])
                ax.errorbar([r["us_per_step"] for r in mine], values, yerr=[values - low, high - values], fmt="none",
                            ecolor=colour, elinewidth=1, capsize=2)
            for r in mine:
                # the solver's cone and noslip rows only matter to the expert: named there, not on every panel
                named_here = key == "expert_success" and r.get("option", TASK_OPTION) != TASK_OPTION
                if r["breaks"] or group == "task" or named_here:
                    ax.scatter(r["us_per_step"], r[key], facecolors="none", edgecolors="red" if r["breaks"] else
                               "black", s=160, linewidths=1.2)
                    # labels of points that nearly coincide are stacked downwards instead of printed over
                    # one another
                    near = sum(abs(math.log(u / r["us_per_step"])) < 0.4 and abs(v - r[key]) < 0.03
                               for u, v in named)
                    named.append((r["us_per_step"], r[key]))
                    ax.annotate(r["label"], (r["us_per_step"], r[key]), fontsize=7,
                                xytext=(4, 6) if group == "task" else (4, -10 - 9 * near), textcoords="offset points")
        ax.axvline(sdf["sdf_nut"]["us_per_step"], color="grey", ls=":", lw=1)
        ax.text(sdf["sdf_nut"]["us_per_step"], ax.get_ylim()[1] * 0.5, " SDF contact alone\n (threaded nut)",
                fontsize=7, color="grey", rotation=90, va="center")
        ax.set_xscale("log")
        ax.set_xticks([10, 20, 50, 100, 200, 500, 1000])
        ax.xaxis.set_major_formatter(ticker.ScalarFormatter())
        ax.xaxis.set_minor_formatter(ticker.NullFormatter())
        ax.set_xlabel("mj_step wall time, us per physics step (log)")
        ax.set_title(title, fontsize=10)
        ax.grid(alpha=0.3)
    axes[1].axhline(0.25, color="red", lw=0.8, ls="--", label="radial clearance")
    axes[1].legend(fontsize=7, loc="upper left")
    anatomy(axes[5], rows)
    fig.suptitle("Insert Tube, 2.0 cm tube into a 2.05 cm bore: one setting changed at a time from the task's "
                 "(red ring = breaks: < 90 % inserted, tunnelling, or penetration over the clearance)", fontsize=10)
    fig.tight_layout()
    FIGURES.mkdir(parents=True, exist_ok=True)
    fig.savefig(FIGURES / "insertion_stability.png", dpi=110)


def anatomy(ax: Any, rows: list[dict[str, Any]]) -> None:
    """Where a step's time goes per setting: MuJoCo's collision detection, its constraint solve (noslip
    included) and the rest of the step."""
    if "us_per_step_collision" not in rows[0]:
        ax.set_axis_off()  # a JSON from before the column existed (--plot-only)
        return
    labels = [r["label"] for r in rows]
    collision = np.array([r["us_per_step_collision"] for r in rows])
    constraint = np.array([r["us_per_step_constraint"] for r in rows])
    rest = np.maximum(np.array([r["us_per_step"] for r in rows]) - collision - constraint, 0.0)
    ax.barh(labels, collision, color="tab:blue", label="collision")
    ax.barh(labels, constraint, left=collision, color="tab:orange", label="constraint solve (noslip included)")
    ax.barh(labels, rest, left=collision + constraint, color="#bbbbbb", label="the rest of mj_step")
    ax.invert_yaxis()
    ax.tick_params(axis="y", labelsize=7)
    ax.set_xlabel("us per physics step")
    ax.set_title("where a step goes (MuJoCo's timers)", fontsize=10)
    ax.legend(fontsize=7, loc="lower right")
    ax.grid(alpha=0.3, axis="x")


if __name__ == "__main__":
    main()
