#!/usr/bin/env python3
"""Refresh a generated block of the documentation from the command that produces its numbers.

A block sits between ``<!-- MARKER:start -->`` and ``<!-- MARKER:end -->`` (e.g. MARKER =
``bench:kinematics``) in the markdown file `DOC_OF` names (docs/benchmarks.md, docs/cli.md). This
script runs the block's ``ctrplan ... --json`` command (extra arguments are passed on), renders the
JSON as markdown (a table, the machine, the exact command) and rewrites only that block, so the
documented numbers always come from the command. Add a block to `BLOCKS` and `DOC_OF`.

    python scripts/update_readme.py kinematics --n 300
    python scripts/update_readme.py --check      # every block's markers sit once in its file
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ctrplan.planning.planners import OPTIMIZING
from ctrplan.training.target import ACCURACY_TARGET, meets

ROOT = Path(__file__).resolve().parents[1]  #: the repository; renderers write links relative to it
BENCHMARKS = ROOT / "docs" / "benchmarks.md"
CLI_DOC = ROOT / "docs" / "cli.md"


@dataclass(frozen=True)
class Block:
    """A generated documentation block: its marker, the ctrplan arguments that produce its JSON, and its
    renderer."""

    marker: str
    args: tuple[str, ...]
    render: Callable[[dict[str, Any]], str]


def machine_line(machine: dict[str, Any]) -> str:
    versions = ", ".join(f"{k} {machine[k]}" for k in ("python", "numpy", "numba", "torch")
                         if machine.get(k))
    return (f"Machine: {machine['cpu']}, {machine['cores']} cores (pinned to one), "
            f"{machine['platform']}; {versions}.")


def markdown_table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def render_kinematics(doc: dict[str, Any]) -> str:
    """Table of `ctrplan bench kinematics --json` (times in ms per single-query call)."""
    header = ["backend", "mode", "points", "n", "min ms", "median ms", "p90 ms", "p99 ms", "max ms",
              "p99/median", "failures", "median iterations"]
    rows = [[r["backend"], r["mode"], str(r["points"]), str(r["n"]), f"{r['min_ms']:.3f}",
             f"{r['median_ms']:.3f}", f"{r['p90_ms']:.3f}", f"{r['p99_ms']:.3f}", f"{r['max_ms']:.3f}",
             f"{r['p99_over_median']:.1f}", str(r["failures"]), f"{r['median_iterations']:g}"]
            for r in doc["results"]]
    text = markdown_table(header, rows)
    batched = doc.get("batched")
    if batched:
        rates = "; ".join(f"{r['backend']} {r['backbones_per_s']:,.0f} backbones/s" for r in batched)
        text += (f"\n\nBatched calls (all cores): {rates} ({batched[0]['batch']} configurations x "
                 f"{batched[0]['points']} points per call).")
    return text + "\n\n" + machine_line(doc["machine"])


def render_pinn(doc: dict[str, Any]) -> str:
    """Accuracy of a PINN vs the exact solver, from `ctrplan eval-model --json`."""
    e, t, o = doc["backbone_error_pct"], doc["tip_error_mm"], doc["orientation_error_deg"]
    rows = [["backbone error / arc length", f"{e['mean']:.3f} %", "", "", f"{e['max']:.3f} %"]]
    rows += [[f"{tube} tip error", *(f"{v[k]:.3f} mm" for k in ("mean", "p99", "p99_9", "max"))]
             for tube, v in t.items()]
    tip = doc.get("tip_error_pct_length")
    if tip:
        rows += [["tube1 tip error / arc length",
                  *(f"{tip[k]:.3f} %" for k in ("mean", "p99", "p99_9", "max"))]]
    to = doc.get("tip_orientation_error_deg")
    if to:
        rows += [["tube1 tip orientation error",
                  *(f"{to[k]:.2f} deg" for k in ("mean", "p99", "p99_9", "max"))]]
    rows += [["orientation error along the backbone",
              *(f"{o[k]:.2f} deg" for k in ("mean", "p99", "p99_9", "max"))],
             ["u_z RMSE", f"{doc['u_z_rmse_1_per_m']:.3f} 1/m", "", "", ""],
             ["theta RMSE", f"{doc['theta_rmse_rad']:.4f} rad", "", "", ""]]
    tr = doc.get("training", {})
    stages = "; ".join(
        f"{s['recipe']} {s['steps']} steps, {s['wall_time_s'] / 60:.1f} min on {s['hardware']}"
        for s in tr.get("stages", [])) or f"{tr.get('recipe')}, {tr.get('wall_time_s')} s"
    nodes = doc.get("inference", {}).get("nodes")
    how = (f"; inference: network at {nodes} nodes per backbone, physics-interpolated" if nodes
           else "; inference: network at every point")
    return (markdown_table([f"metric ({doc['configurations']:,} unseen configurations)", "mean", "p99",
                            "p99.9", "max"], rows) + f"\n\nModel `{doc['model']}`; training: {stages}{how}.")


def render_training(cards: list[dict[str, Any]]) -> str:
    """Accuracy vs training time of each recipe run, from the model cards `ctrplan train` wrote."""
    rows = []
    for c in cards:
        m = c["metrics"]["backbone_error_pct"]
        continued = c["recipe"]["name"] == "polish" or len(c.get("stages", [])) > 1
        start = " (from the previous row)" if continued else ""
        rows.append([c["recipe"]["name"] + start, c["hardware"], str(c["steps"]),
                     f"{c['wall_time_s'] / 60:.1f}", f"{c['metrics']['configurations']:,}",
                     f"{m['mean']:.3f}", f"{m['max']:.3f}"])
    return markdown_table(["recipe", "hardware", "steps", "minutes", "unseen configurations",
                           "backbone error mean %", "max %"], rows)


ROBOTS_JSON = ROOT / "docs" / "training" / "robots.json"


def _cores(row: dict[str, Any]) -> str:
    """The cores a robots-table run used: its threads, and the mining worker's CPU minutes."""
    worker = row.get("mining_worker") or {}
    if worker.get("solved_in") == "a worker process":
        waited = worker.get("waited_s")
        waited = f", optimiser waited {waited / 60:.1f} min" if waited is not None else ""
        return f"{row['threads']} (worker {worker['solve_cpu_s'] / 60:.1f} CPU-min{waited})"
    return str(row.get("threads", "–"))


def _machine(row: dict[str, Any]) -> str:
    """The CPU (or GPU) a robots-table run trained on, from its card's hardware: "AMD EPYC"."""
    return row["hardware"].split(",")[0].replace("(R)", "").replace(" Processor", "")


def render_robots(doc: dict[str, Any]) -> str:
    """Time to the accuracy target per robot, from `scripts/pinn_robots.py`'s JSON (issue 40)."""
    rows = []
    for r in doc["robots"]:
        mm = r["tip_error_mm"]["tube1"]
        start = r.get("transferred_from")
        start = f"`{start['model']}` (d = {start['distance']:.2f})" if start else "scratch"
        start = start if "transferred_from" in r else "– (before transfer)"
        load = r.get("load_average")
        cpu = r.get("train_cpu_s")
        rows.append([f"`{r['robot']}`" if "/" in r["robot"] else r["robot"], start, _machine(r),
                     r.get("clock", "wall"),
                     f"{r.get('command_s', r['wall_time_s']) / 60:.1f}", _fmt(cpu and cpu / 60, ".1f"),
                     _cores(r),
                     f"{r['dense_batch']:,}", _fmt(r.get("mining_share"), ".2f"), str(r["steps"]),
                     " / ".join(f"{mm[k]:.3f}" for k in ("mean", "p99", "p99_9", "max")),
                     "yes" if meets(mm) else "no", _reached(r), _card_says(r, mm),
                     f"{load['before'][0]:.1f} / {load['after'][0]:.1f}" if load else "–"])
    hw = "; ".join(sorted({r["hardware"] for r in doc["robots"]}))
    n = doc["robots"][0]["configurations"] if doc["robots"] else 0
    header = ["robot", "started from", "machine", "clock", "wall minutes", "CPU min", "cores", "batch",
              "mining share", "steps",
              f"tube-1 tip mean / p99 / p99.9 / max mm ({n:,} unseen)", "meets the target",
              "monitor met the target at", "the card says", "load before / after"]
    return (markdown_table(header, rows)
            + f"\n\nErrors against the exact model on {n:,} unseen configurations per robot (`ctrplan "
              f"eval-model --n {n}`); trained with `ctrplan train --robot ROBOT --time-limit 20m "
              f"--threads 1|2 [--clock cpu]` (default recipe; \"clock\": what the 20 minutes were read "
              f"on; \"cores\": `--threads`: with 1, two or three runs at once, one thread each; with 2, "
              f"one run alone on the machine, one core training and one a mining worker whose CPU "
              f"minutes follow; \"batch\": its supervised rows per step, `dense_batch`; \"mining "
              f"share\": the part of each batch from the mined hard examples, `Mining.share`, – where "
              f"the card is gone) on {hw}. \"CPU min\" is the CPU time the training command got (its "
              f"mining worker's included), the load average (1 min) before and after each run is in the "
              f"last column. Target: tube-1 tip p99.9 <= 0.5 mm and max <= 1 mm. \"monitor met the target "
              f"at\": minutes into the run when the network first met it on the 5,000 monitor "
              f"configurations (their own seed; – where it did not, or where the run predates the "
              f"monitor); the verdict is on the {n:,} evaluation configurations, so a run can meet the "
              f"target on the monitor's and narrowly miss it on these. Generated by `python "
              f"scripts/pinn_robots.py --out docs/training/robots.json ...` (via `scripts/update_readme.py "
              f"robots`).")


def _reached(r: dict) -> str:
    t = r.get("time_to_target")
    if t is None:
        return "– (no monitor)"
    return "–" if t.get("reached_at_s") is None else f"{t['reached_at_s'] / 60:.1f} min"


def _card_says(r: dict, mm: dict) -> str:
    """The card's verdict: meets, or misses by how much with the extrapolation (labelled) or why
    there is none."""
    if r.get("meets_target") or (r.get("meets_target") is None and meets(mm)):
        return "meets the target"
    far = ", ".join(f"{stat} {mm[key] / limit:.1f}x" for stat, key, limit in
                    (("p99.9", "p99_9", ACCURACY_TARGET["tube1_tip_p99_9_mm"]),
                     ("max", "max", ACCURACY_TARGET["tube1_tip_max_mm"])) if mm[key] > limit)
    ex = (r.get("time_to_target") or {}).get("extrapolation") or {}
    jumps = (r.get("card_worst") or {}).get("next_to_jump", 0)
    why = f"; {jumps} of its 10 worst next to a jump of the exact model" if jumps else ""
    if ex.get("extrapolated_s") is None:
        reason = ex.get("reason", "the tail did not fall")
        return f"misses ({far} the target); no extrapolation ({reason}){why}"
    return f"misses ({far} the target); EXTRAPOLATED at its rate: {_duration(ex['extrapolated_s'])}{why}"


def _duration(seconds: float) -> str:
    """Minutes, hours, or 'over 100 h' for an extrapolated training time."""
    if seconds < 600 * 60:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.0f} h" if seconds < 100 * 3600 else "over 100 h (the tail hardly falls)"


def _fmt(x: float | None, spec: str = ".2f") -> str:
    return "–" if x is None else format(x, spec)


def plan_table(rows: list[dict[str, Any]]) -> str:
    """One scene's rows of `ctrplan bench plan --json` as a markdown table."""
    header = ["planner", "backend", "solved", "median s", "p90 s", "max s", "time in kin / coll / planner",
              "checks/s", "path mm", "max error vs exact mm", "repaired", "unsafe"]
    body = []
    for r in rows:
        t, share = r["planning_time_s"], r["time_share"]
        body.append([r["planner"], r["backend"], f"{r['solved']}/{r['runs']}", _fmt(t["median"]),
                     _fmt(t["p90"]), _fmt(t["max"]),
                     " / ".join(f"{100 * share[k]:.0f} %" for k in ("kinematics", "collision", "planner")),
                     _fmt(r["checks_per_s"]["median"], ",.0f"), _fmt(r["path_length_mm"]["median"], ".0f"),
                     _fmt(r["max_position_error_mm"]["max"]), str(r["repaired"]), str(r["unsafe"])])
    return markdown_table(header, body)


def plan_conclusion(summary: list[dict[str, Any]]) -> str:
    """Plain-language comparison of the PINN with the exact backends, computed from the summary.

    Median planning times are compared where both backends solved at least half of the runs (else the
    medians are just the time budget); elsewhere the success rates are compared."""
    by = {(r["scene"], r["planner"], r["backend"]): r for r in summary}
    ratios, checks, lines = [], [], []
    for (scene, planner, backend), r in by.items():
        p = by.get((scene, planner, "pinn"))
        if backend == "pinn" or p is None:
            continue
        checks.append((backend, r["checks_per_s"]["median"] / p["checks_per_s"]["median"]))
        both = min(r["success_rate"], p["success_rate"]) >= 0.5
        line = (f"{scene} / {planner}: {backend} {r['solved']}/{r['runs']} solved, median "
                f"{r['planning_time_s']['median']:.2f} s; PINN {p['solved']}/{p['runs']}, "
                f"{p['planning_time_s']['median']:.2f} s")
        if planner in OPTIMIZING:  # runs until the budget is spent: compare what it bought
            line += (f"; path after the budget {_fmt(r['path_length_mm']['median'], '.0f')} mm vs "
                     f"{_fmt(p['path_length_mm']['median'], '.0f')} mm (PINN)")
        elif both:
            ratio = r["planning_time_s"]["median"] / p["planning_time_s"]["median"]
            ratios.append((backend, ratio))
            line += f" ({ratio:.2f}x)"
        else:
            line += " (mostly out of time: medians not compared)"
        lines.append(line)
    text = []
    for backend in dict.fromkeys(b for b, _ in checks):
        rs = np.array([x for b, x in ratios if b == backend])
        cs = np.array([x for b, x in checks if b == backend])
        rate = f"it checks {float(np.exp(np.log(cs).mean())):.2f}x as many configurations per second"
        if rs.size:
            g = float(np.exp(np.log(rs).mean()))
            verdict = ("slower than" if g > 1.1 else "faster than" if g < 0.9 else "about as fast as")
            text.append(f"- **{backend}** is {verdict} the PINN: median planning time {g:.2f}x the PINN's "
                        f"(geometric mean over {len(rs)} scene/planner pair(s) where both mostly succeed; "
                        f"range {rs.min():.2f}–{rs.max():.2f}x; RRT* and BIT* use their whole budget and "
                        f"are compared by path length below); {rate}.")
        else:
            text.append(f"- **{backend}**: no feasible planner solved at least half of the runs with both "
                        f"backends; {rate}.")
    pinn = [r for r in summary if r["backend"] == "pinn"]
    exact = [r for r in summary if r["backend"] != "pinn"]

    def spread(rows: list[dict[str, Any]]) -> float:
        vals = [r["planning_time_s"]["p90"] / r["planning_time_s"]["median"] for r in rows
                if r["success_rate"] >= 0.5 and r["planner"] not in OPTIMIZING]
        return float(np.median(vals)) if vals else float("nan")

    text.append(f"- **Predictability**: the run-to-run spread is the sampling planner's: p90/median "
                f"planning time is {spread(pinn):.2f} with the PINN and {spread(exact):.2f} with the exact "
                f"backends (median over the groups that mostly succeed).")
    solved, repaired = sum(r["solved"] for r in pinn), sum(r["repaired"] for r in pinn)
    text.append(f"- **Safety**: every PINN path was re-checked with the exact model: of {solved} solved "
                f"runs, {repaired} were repaired first (stretches re-planned with the exact model); "
                f"{sum(r['unsafe'] for r in pinn)} found paths stayed unsafe and count as not solved.")
    return "\n".join(text) + "\n\n<details><summary>Per scene and planner</summary>\n\n" + \
        "\n".join(f"- {line}" for line in lines) + "\n\n</details>"


def render_plan(doc: dict[str, Any]) -> str:
    """Tables, plots and conclusion of `ctrplan bench plan --json`."""
    summary, st = doc["summary"], doc["settings"]
    out = Path(st["out"]) if "out" in st else None
    parts = [plan_conclusion(summary)]
    for scene in dict.fromkeys(r["scene"] for r in summary):
        rows = [r for r in summary if r["scene"] == scene]
        parts.append(f"**{scene}** ({rows[0]['runs']} seeded runs per row, {rows[0]['time_limit_s']:g} s "
                     f"budget)\n\n{plan_table(rows)}")
    if out is not None:
        rel = (ROOT / out).resolve().relative_to(ROOT)
        parts.append(f"![planning times]({rel}/planning_times.png)\n\n![time split]({rel}/time_split.png)")
    m = doc["machine"]
    parts.append(f"Machine: {m['cpu']}, {m['cores']} cores, {st['executor']}; {m['platform']}. "
                 f"Times include goal sampling (IK) and any repair, not the exact re-validation. "
                 f"\"unsafe\": a path the planner found that failed the exact check even after repair. "
                 f"Wall time {st['wall_time_s'] / 60:.0f} min.")
    return "\n\n".join(parts)


def render_design(doc: dict[str, Any]) -> str:
    """Reach table, best design, timings and Pareto plot of `ctrplan design --json`."""
    nominal, best = doc["nominal"], doc["best"]

    def cell(design: dict[str, Any] | None, name: str) -> str:
        if design is None:
            return "–"
        t = design["targets"][name]
        if t["reached"]:
            return f"yes ({t['min_clearance_mm']:.2f} mm clearance, {t['planning_time_s']:.1f} s)"
        return "no: " + ("no collision-free goal configuration" if t["stage"] == "screen"
                         else "no path within the budget")

    best_head = "best design" if best is None else f"best design (trial {best['trial']})"
    rows = [[name, cell(nominal, name), cell(best, name)] for name in doc["targets"]]
    rows.append(["**total**", f"**{len(nominal['reached'])} of {len(doc['targets'])}**",
                 "–" if best is None else f"**{len(best['reached'])} of {len(doc['targets'])}**"])
    parts = [markdown_table(["target", "base design (nominal robot)", best_head], rows)]
    if best is not None:
        base = nominal["robot"]["tubes"]
        tube_rows = []
        for i, (b, t) in enumerate(zip(base, best["robot"]["tubes"], strict=True), 1):
            tube_rows.append([str(i), f"{t['inner_diameter_mm']:g} / {t['outer_diameter_mm']:g}",
                              f"{t['straight_length_mm']:.1f}", f"{t['curved_length_mm']:.1f} "
                              f"({b['curved_length_mm']:g})", f"{t['curvature_1_per_m']:.2f} "
                              f"({b['curvature_1_per_m']:g})"])
        parts.append("Best design (nominal in brackets; diameters from the catalogue):\n\n" + markdown_table(
            ["tube", "ID / OD mm", "straight mm", "curved mm", "curvature 1/m"], tube_rows))
        objectives = ", ".join(f"{k} {v:.4g}" for k, v in best["objectives"].items())
        parts.append(f"Objectives of the best design: {objectives}.")
    tt, m = doc["trial_time_s"], doc["machine"]
    parts.append(f"{doc['trials']} trials ({doc['feasible']} feasible) in {doc['study_wall_s'] / 60:.1f} min "
                 f"(first start to last end) on {doc['executor']}; wall time per trial median "
                 f"{tt['median']:.1f} s, mean {tt['mean']:.1f} s, max {tt['max']:.1f} s. Machine: "
                 f"{m['cpu']}, {m['cores']} cores; {m['platform']}.")
    out = Path(doc["outputs"]["pareto.png"]).parent
    rel = (ROOT / out).resolve().relative_to(ROOT)
    parts.append(f"![Pareto plot]({rel}/pareto.png)\n\nEvery trial, the paths and the anatomy: "
                 f"[{rel}/report.html]({rel}/report.html).")
    return "\n\n".join(parts)


DESIGN_OUT = Path("docs/bench/design_skullbase")  # the design block's --out (relative to ROOT)

BLOCKS = {
    "kinematics": Block(marker="bench:kinematics", args=("bench", "kinematics"), render=render_kinematics),
    "pinn": Block(marker="pinn:accuracy", args=("eval-model", "--n", "5000"), render=render_pinn),
    "plan": Block(marker="bench:plan", args=("bench", "plan", "scenes/skullbase.yaml", "--out",
                                              "docs/bench/plan_skullbase"), render=render_plan),
    "plan-scenes": Block(marker="bench:plan-scenes",
                         args=("bench", "plan", "scenes/open.yaml", "scenes/pipe.yaml", "--out",
                               "docs/bench/plan_scenes"), render=render_plan),
    "design": Block(marker="design:skullbase", args=("design", "scenes/skullbase_design.yaml", "--out",
                                                     str(DESIGN_OUT)), render=render_design),
}
TRAINING_CARDS = ROOT / "docs" / "training"


FINETUNE_MARKER = "pinn:finetune"
FINETUNE_SHOTS = 500
FINETUNE_EXTRA = ("--threads", "2")


def render_finetune(report: dict[str, Any]) -> str:
    """Held-out tip error of the Cosserat models and the PINN stages of few-shot fine-tuning on the
    real-like lab, the stage written and the written model through `fk` (from `scripts/fewshot_lab.py`)."""
    card = report["card"]
    table, on = card["metrics"]["measured_heldout"], card["finetuned_on"]
    kept = on["kept"]
    rows = [[m["model"] + (" **(written)**" if m["key"] == kept["stage"] else ""), f"{m['mean_mm']:.3f}",
             f"{m['median_mm']:.3f}", f"{m['p95_mm']:.3f}", f"{m['mean_pct_length']:.3f} %"]
            for m in table["models"]]
    ext, lag, fk = on["extended_model"], on["learned_lag"], report["fk_written_model"]
    stages = ", ".join(f"{k} {v:.0f} s" for k, v in on["stage_seconds"].items())
    fitted = ", ".join(f"{k} = {v['value']:.4g}" for k, v in ext["parameters"].items())
    validation = ", ".join(f"{k} {v:.3f}" for k, v in kept["validation_mean_mm"].items())
    causes = ", ".join(f"`{c}`" for c in ext["causes"])
    lag_text = lag.get("reason", "")
    if "validation_mean_mm" in lag:
        val = lag["validation_mean_mm"]
        lag_text = (f"validation mean {val['without']:.3f} -> {val['with']:.3f} mm, "
                    f"{'kept' if lag['kept'] else 'not kept'}")
        if lag.get("unsupported"):
            lag_text += f" (the shots do not support it: {', '.join(lag['unsupported'])})"
    return (markdown_table(["model", "mean mm", "median mm", "p95 mm", "mean % of arc length"], rows)
            + f"\n\nTube-1 tip error on the last {table['rows']:,} of {on['rows']:,} rows (acquisition "
              f"order) of `tests/independent/lab.real_like` (seed 0); {on['fit_shots']} shots fitted, the "
              f"next "
              f"{on['validation_shots']} validate the stages (mean mm: {validation}); written: "
              f"`{kept['stage']}`. The written model through `ctrplan fk --robot ft.robot.yaml --model ft` "
              f"on the same rows: mean {fk['mean_mm']:.3f}, p95 {fk['p95_mm']:.3f} mm. Extended Cosserat: "
              f"`diagnose` on the fitted shots named {causes} ({fitted}). Learned lag: {lag_text}. "
              f"Stages {stages} on {card['hardware']} (a 2-core machine shared with other jobs); all of "
              f"it took {report['train_wall_s'] / 60:.1f} min."
              f"\n\nGenerated by `{shlex.join(report['command'])}` on that data "
              f"(via `scripts/update_readme.py finetune`, which runs `scripts/fewshot_lab.py`).")


def run_finetune(extra: list[str], results: Path | None = None) -> str:
    """Fine-tune the shipped PINN on 500 shots of the real-like lab (`scripts/fewshot_lab.py`) and render
    the held-out table; or render the ``report.json`` an earlier `scripts/fewshot_lab.py OUT` wrote
    (its model card is read from OUT/ft.json where the report lacks it)."""
    import tempfile

    if results is not None:
        report = json.loads(results.read_text())
        report.setdefault("card", json.loads((results.parent / "ft.json").read_text()))
        return render_finetune(report)
    sys.path.insert(0, str(ROOT / "scripts"))
    from fewshot_lab import run_lab

    with tempfile.TemporaryDirectory() as tmp:
        report = run_lab(Path(tmp), 0, FINETUNE_SHOTS, [*FINETUNE_EXTRA, *extra])
    return render_finetune(report)


LOOP_MARKER = "design:loop"
LOOP_MODEL = "skullbase_design"
LOOP_TRAIN_ARGS = ("--time-limit", "25", "--threads", "2")


def render_design_loop(design: dict[str, Any], stability: dict[str, Any], card: dict[str, Any],
                       plans: dict[str, dict[str, Any]], walls: dict[str, float]) -> str:
    """Certify -> train -> plan for the design block's best design: the stability verdict, the
    PINN's card and, per target, planning with that PINN next to the design run's exact planning."""
    best, m = design["best"], card["metrics"]
    tip, ori = m["tip_error_pct_length"], m["tip_orientation_error_deg"]
    rows = []
    for name, doc in plans.items():
        v, exact = doc["validated"], best["targets"][name]
        check = "–" if v is None else (
            f"{'in' if v['tip_in_target'] else 'outside'} the target, "
            f"{'collision-free' if v['collision_free'] else 'COLLIDES'}, {_fmt(v['min_clearance_mm'])} mm"
            + (" (repaired)" if v["repaired"] else ""))
        rows.append([name, "solved" if doc["solved"] else f"not solved ({doc['message']})",
                     f"{doc['planning_time_s']:.2f}", check,
                     "–" if v is None else _fmt(v["max_position_error_mm"]),
                     f"{exact['planning_time_s']:.2f}" if exact["reached"] else "not reached"])
    solved = sum(doc["solved"] for doc in plans.values())
    verdict = "snap-free" if stability["snap_free"] else "NOT snap-free"
    bound = card.get("backbone_error_bound")
    return "\n\n".join([
        f"1. **certify** (`ctrplan stability --robot {DESIGN_OUT}/best_robot.yaml`): {verdict} over "
        f"{stability['checked']:,} configurations ({100 * stability['unstable_fraction']:.2f} % flagged), "
        f"{walls['stability'] / 60:.1f} min.\n"
        f"2. **train** (`ctrplan train --robot ... --name {LOOP_MODEL} {' '.join(LOOP_TRAIN_ARGS)}`): "
        f"{card['steps']:,} steps in {card['wall_time_s'] / 60:.1f} min on {card['hardware']}; on "
        f"{m['configurations']:,} unseen configurations tube-1 tip error mean {tip['mean']:.3f} %, max "
        f"{tip['max']:.3f} % of arc length, tip orientation max {ori['max']:.2f} deg"
        + ("" if bound is None else "; error bound calibrated into the card") + ".\n"
        f"3. **plan** every target with that PINN (`ctrplan plan {DESIGN_OUT}/paths/TARGET/scene.yaml "
        f"--model {DESIGN_OUT}/pinn/{LOOP_MODEL}.safetensors --seed 0`): {solved} of {len(plans)} "
        f"solved and confirmed by the exact model.",
        markdown_table(["target", "PINN plan", "planning s", "exact check: tip, collisions, clearance",
                        "PINN vs exact max mm", "exact planning s (design run)"], rows)])


def run_design_loop(extra: list[str]) -> str:
    """The whole loop on the design block's best design (run the design block first): certify it
    with `ctrplan stability`, train a PINN for it with `ctrplan train` (``extra`` goes to train) and
    plan every target with that PINN; outputs under `DESIGN_OUT`."""
    import time

    design_json = ROOT / DESIGN_OUT / "design.json"
    if not design_json.exists():
        raise SystemExit(f"{design_json}: not found; run `scripts/update_readme.py design` first")
    design = json.loads(design_json.read_text())
    if design["best"] is None:
        raise SystemExit(f"{design_json}: the study has no feasible design")
    robot, walls = str(DESIGN_OUT / "best_robot.yaml"), {}

    def timed(stage: str, args: list[str], ok: tuple[int, ...] = (0,)) -> dict[str, Any]:
        t0 = time.perf_counter()
        doc = ctrplan_json(args, ok)
        walls[stage] = walls.get(stage, 0.0) + time.perf_counter() - t0
        return doc

    stability = timed("stability", ["stability", "--robot", robot, "--out", str(DESIGN_OUT / "stability"),
                                    "--json"])
    card = timed("train", ["train", "--robot", robot, "--name", LOOP_MODEL, *LOOP_TRAIN_ARGS, *extra,
                           "--out-dir", str(DESIGN_OUT / "pinn"), "--json"])
    model = str(DESIGN_OUT / "pinn" / f"{LOOP_MODEL}.safetensors")
    plans = {name: timed("plan", ["plan", str(DESIGN_OUT / "paths" / name / "scene.yaml"), "--model", model,
                                  "--seed", "0", "--out", str(DESIGN_OUT / "paths" / name / "pinn"),
                                  "--json"], ok=(0, 1))  # 1: not solved, reported in the table
             for name in design["targets"]}
    return (render_design_loop(design, stability, card, plans, walls)
            + f"\n\nGenerated by `python scripts/update_readme.py design-loop` "
              f"({sum(walls.values()) / 60:.0f} min).")


def replace_block(text: str, marker: str, content: str, where: str = "the document") -> str:
    """``text`` with the body of block ``marker`` replaced by ``content``; the markers must exist once."""
    start, end = f"<!-- {marker}:start -->", f"<!-- {marker}:end -->"
    pattern = re.compile(re.escape(start) + r".*?" + re.escape(end), re.DOTALL)
    if len(pattern.findall(text)) != 1 or text.count(start) != 1 or text.count(end) != 1:
        raise SystemExit(f"{where}: need exactly one {start} ... {end} block")
    return pattern.sub(lambda _: f"{start}\n{content}\n{end}", text)


#: Where each block lives (the markdown file its markers are in).
DOC_OF = {"kinematics": BENCHMARKS, "plan": BENCHMARKS, "plan-scenes": BENCHMARKS, "design": BENCHMARKS,
          "design-loop": BENCHMARKS, "pinn": BENCHMARKS, "robots": BENCHMARKS, "training": BENCHMARKS,
          "finetune": CLI_DOC}
MARKER_OF = {**{name: block.marker for name, block in BLOCKS.items()}, "design-loop": LOOP_MARKER,
             "robots": "pinn:robots", "training": "pinn:training", "finetune": FINETUNE_MARKER}
#: A relative markdown link target (no scheme, anchor or absolute path).
LINK = re.compile(r"\]\((?![a-z][a-z0-9+.-]*:|#|/)([^)\s]+)\)")


def relink(markdown: str, folder: Path) -> str:
    """``markdown`` whose relative links, written relative to `ROOT`, are made relative to ``folder``
    (the folder of the file the markdown goes into)."""
    def moved(match: re.Match[str]) -> str:
        target = match.group(1)
        rel = Path(os.path.relpath(ROOT / target, folder.resolve())).as_posix()
        return f"]({rel}{'/' if target.endswith('/') else ''})"
    return LINK.sub(moved, markdown)


def check() -> int:
    """Exit status of ``--check``: 0 when every block's markers sit exactly once in its file."""
    failures = 0
    for name, doc in DOC_OF.items():
        try:
            replace_block(doc.read_text(), MARKER_OF[name], "", str(doc.relative_to(ROOT)))
            print(f"{name}: <!-- {MARKER_OF[name]} --> in {doc.relative_to(ROOT)}", file=sys.stderr)
        except SystemExit as err:
            print(err, file=sys.stderr)
            failures += 1
    return 1 if failures else 0


def ctrplan_json(args: list[str], ok: tuple[int, ...] = (0,)) -> dict[str, Any]:
    """Run ``ctrplan ARGS`` (ending in --json) with this interpreter; its JSON document. An exit code
    outside ``ok`` stops the script."""
    entry = "from ctrplan.cli.app import main; raise SystemExit(main())"  # `ctrplan` of this interpreter
    result = subprocess.run([sys.executable, "-c", entry, *args], stdout=subprocess.PIPE, check=False,
                            text=True, cwd=ROOT)
    if result.returncode not in ok:
        raise SystemExit(f"ctrplan {shlex.join(args)} failed with exit code {result.returncode}")
    return json.loads(result.stdout)


def run_block(name: str, extra: list[str], results: Path | None = None) -> str:
    """Run block ``name``'s command with ``extra`` arguments; its rendered markdown. With ``results``
    (the JSON that command wrote, e.g. ``--out DIR/results.json``) render that instead of re-running."""
    args = [*BLOCKS[name].args, *extra, "--json"]
    doc = json.loads(results.read_text()) if results else ctrplan_json(args)
    command = shlex.join(["ctrplan", *args])
    how = f"rendered from its `{results}`" if results else "via `scripts/update_readme.py`"
    return f"{BLOCKS[name].render(doc)}\n\nGenerated by `{command}` ({how})."


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     epilog="Other arguments are passed on to the block's command.")
    parser.add_argument("block", nargs="?", choices=sorted(DOC_OF), help="block to regenerate")
    parser.add_argument("--doc", "--readme", dest="doc", type=Path, default=None,
                        help="Markdown file to update (default: the block's own, see DOC_OF)")
    parser.add_argument("--check", action="store_true",
                        help="Only check that every block's markers sit once in its file; run nothing")
    parser.add_argument("--results", type=Path, default=None,
                        help="Render this results.json of an earlier run of the block's command (pass "
                             "the same extra arguments) instead of running it again")
    ns, extra = parser.parse_known_args(argv)  # the rest goes to the ctrplan command
    if ns.check:
        raise SystemExit(check())
    if ns.block is None:
        parser.error("name a block to regenerate (or --check)")
    doc = ns.doc or DOC_OF[ns.block]
    if ns.block == "training":
        cards = [json.loads(p.read_text()) for p in sorted(TRAINING_CARDS.glob("[0-9]*_*.json"))]
        body = render_training(cards) + ("\n\nFrom the model cards in `docs/training/` (written by "
                                         "`ctrplan train`; backbone error / arc length on the "
                                         "card's unseen configurations).")
    elif ns.block == "robots":
        body = render_robots(json.loads(ROBOTS_JSON.read_text()))
    elif ns.block == "finetune":
        body = run_finetune(extra, ns.results)
    elif ns.block == "design-loop":
        body = run_design_loop(extra)
    else:
        body = run_block(ns.block, extra, ns.results)
    marker = MARKER_OF[ns.block]
    # read the file only now: the command may have run for minutes while it was edited
    doc.write_text(replace_block(doc.read_text(), marker, relink(body, doc.parent), str(doc)))
    print(f"updated the {ns.block} block of {doc}", file=sys.stderr)


if __name__ == "__main__":
    main()
