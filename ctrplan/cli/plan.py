"""`ctrplan plan`: plan a collision-free motion through a scene, validate it with the exact model.

Exit codes (docs/design.md §3): 0 solved, 1 not solved in time (or not safe under the exact model), 2 bad
input. ``--json`` prints one JSON document on stdout; progress and the readable summary then go to
stderr.
"""

from __future__ import annotations

import json
import logging
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from ctrplan.base.dataio import check_output_dir
from ctrplan.base.errors import InputError
from ctrplan.cli import console as console_state
from ctrplan.cli.app import app
from ctrplan.cli.options import ModelOpt, check_max_states, load_backend, parse_duration
from ctrplan.cli.progress import StatusLine
from ctrplan.kinematics import DEFAULT_PLANNING_BACKEND, PLANNING_ORDER
from ctrplan.model.robot import Robot
from ctrplan.planning.planners import PLANNERS

SceneArg = Annotated[Path, typer.Argument(metavar="SCENE.yaml", show_default=False,
                                          help="Scene file (robot, base pose, obstacles, target, start).")]


log = logging.getLogger("ctrplan.ompl")
#: The summary lists the clearance to this many nearest structures (and every one below its margin).
SUMMARY_STRUCTURES = 4


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


PlanBackendOpt = Annotated[str, typer.Option(
    "--backend", metavar="NAME",
    help=f"Kinematics backend for planning: {' | '.join(PLANNING_ORDER)} (default: "
         f"{DEFAULT_PLANNING_BACKEND}; an error, not a fallback, if the PINN cannot be used). The path "
         "is always re-validated with the exact Cosserat model.")]

PlanRobotOpt = Annotated[str | None, typer.Option(
    "--robot", metavar="R.yaml", show_default=False,
    help="Robot file or built-in name that replaces the scene's `robot:` (the scene's start must "
         "fit it: `ctrplan scene check --robot R.yaml --fix OUT.yaml` finds one).")]

PlannerOpt = Annotated[str | None, typer.Option(
    "--planner", metavar="NAME", show_default=False,
    help=f"Planner: {' | '.join(PLANNERS)} (default: the scene's, corridor).")]

PlanTimeLimitOpt = Annotated[str | None, typer.Option(
    "--time-limit", metavar="DURATION", show_default=False,
    help="Time limit T, e.g. 10s or 2m; a bare number is seconds (default: the scene's, 10): the plan "
         "ends within 1.5 x T of wall time (kernel compilation, first run only, aside), and the work "
         "budget is what T buys on the reference machine; when the clock stops the search first, the "
         "result says so. Given --max-states and no --time-limit, work decides and 30 x T only guards.")]

PlanMaxStatesOpt = Annotated[int | None, typer.Option(
    "--max-states", metavar="N", show_default=False,
    help="Work budget: configurations the planning backend evaluates for goal sampling and search "
         "(default: the scene's max_states, else from --time-limit). Without --time-limit it decides "
         "the result: with --seed the same path on any machine load.")]

PlanSeedOpt = Annotated[int | None, typer.Option(
    "--seed", metavar="N", show_default=False, min=0,
    help="Random seed (OMPL and goal sampling).")]

PlanOutOpt = Annotated[Path | None, typer.Option(
    "--out", metavar="DIR", show_default=False,
    help="Write path.json, trajectory.csv (solved plans), obstacles.ply, plan.png and plan.html "
         "into DIR.")]

RateOpt = Annotated[float, typer.Option(
    "--rate", metavar="HZ", min=0.1, max=10_000.0,
    help="Rows per second of trajectory.csv (--out): joints, their velocities and the robot file's "
         "actuator units at a fixed rate.")]

PlanJsonOpt = Annotated[bool, typer.Option(
    "--json", help="Print one JSON summary on stdout (progress and summary go to stderr).")]

RoadmapOpt = Annotated[Path | None, typer.Option(
    "--roadmap", metavar="DIR", show_default=False,
    help="Answer from the roadmap in DIR (`ctrplan roadmap build`) instead of a single-query search; "
         "--out then writes obstacles.ply and path_<row>.json per target.")]

TargetsOpt = Annotated[Path | None, typer.Option(
    "--targets", metavar="TARGETS.csv", show_default=False,
    help="With --roadmap: answer every row (header x,y,z,tolerance_mm; scene frame, mm) instead of "
         "the scene's target.")]


@app.command("plan")
def plan_command(scene: SceneArg, backend: PlanBackendOpt = DEFAULT_PLANNING_BACKEND, model: ModelOpt = None,
                 robot: PlanRobotOpt = None, planner: PlannerOpt = None,
                 time_limit: PlanTimeLimitOpt = None, max_states: PlanMaxStatesOpt = None,
                 seed: PlanSeedOpt = None, out: PlanOutOpt = None, json_out: PlanJsonOpt = False,
                 roadmap: RoadmapOpt = None, targets: TargetsOpt = None, rate: RateOpt = 50.0) -> None:
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
    check_max_states(max_states)
    if out is not None:
        check_output_dir(out)  # created when the outputs are written

    from ompl import util as ou

    from ctrplan.collision.world import CollisionWorld
    from ctrplan.planning import plan
    from ctrplan.planning.execution import trajectory_table
    from ctrplan.scene.loader import load_scene
    from ctrplan.viz.plan_outputs import plan_document, write_plan_outputs

    ou.setLogLevel(ou.LOG_WARN)
    # the start is checked by plan() with the scene checks (naming the nearest valid start)
    sc = load_scene(scene, check_start=False, robot=None if robot is None else Robot.load(robot))
    console = Console(stderr=json_out, highlight=False)
    err = Console(stderr=True, highlight=False)

    with _Progress(err) as progress, ompl_messages_to_logging():
        progress.update("compile")  # loading a backend compiles (or loads) its kernels
        be = load_backend(backend, sc.robot, model)
        world = CollisionWorld.from_scene(sc)  # the plan's, and the trajectory's clearances
        result = plan(sc, be, planner=planner, time_limit_s=time_limit, max_states=max_states, seed=seed,
                      progress=progress.update, clearances=True, world=world,
                      wall_limit=True if time_limit is not None else None)
        trajectory = None
        if out is not None and result.solved:
            progress.update("trajectory")
            trajectory = trajectory_table(sc, result.path, rate, world)
    if console_state.interrupted():  # Ctrl-C inside an OMPL callback ends the search, not the command
        raise KeyboardInterrupt
    doc = plan_document(result, sc, scene, (be.model_card or {}).get("weights_file"))
    if out is not None:
        write_plan_outputs(out, sc, result, doc, trajectory)
    _summary(console, sc, result, doc, out)
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
                "start": "checking the start (collision world)",
                "goal": "sampling goal configurations (IK)", "search": "searching",
                "simplify": "simplifying the path", "validate": "validating with the exact model",
                "repair": "repairing with the exact model",
                "clearance": "measuring clearances (exact model)",
                "trajectory": "timing the trajectory (exact model)"}.get(stage, stage)
        if stage == "compile" and "total" in info:
            text = f"compiling kernels {info['done']}/{info['total']} (first run only)"
        if "elapsed" in info:
            text += f"  {info['elapsed']:.1f} s"
        if "states" in info and "max_states" in info:
            text += f"  {info['states']:,}/{info['max_states']:,} states"
        if "goals" in info:
            text += f"  {info['goals']} goals"
        self(text)


def _summary(console, sc, result, doc: dict, out: Path | None) -> None:
    from rich.table import Table

    from ctrplan.viz.plan_outputs import listed_structures, structure_line

    v = result.validated
    ok = "[bold green]solved[/]" if result.solved else "[bold red]not solved[/]"
    t = Table(title=f"ctrplan plan {sc.name}: {ok}", show_header=False, title_justify="left")
    t.add_column(style="dim")
    t.add_column()
    t.add_row("planner / backend", f"{result.planner} / {result.backend}")
    search, clock = result.work.search, result.work.clock or {}
    bound = (f"time limit {result.time_limit_s:g} s: all within {clock.get('wall_limit_s') or 0:g} s"
             if clock.get("mode") == "time limit"
             else f"guard {0 if search is None else search.budget.guard_s:g} s")
    t.add_row("planning time", f"{result.planning_time_s:.2f} s ({bound}"
                               + (": [bold yellow]the clock stopped it[/])" if result.cut_short else ")"))
    t.add_row("work", f"{result.states:,} of {result.max_states:,} states of the search "
                      f"({clock.get('reference_states_per_s', 0):,.0f} states/s on the reference machine); "
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
        listed = listed_structures(doc)
        shown = [c for i, c in enumerate(listed) if i < SUMMARY_STRUCTURES or c["below_margin"]]
        for c in shown:
            t.add_row(f"  {c['name']}", structure_line(c, rich=True))
        if len(shown) < len(listed):
            t.add_row("", f"{len(listed) - len(shown)} farther structures: see --json or plan.html")
    t.add_row("message", result.message)
    if out is not None:
        t.add_row("outputs", str(out))
    console.print(t)

