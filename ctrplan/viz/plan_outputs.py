"""What ``ctrplan plan --out`` writes for a plan (docs/design.md §3): ``path.json``, ``obstacles.ply``,
``plan.png``, ``plan.html`` and, for a solved plan, ``trajectory.csv`` -- for the command and for
the design study's best paths (`ctrplan.design.outputs`)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ctrplan.dataio import atomic_write, format_csv, output_dir
from ctrplan.kinematics import CosseratBackend
from ctrplan.planning.trajectory import segment_positions, time_parametrise
from ctrplan.planning.validate import clearance_along
from ctrplan.viz.plan_plot import plot_plan
from ctrplan.viz.style import CLEARANCE_CAP_MM
from ctrplan.viz.viewer import viewer_data, write_viewer

#: trajectory.csv reports clearances up to this (mm); larger ones as this.
TRAJECTORY_CLEARANCE_CAP_MM = 50.0


def plan_document(result, sc, scene_file: Path, model: str | None) -> dict:
    """The JSON document of a plan (docs/design.md §3): the result, its scene file and PINN weights file
    (or None), and the target region."""
    doc = result.to_json()
    doc["scene"] = str(scene_file)
    doc["model"] = model
    doc["target"] = sc.target.to_dict()
    if np.ptp(sc.target.semi_axes) > 0:  # one tolerance describes only a sphere; see doc["target"]
        doc["goal_tolerance_mm"] = None
    return doc


def write_plan_outputs(out: Path, sc, result, doc: dict) -> None:
    """path.json, obstacles.ply, plan.png, plan.html and, for a solved plan, trajectory.csv; each file
    is written completely or not at all."""
    output_dir(out)
    full = dict(doc)
    clearance = None
    if result.dense is not None:
        exact = result.dense.exact
        bbs, radii = sc.to_scene(exact.positions_mm), exact.radius_mm
        clearance = clearance_along(sc, exact, TRAJECTORY_CLEARANCE_CAP_MM)
        full["dense_path"] = result.dense.dense_q.tolist()
        full["backbones_mm"] = np.round(np.where(np.isfinite(bbs), bbs, np.nan), 4).tolist()
        full["backbone_radius_mm"] = np.round(radii, 4).tolist()
        full["backbones_backend"] = "cosserat"
        full["frame"] = "scene (mm)"
        if result.solved:
            write_trajectory(out / "trajectory.csv", sc, result, bbs[:, -1, :], np.nanmin(clearance, axis=1))
    else:  # nothing planned: show the start
        b = CosseratBackend(sc.robot).forward(sc.start, points=sc.settings.points, check=False)
        bbs, radii = sc.to_scene(b.positions_mm), b.radius_mm
    with atomic_write(out / "path.json") as fh:
        fh.write(json.dumps(_nan_to_none(full)))
    mesh = sc.merged_obstacles()
    with atomic_write(out / "obstacles.ply", "wb") as fh:
        fh.write(mesh.export(file_type="ply"))
    tmp_png = out / ".plan.png.tmp.png"
    plot_plan(sc, bbs, tmp_png, tip_path=bbs[:, -1, :],
              title=f"{sc.name}: {result.planner}/{result.backend}, "
                    f"{'solved' if result.solved else 'not solved'}")
    tmp_png.replace(out / "plan.png")
    tmp_html = out / ".plan.html.tmp.html"
    shown = None if clearance is None else np.minimum(clearance, CLEARANCE_CAP_MM)
    write_viewer(tmp_html, viewer_data(sc, bbs, radii, _viewer_info(sc, result), shown),
                 title=f"ctrplan: {sc.name}")
    tmp_html.replace(out / "plan.html")


def write_trajectory(path: Path, sc, result, tips_mm: np.ndarray, clearance_mm: np.ndarray) -> None:
    """trajectory.csv: the validated path timed within the robot's joint limits (`ctrplan.planning.
    trajectory`), one row per exactly validated state: time_s, joints (mm, rad), the tip (scene frame,
    mm) and the exact model's clearance (mm; `TRAJECTORY_CLEARANCE_CAP_MM` where it is larger)."""
    dense = result.dense.dense_q
    trajectory = time_parametrise(result.path, sc.robot.limits)
    times = trajectory.time_of(*segment_positions(np.asarray(result.path), dense))
    header = ["time_s", *sc.robot.joint_names, "tip_x", "tip_y", "tip_z", "clearance_mm"]
    rows = np.column_stack([times, dense, tips_mm, clearance_mm])
    with atomic_write(path) as fh:
        fh.write(format_csv(header, rows, ["%.6f"] * rows.shape[1]))


def _viewer_info(sc, result) -> dict[str, str]:
    """The result as labelled lines for plan.html."""
    info = {"result": "solved" if result.solved else result.message,
            "planner / backend": f"{result.planner} / {result.backend}",
            "planning time": f"{result.planning_time_s:.2f} s (time budget {result.time_limit_s:g} s)",
            "work": f"{result.details.get('budget', {}).get('states', 0):,} of {result.max_states:,} states"
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
    return info


def _nan_to_none(x):
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {k: _nan_to_none(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_nan_to_none(v) for v in x]
    return x
