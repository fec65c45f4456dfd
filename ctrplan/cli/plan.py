"""`ctrplan plan`: plan a collision-free motion through a scene, validate it with the exact model.

Exit codes (DESIGN §3): 0 solved, 1 not solved in time (or not safe under the exact model), 2 bad
input. ``--json`` prints one JSON document on stdout; progress and the readable summary then go to
stderr.
"""

from __future__ import annotations

import json
import logging
import math
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from ctrplan import console as console_state
from ctrplan.cli import app
from ctrplan.cli.kinematics import ModelOpt, load_backend
from ctrplan.cli.options import parse_duration
from ctrplan.cli.progress import StatusLine
from ctrplan.dataio import check_output_dir, output_dir
from ctrplan.errors import InputError
from ctrplan.robot import Robot
from ctrplan.scene import PLANNERS

SceneArg = Annotated[Path, typer.Argument(metavar="SCENE.yaml", show_default=False,
                                          help="Scene file (robot, base pose, obstacles, target, start).")]


log = logging.getLogger("ctrplan.ompl")
#: trajectory.csv reports clearances up to this (mm); larger ones as this.
TRAJECTORY_CLEARANCE_CAP_MM = 50.0


@contextmanager
def ompl_messages_to_logging() -> Iterator[None]:
    """Send OMPL's own messages to the ``ctrplan.ompl`` logger (debug level) instead of stderr:
    its raw C++ warnings mislead; the plan result states the cause in our words."""
    from ompl import util as ou

    with tempfile.TemporaryDirectory(prefix="ctrplan-ompl-") as tmp:
        path = Path(tmp) / "ompl.log"
        handler = ou.OutputHandlerFile(str(path))
        ou.useOutputHandler(handler)
        try:
            yield
        finally:
            ou.restorePreviousOutputHandler()
            del handler
            for message in path.read_text(errors="replace").split("\n"):
                if message.strip():
                    log.debug("%s", message.rstrip())


@app.command("plan")
def plan_command(
    scene: SceneArg,
    backend: Annotated[str, typer.Option(
        "--backend", metavar="NAME",
        help="Kinematics backend for planning: pinn | cosserat | hybrid (default: pinn; an error, not a "
             "fallback, if the PINN cannot be used). The path is always re-validated with the exact "
             "Cosserat model.")] = "pinn",
    model: ModelOpt = None,
    robot: Annotated[str | None, typer.Option(
        "--robot", metavar="R.yaml", show_default=False,
        help="Robot file or built-in name that replaces the scene's `robot:` (the scene's start must "
             "fit it: `ctrplan scene check --robot R.yaml --fix OUT.yaml` finds one).")] = None,
    planner: Annotated[str | None, typer.Option(
        "--planner", metavar="NAME", show_default=False,
        help=f"OMPL planner: {' | '.join(PLANNERS)} (default: the scene's, rrtconnect).")] = None,
    time_limit: Annotated[str | None, typer.Option(
        "--time-limit", metavar="DURATION", show_default=False,
        help="Planning time T, e.g. 10s or 2m; a bare number is seconds (default: the scene's, 10): sets "
             "the work budget --max-states takes by default (what T buys on the reference machine) and "
             "the wall-clock guard (30 x T) that stops a search on a slow or overloaded machine and "
             "says so.")] = None,
    max_states: Annotated[int | None, typer.Option(
        "--max-states", metavar="N", show_default=False,
        help="Work budget: configurations the planning backend evaluates for goal sampling and search "
             "(default: the scene's max_states, else from --time-limit). It decides the result: with "
             "--seed the same path on any machine load.")] = None,
    seed: Annotated[int | None, typer.Option(
        "--seed", metavar="N", show_default=False, min=0,
        help="Random seed (OMPL and goal sampling).")] = None,
    out: Annotated[Path | None, typer.Option(
        "--out", metavar="DIR", show_default=False,
        help="Write path.json, trajectory.csv (solved plans), obstacles.ply, plan.png and plan.html "
             "into DIR.")] = None,
    json_out: Annotated[bool, typer.Option(
        "--json", help="Print one JSON summary on stdout (progress and summary go to stderr).")] = False,
    roadmap: Annotated[Path | None, typer.Option(
        "--roadmap", metavar="DIR", show_default=False,
        help="Answer from the roadmap in DIR (`ctrplan roadmap build`) instead of a single-query search; "
             "--out then writes obstacles.ply and path_<row>.json per target.")] = None,
    targets: Annotated[Path | None, typer.Option(
        "--targets", metavar="TARGETS.csv", show_default=False,
        help="With --roadmap: answer every row (header x,y,z,tolerance_mm; scene frame, mm) instead of "
             "the scene's target.")] = None,
) -> None:
    """Plan a motion of the robot's tip into the scene's target region.

    Exit code 0: solved and confirmed collision-free by the exact Cosserat model; 1: not solved in
    time, or the path is not safe under the exact model and could not be repaired; 2: bad input.
    """
    from rich.console import Console

    if targets is not None and roadmap is None:
        raise InputError("--targets: needs --roadmap DIR (the single-query planner answers the scene's "
                         "target)")
    if roadmap is not None:
        from ctrplan.cli.roadmap import plan_from_roadmap

        plan_from_roadmap(scene, roadmap, targets, backend=backend, model=model, out=out, json_out=json_out,
                          robot=None if robot is None else Robot.load(robot))
        return
    time_limit = parse_duration(time_limit, "s")
    if max_states is not None and max_states < 1:
        raise InputError(f"--max-states: must be an integer >= 1 (states), got {max_states}")
    if out is not None:
        check_output_dir(out)  # created when the outputs are written

    from ompl import util as ou

    from ctrplan.planning import plan
    from ctrplan.scene import load_scene

    ou.setLogLevel(ou.LOG_WARN)
    sc = load_scene(scene, robot=None if robot is None else Robot.load(robot))
    console = Console(stderr=json_out, highlight=False)
    err = Console(stderr=True, highlight=False)

    with _Progress(err) as progress, ompl_messages_to_logging():
        progress.update("compile")  # loading a backend compiles (or loads) its kernels
        be = load_backend(backend, sc.robot, model)
        result = plan(sc, be, planner=planner, time_limit_s=time_limit, max_states=max_states, seed=seed,
                      progress=progress.update)
    if console_state.interrupted():  # Ctrl-C inside an OMPL callback ends the search, not the command
        raise KeyboardInterrupt
    pinn = getattr(be, "pinn", be)  # hybrid keeps its PINN in .pinn
    doc = plan_document(result, sc, scene, getattr(pinn, "card", {}).get("weights_file"))
    if out is not None:
        write_plan_outputs(out, sc, result, doc)
    _summary(console, sc, result, out)
    if json_out:
        typer.echo(json.dumps(doc))
    if not result.solved:
        raise typer.Exit(1)  # the summary and the JSON already say why


class _Progress(StatusLine):
    """A transient rich status line on stderr on a terminal; elsewhere a plain line about every
    10 s (`PlainProgress`: kernel compilation and long searches are not silent in a log)."""

    def __init__(self, console):
        super().__init__(console, "plan", "planning ...")

    def update(self, stage: str, **info) -> None:
        text = {"compile": "compiling kernels (first run only)",
                "goal": "sampling goal configurations (IK)", "search": "searching",
                "simplify": "simplifying the path", "validate": "validating with the exact model",
                "repair": "repairing with the exact model"}.get(stage, stage)
        if "elapsed" in info:
            text += f"  {info['elapsed']:.1f} s"
        if "states" in info and "max_states" in info:
            text += f"  {info['states']:,}/{info['max_states']:,} states"
        if "goals" in info:
            text += f"  {info['goals']} goals"
        self(text)


def _summary(console, sc, result, out: Path | None) -> None:
    from rich.table import Table

    v = result.validated
    ok = "[bold green]solved[/]" if result.solved else "[bold red]not solved[/]"
    t = Table(title=f"ctrplan plan {sc.name}: {ok}", show_header=False, title_justify="left")
    t.add_column(style="dim")
    t.add_column()
    t.add_row("planner / backend", f"{result.planner} / {result.backend}")
    budget = result.details.get("budget", {})
    t.add_row("planning time", f"{result.planning_time_s:.2f} s (time budget {result.time_limit_s:g} s, "
                               f"guard {budget.get('guard_s', 0):g} s"
                               + (": [bold yellow]fired[/])" if result.cut_short else ")"))
    t.add_row("work", f"{budget.get('states', 0):,} of {result.max_states:,} states of the search; "
                      f"{result.kinematics_calls:,} kinematics calls in all")
    t.add_row("waypoints", str(len(result.path)))
    if v is not None:
        tip = np.asarray(v.tip_mm)
        dist = float(sc.target.distance(tip)) if tip.size == 3 else float("nan")
        t.add_row("exact model", f"collision-free: {v.collision_free}, clearance "
                                 f"{v.min_clearance_mm:.2f} mm ({v.nearest_obstacle}), "
                                 f"{v.states} states")
        t.add_row("backend vs exact", f"max position error {v.max_position_error_mm:.3f} mm, "
                                      f"tip error {v.max_tip_error_mm:.3f} mm")
        t.add_row("final tip", f"{np.round(tip, 2).tolist()} mm, in target: {v.tip_in_target}"
                               + (f" ({dist:.2f} mm outside)" if dist > 0 else ""))
        if v.repaired:
            t.add_row("repair", "the path was repaired with the exact model")
    t.add_row("message", result.message)
    if out is not None:
        t.add_row("outputs", str(out))
    console.print(t)


def plan_document(result, sc, scene_file: Path, model: str | None) -> dict:
    """The JSON document of a plan (DESIGN §3): the result, its scene file and PINN weights file
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
    from ctrplan.dataio import atomic_write
    from ctrplan.planning.validate import clearance_along
    from ctrplan.viz import plot_plan, viewer_data, write_viewer
    from ctrplan.viz.style import CLEARANCE_CAP_MM

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
        from ctrplan.kinematics import CosseratBackend

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
    from ctrplan.dataio import atomic_write, format_csv
    from ctrplan.planning.trajectory import segment_positions, time_parametrise

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
