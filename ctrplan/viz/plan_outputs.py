"""What ``ctrplan plan --out`` writes for a plan (docs/design.md §3): ``path.json``, ``obstacles.ply``,
``plan.png``, ``plan.html`` and, for a solved plan, ``trajectory.csv`` -- for the command and for
the design study's best paths (`ctrplan.design.outputs`).

The writers render a `ctrplan.planning.PlanResult` whose clearances were measured by its exact
validation (``plan(..., clearances=True)``, `ctrplan.planning.validate.measure_clearance`): they
compute nothing of their own -- no collision checks, no kinematics.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ctrplan.base.dataio import atomic_write, format_csv, output_dir
from ctrplan.viz.plan_plot import plot_plan
from ctrplan.viz.style import CLEARANCE_CAP_MM
from ctrplan.viz.viewer import viewer_data, write_viewer

if TYPE_CHECKING:
    from ctrplan.planning.execution import TrajectoryTable
    from ctrplan.planning.result import PlanResult


def plan_document(result: PlanResult, sc, scene_file: Path, model: str | None) -> dict:
    """The JSON document of a plan (docs/design.md §3): the result, its scene file and PINN weights file
    (or None), the target region and, for a path the exact model checked and measured,
    ``validated.structures``: the exact model's clearance to every named structure along it."""
    doc = result.to_json()
    doc["scene"] = str(scene_file)
    doc["model"] = model
    doc["target"] = sc.target.to_dict()
    if np.ptp(sc.target.semi_axes) > 0:  # one tolerance describes only a sphere; see doc["target"]
        doc["goal_tolerance_mm"] = None
    return doc


def listed_structures(doc: dict) -> list[dict]:
    """The per-structure clearances `plan_document` listed (none without a checked path), nearest
    first."""
    listed = (doc.get("validated") or {}).get("structures", [])
    return sorted(listed, key=lambda c: np.inf if c["clearance_mm"] is None else c["clearance_mm"])


def structure_line(c: dict, rich: bool = False) -> str:
    """One structure's clearance as a line: distance, margin, where, and a flag when below it."""
    where = f"state {c['state']}, {c['arc_length_mm']:.1f} mm along the robot" \
        if c["arc_length_mm"] is not None else "no state"
    flag = "BELOW its margin" if c["below_margin"] else ""
    if flag and rich:
        flag = f"[bold red]{flag}[/]"
    clear = "no finite state:" if c["clearance_mm"] is None else f"{c['clearance_mm']:.2f} mm"
    return (f"{clear} (required {c['required_mm']:g} mm; {where})"
            + (f" {flag}" if flag else ""))


def write_plan_outputs(out: Path, sc, result: PlanResult, doc: dict,
                       trajectory: TrajectoryTable | None = None) -> None:
    """path.json, obstacles.ply, plan.png, plan.html and, for a solved plan, trajectory.csv (its
    ``trajectory``, `ctrplan.planning.execution.trajectory_table`); each file is written completely
    or not at all. A validated path must carry its measured clearances."""
    output_dir(out)
    full = dict(doc)
    clearance = None
    if result.dense is not None:
        exact, clearance = result.dense.exact, result.dense.clearance_mm
        if clearance is None:
            raise ValueError("write_plan_outputs: the path's clearances were not measured "
                             "(plan(..., clearances=True) or measure_clearance)")
        bbs, radii = sc.to_scene(exact.positions_mm), exact.radius_mm
        full["dense_path"] = result.dense.dense_q.tolist()
        full["backbones_mm"] = np.round(np.where(np.isfinite(bbs), bbs, np.nan), 4).tolist()
        full["backbone_radius_mm"] = np.round(radii, 4).tolist()
        full["backbones_backend"] = result.dense.report.backend
        full["frame"] = "scene (mm)"
        if result.solved:
            if trajectory is None:
                raise ValueError("write_plan_outputs: a solved plan needs its trajectory (trajectory_table)")
            write_trajectory(out / "trajectory.csv", trajectory)
    else:  # nothing planned: show the start
        bbs, radii = sc.to_scene(result.start.positions_mm), result.start.radius_mm
    with atomic_write(out / "path.json") as fh:
        fh.write(json.dumps(_nan_to_none(full)))
    mesh = sc.merged_obstacles()
    with atomic_write(out / "obstacles.ply", "wb") as fh:
        fh.write(mesh.export(file_type="ply"))
    tmp_png = out / ".plan.png.tmp.png"
    plot_plan(sc, bbs, tmp_png, tip_path=bbs[:, -1, :],
              title=f"{sc.name}: {result.planner}/{result.backend}, "
                    f"{'solved' if result.solved else 'not solved'}", notes=_figure_notes(result, doc))
    tmp_png.replace(out / "plan.png")
    tmp_html = out / ".plan.html.tmp.html"
    shown = None if clearance is None else np.minimum(clearance, CLEARANCE_CAP_MM)
    listed = {c["name"]: (structure_line(c), c["below_margin"]) for c in listed_structures(doc)}
    data = viewer_data(sc, bbs, radii, _viewer_info(sc, result, doc), shown, structures=listed)
    write_viewer(tmp_html, data, title=f"ctrplan: {sc.name}")
    tmp_html.replace(out / "plan.html")


def write_trajectory(path: Path, table: TrajectoryTable) -> None:
    """trajectory.csv: the rows of ``table`` (`ctrplan.planning.execution`: time, joints, their
    velocities, actuator units, the exact tip and clearance at a fixed rate)."""
    header, rows = table.header, table.rows
    with atomic_write(path) as fh:
        fh.write(format_csv(header, rows, ["%.6f"] * rows.shape[1]))


def _figure_notes(result: PlanResult, doc: dict) -> list[tuple[str, bool]]:
    """plan.png's notes (text, warn): the result or why it failed, the exact model's clearance and
    the clearance to each structure, nearest first, those below their margin as warnings."""
    why = result.message if result.message.startswith("not solved") else f"not solved: {result.message}"
    notes = [("solved" if result.solved else why, not result.solved)]
    v = result.validated
    if v is None:
        return notes + [("no path: no clearance to show (the start is drawn)", False)]
    notes.append((f"min clearance {v.min_clearance_mm:.2f} mm to {v.nearest_obstacle or 'nothing'} "
                  f"(exact model, {v.states} states)", not v.collision_free))
    listed = listed_structures(doc)
    width = max([len(c["name"]) for c in listed] + [9])
    key = ("clearance to each structure along the path (exact model, mm; need: the scene's margin plus "
           "the structure's own; s: arc length from the front plate; !: below it)")
    header = f"  {'structure':<{width}} clear.   need state  s"
    notes += [("", False), (key, False), ("", False), (header, False)]
    for c in listed:
        clear = "-" if c["clearance_mm"] is None else f"{c['clearance_mm']:.2f}"
        arc = "-" if c["arc_length_mm"] is None else f"{c['arc_length_mm']:.0f}"
        row = f"{c['name']:<{width}} {clear:>6} {c['required_mm']:>6.2f} {c['state']:>5} {arc:>4}"
        notes.append((("! " if c["below_margin"] else "  ") + row, c["below_margin"]))
    return notes


def _viewer_info(sc, result: PlanResult, doc: dict) -> dict[str, str]:
    """The result as labelled lines for plan.html."""
    info = {"result": "solved" if result.solved else result.message,
            "planner / backend": f"{result.planner} / {result.backend}",
            "planning time": f"{result.planning_time_s:.2f} s (time budget {result.time_limit_s:g} s)",
            "work": f"{result.states:,} of {result.max_states:,} states"
                    + (" (cut short by the wall-clock guard)" if result.cut_short else "")}
    v = result.validated
    if v is not None:
        miss = float(sc.target.distance(np.asarray(v.tip_mm))) if len(v.tip_mm) == 3 else float("nan")
        info["final tip"] = "in the target" if v.tip_in_target else f"{miss:.2f} mm outside the target"
        info["min clearance"] = f"{v.min_clearance_mm:.2f} mm to {v.nearest_obstacle or 'nothing'} " \
                                f"(exact model, {v.states} states)"
        if v.max_position_error_mm > 0:
            error = v.max_position_error_mm
            info[f"{result.backend} vs exact"] = f"backbones differ by {error:.2f} mm at most"
        if v.repaired:
            info["repair"] = "stretches re-planned with the exact model"
    below = [c["name"] for c in listed_structures(doc) if c["below_margin"]]
    if listed_structures(doc):
        info["structures"] = (f"below their margin: {', '.join(below)}" if below else
                              "every one keeps its margin") + " (hover one for its clearance)"
    return info


def _nan_to_none(x):
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {k: _nan_to_none(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_nan_to_none(v) for v in x]
    return x
