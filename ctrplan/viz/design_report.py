"""The figures and the page of a design study (`ctrplan.design.outputs.StudyOutcome`).

`pareto_figure` draws targets reached over the trials and against every other objective (Pareto front,
best and base design marked); `overview_figure` the anatomy around the targets with the best design's
backbone at the end of each path; `write_report` one self-contained ``report.html`` (images embedded,
no external resource): the reach table (targets x base design, best design), the best design's
parameters, the overview, each target's path, the Pareto plot and every trial. `write_study_figures`
writes them all, and each reached target's plan outputs, as ``ctrplan design`` leaves them.
"""

from __future__ import annotations

import base64
import html
import io
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from ctrplan.design.outputs import StudyOutcome
from ctrplan.design.ranking import Design, ranked
from ctrplan.design.record import DesignRecord
from ctrplan.design.task import DesignTask
from ctrplan.viz.plan_outputs import plan_document, write_plan_outputs
from ctrplan.viz.plan_plot import triangles_in
from ctrplan.viz.style import pyplot, write_png


def write_study_figures(outcome: StudyOutcome, out: Path) -> None:
    """Every reached target's plan outputs (``paths/<target>/``: path.json, plan.png, plan.html,
    obstacles.ply), ``pareto.png`` and then ``report.html``, which embeds them."""
    for best in outcome.paths.values():
        doc = plan_document(best.result, best.scene, best.scene_file, None)
        write_plan_outputs(best.folder, best.scene, best.result, doc, best.trajectory)
    pareto_figure(outcome.task, outcome.designs, outcome.front, outcome.best, outcome.nominal,
                  out / "pareto.png")
    write_report(outcome, out)


def pareto_figure(task: DesignTask, designs: list[Design], front: list[Design], best: Design | None,
                  nominal: Design | None, path: Path) -> Path:
    """``pareto.png``: targets reached per trial, then against each other objective."""
    plt = pyplot()
    others = task.objectives[1:]
    fig, axes = plt.subplots(1, 1 + len(others), figsize=(5.2 * (1 + len(others)), 4.4), squeeze=False)
    axes = axes[0]
    n_targets = len(task.targets)
    feasible = [d for d in designs if d.record.feasible]
    infeasible = [d for d in designs if not d.record.feasible]

    def reached(ds: list[Design]) -> np.ndarray:
        return np.array([len(d.record.reached) for d in ds], dtype=float)

    ax = axes[0]
    ax.plot([d.trial for d in infeasible], reached(infeasible), "x", color="0.6", label="infeasible")
    ax.plot([d.trial for d in feasible], reached(feasible), "o", color="tab:blue", ms=4, label="feasible")
    if feasible:
        trials = np.array([d.trial for d in feasible])
        ax.step(trials, np.maximum.accumulate(reached(feasible)), where="post", color="tab:red",
                label="best trial so far")
    if nominal is not None:
        ax.axhline(len(nominal.record.reached), color="k", ls="--", lw=1, label="base design")
    ax.set_xlabel("trial")
    ax.set_ylabel(f"targets reached (of {n_targets})")
    ax.set_title("search progress", fontsize=10)
    rng = np.random.default_rng(0)  # a little vertical spread: many designs share a count
    for ax, objective in zip(axes[1:], others, strict=True):
        def x(ds: list[Design], value: Callable[[DesignRecord], float] = objective.value) -> list[float]:
            return [value(d.record) for d in ds]

        jitter = rng.uniform(-0.12, 0.12, len(feasible))
        ax.plot(x(feasible), reached(feasible) + jitter, "o", color="0.55", ms=4, label="feasible design")
        ax.plot(x(front), reached(front), "o", mfc="none", mec="tab:red", ms=9, mew=1.5, label="Pareto front")
        if nominal is not None and nominal.record.feasible:
            ax.plot(x([nominal]), reached([nominal]), "D", color="k", ms=7, label="base design")
        if best is not None:
            ax.plot(x([best]), reached([best]), "*", color="gold", mec="k", ms=16,
                    label="best: the base design" if best.trial is None else "best")
        ax.set_xlabel(objective.axis_label)
        ax.set_ylabel(f"targets reached (of {n_targets})")
        ax.set_title(objective.criterion.description, fontsize=9)
    for ax in axes:
        ax.set_ylim(-0.5, n_targets + 0.5)
        ax.set_yticks(range(n_targets + 1))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="best")
    fig.suptitle(f"{task.name}: {len(designs)} trials, {len(feasible)} feasible", fontsize=11)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_png(fig, path, dpi=100)


def _region_outline(region, a: int, b: int) -> np.ndarray:
    """Outline (M, 2) of a target region projected on axes a, b (convex hull of its surface)."""
    from scipy.spatial import ConvexHull

    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 32), np.linspace(0, np.pi, 16))
    p = np.stack([np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v)], -1).reshape(-1, 3)
    pts = (p * region.semi_axes @ region.rotation.T + region.center)[:, [a, b]]
    return pts[ConvexHull(pts).vertices]


def overview_figure(task: DesignTask, backbones: list[tuple[str, np.ndarray]]) -> bytes:
    """PNG: side (z-y) and top (z-x) views of the anatomy around the targets, every target in its
    colour, and the best design's ``backbones`` (target name, (P, 3) scene frame, mm) at the end of
    its path to each reached target (same colour)."""
    from matplotlib.collections import PolyCollection

    plt = pyplot()
    scene = task.scene
    centres = np.array([t.region.center for t in task.targets])
    lo, hi = centres.min(axis=0) - 25.0, centres.max(axis=0) + 12.0
    bounds = np.stack([lo, hi])
    tris = triangles_in(scene, bounds, max_triangles=15000)
    colours = plt.get_cmap("tab10")
    names = [t.name for t in task.targets]
    fig, axes = plt.subplots(1, 2, figsize=(14, 5.6))
    for ax, (a, b, title) in zip(axes, ((2, 1, "side view (z-y)"), (2, 0, "top view (z-x)")), strict=True):
        for _, t in tris:
            ax.add_collection(PolyCollection(t[:, :, [a, b]], facecolor="0.5", edgecolor="none", alpha=0.07))
        for i, target in enumerate(task.targets):
            outline = _region_outline(target.region, a, b)
            ax.fill(outline[:, 0], outline[:, 1], color=colours(i % 10), alpha=0.45, lw=0,
                    label=f"target {target.name}")
        for name, p in backbones:
            ax.plot(p[:, a], p[:, b], color=colours(names.index(name) % 10), lw=2.0,
                    label=f"best design at {name}")
        ax.set_xlim(lo[a], hi[a])
        ax.set_ylim(lo[b], hi[b])
        ax.set_aspect("equal")
        ax.set_xlabel("xyz"[a] + " (mm)")
        ax.set_ylabel("xyz"[b] + " (mm)")
        ax.set_title(title, fontsize=10)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="center right", fontsize=8, frameon=False)
    fig.suptitle(f"{scene.name}: the targets of {task.name} and the best design at each reached one",
                 fontsize=11)
    fig.tight_layout(rect=(0, 0, 0.8, 1))
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    return buf.getvalue()


def _img(png: bytes, alt: str) -> str:
    return f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{base64.b64encode(png).decode()}">'


def _table(header: list[str], rows: list[list[Any]]) -> str:
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _fmt(value: Any) -> str:
    if value is None:
        return "–"
    if isinstance(value, float):
        return f"{value:.4g}"
    return html.escape(str(value))


def _reach_cell(record: DesignRecord | None, name: str) -> str:
    if record is None:
        return "–"
    if not record.feasible:
        return "infeasible"
    t = record.target(name)
    if t.reached:
        return (f'<span class="yes">reached</span><br><small>clearance {t.min_clearance_mm:.2f} mm, '
                f'{t.planning_time_s:.1f} s</small>')
    return f'<span class="no">no</span><br><small>{html.escape(t.message)}</small>'


def write_report(outcome: StudyOutcome, out: Path) -> Path:
    """``report.html`` in ``out`` (after the other outputs: it embeds ``pareto.png`` and each
    reached target's ``plan.png``)."""
    from ctrplan.base.dataio import atomic_write

    task, doc, designs = outcome.task, outcome.doc, outcome.designs
    best, nominal = outcome.best, outcome.nominal

    parts = [f"<h1>ctrplan design: {html.escape(task.name)}</h1>",
             f"<p>Study <b>{html.escape(doc['study'])}</b> in <code>{html.escape(doc['storage'])}</code>: "
             f"{doc['trials']} finished trials, {doc['feasible']} feasible; this run took "
             f"{doc['time_s']:.0f} s on {html.escape(doc['executor'])}; seed {doc['seed']}. Objectives: "
             f"{html.escape(', '.join(doc['objectives']))}. A target counts as reached only when the exact "
             f"Cosserat model confirms a collision-free, stable path from the start into it.</p>"]
    if doc["trial_time_s"]:
        tt = doc["trial_time_s"]
        parts.append(f"<p>Wall time per trial: median {tt['median']:.1f} s, mean {tt['mean']:.1f} s, max "
                     f"{tt['max']:.1f} s (sum {tt['total']:.0f} s over all workers); from the first trial's "
                     f"start to the last one's end {doc['study_wall_s']:.0f} s.</p>")
    rows = [[f"<b>{html.escape(t.name)}</b>", html.escape(t.reason),
             _reach_cell(None if nominal is None else nominal.record, t.name),
             _reach_cell(None if best is None else best.record, t.name)] for t in task.targets]
    n_nom = "–" if nominal is None else len(nominal.record.reached)
    n_best = "–" if best is None else len(best.record.reached)
    rows.append(["<b>total</b>", "", f"<b>{n_nom} of {len(task.targets)}</b>", f"<b>{n_best} of "
                 f"{len(task.targets)}</b>"])
    is_base = best is not None and best.trial is None
    best_name = ("best design" if best is None else "best design = the base design" if is_base
                 else f"best design (trial {best.trial})")
    parts += ["<h2>Reach</h2>", _table(["target", "why it matters", "base design", best_name], rows)]
    parts += _warnings(doc, is_base)
    if best is not None:
        parts += ["<h2>Best design" + (": the base design" if is_base else "") + "</h2>",
                  _parameter_table(task, best, nominal),
                  "<p>Robot file: <code>best_robot.yaml</code>; each target's scene: "
                  "<code>paths/&lt;target&gt;/scene.yaml</code>.</p>"]
    parts += ["<h2>Anatomy and paths</h2>", _img(overview_figure(task, outcome.backbones), "overview")]
    for t in task.targets:
        png = out / "paths" / t.name / "plan.png"
        if png.is_file():
            parts += [f"<h3>{html.escape(t.name)}</h3>", _img(png.read_bytes(), f"path to {t.name}"),
                      f'<p><a href="paths/{html.escape(t.name)}/plan.html">interactive 3-D view</a></p>']
    infeasible = [d for d in designs if not d.record.feasible]
    parts += ["<h2>Pareto front</h2>", _img((out / "pareto.png").read_bytes(), "Pareto plot"),
              "<h2>Every trial</h2><p>Feasible designs best first, then the infeasible ones.</p>",
              f'<div class="wide">{_designs_table(task, ranked(designs, task) + infeasible)}</div>']
    page = (f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>ctrplan design "
            f"{html.escape(task.name)}</title><style>{_CSS}</style></head><body>{''.join(parts)}</body></html>")
    with atomic_write(out / "report.html") as fh:
        fh.write(page)
    return out / "report.html"


def _warnings(doc: dict, is_base: bool) -> list[str]:
    """Paragraphs for what limits the result: no trial beat the base design, the time limit stopped
    the study, a wall-clock guard decided some verdicts."""
    out = []
    if is_base:
        out.append(f'<p class="warn"><b>No trial beats the base design</b> in the task\'s objectives '
                   f'({html.escape(", ".join(doc["objectives"]))}): the best design, and '
                   f'<code>best_robot.yaml</code>, is the base design.</p>')
    if doc["cut_short"]:
        out.append(f'<p class="warn">{html.escape(doc["cut_short"])}.</p>')
    if doc["guarded_trials"]:
        out.append(f'<p class="warn">A wall-clock guard cut a search short in {doc["guarded_trials"]} '
                   f'design(s) (<code>cut_short</code> of the base design\'s targets and in '
                   f'<code>designs.csv</code>): those verdicts depend on the load of the machine that ran '
                   f'them.</p>')
    return out


def _parameter_table(task: DesignTask, best: Design, nominal: Design | None) -> str:
    base = task.robot.to_dict()["tubes"]
    mine = best.record.robot["tubes"]
    rows = []
    for i, (b, m) in enumerate(zip(base, mine, strict=True)):
        for key in ("inner_diameter_mm", "outer_diameter_mm", "straight_length_mm", "curved_length_mm",
                    "curvature_1_per_m"):
            changed = abs(b[key] - m[key]) > 1e-9
            value = f"<b>{m[key]:.4g}</b>" if changed else f"{m[key]:.4g}"
            rows.append([f"tube {i + 1}", key, f"{b[key]:.4g}", value])
    objectives = [[o.axis_label, _fmt(None if nominal is None else o.value(nominal.record)),
                   _fmt(o.value(best.record))] for o in task.objectives]
    return (_table(["tube", "field", "base design", "best design"], rows)
            + "<p>Objectives:</p>" + _table(["objective", "base design", "best design"], objectives))


def _designs_table(task: DesignTask, designs: list[Design]) -> str:
    params = sorted({k for d in designs for k in d.record.parameters})
    header = ["trial", "feasible", "reached", *[o.name for o in task.objectives[1:]], *params, "time s"]
    rows = []
    for d in designs:
        r = d.record
        status = "yes" if r.feasible else f"no: {html.escape(r.infeasible.constraint)}"
        rows.append([d.trial, status, html.escape(", ".join(r.reached) or "–"),
                     *[_fmt(o.value(r)) for o in task.objectives[1:]],
                     *[_fmt(r.parameters.get(p)) for p in params], f"{r.time_s:.1f}"])
    return _table(header, rows)


_CSS = """
body{font:14px/1.45 system-ui,sans-serif;max-width:1300px;margin:24px auto;padding:0 16px;color:#222}
h1{font-size:22px}h2{font-size:18px;margin-top:28px;border-bottom:1px solid #ddd}h3{font-size:15px}
table{border-collapse:collapse;margin:8px 0;font-size:12px}
th,td{border:1px solid #ddd;padding:3px 7px;vertical-align:top;text-align:left}
th{background:#f3f3f3}img{max-width:100%;border:1px solid #eee}
.yes{color:#1a7f37;font-weight:600}.no{color:#b42318;font-weight:600}small{color:#555}
.warn{background:#fff4e5;border-left:4px solid #f79009;padding:6px 10px}
code{background:#f5f5f5;padding:0 3px}.wide{overflow-x:auto}
"""
