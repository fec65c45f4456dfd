"""`ctrplan stability`: is a robot's joint domain free of snapping?"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from ctrplan.base.dataio import atomic_write, check_output_dir, output_dir
from ctrplan.base.errors import InputError
from ctrplan.base.memory import check_fits
from ctrplan.cli.app import app
from ctrplan.cli.options import RobotOpt
from ctrplan.cli.progress import PlainProgress
from ctrplan.model.robot import Robot


@app.command()
def stability(
    robot: RobotOpt = None,
    n: Annotated[int, typer.Option("--n", help="Rotation sweeps from random configurations.")] = 64,
    steps: Annotated[int, typer.Option("--steps", help="Configurations per sweep.")] = 73,
    seed: Annotated[int, typer.Option("--seed", min=0)] = 0,
    out: Annotated[Path, typer.Option(
        "--out", metavar="DIR", help="Where stability.json and stability.png go.")] = Path("runs/stability"),
    as_json: Annotated[bool, typer.Option("--json", help="Print the verdict as JSON on stdout.")] = False,
) -> None:
    """Check elastic stability over the robot's whole joint domain.

    Sweeps one tube rotation at a time across its interval from N random configurations, following
    the equilibrium by continuation, and flags configurations whose equilibrium is unstable
    (conjugate-point test), where the continuation jumps (the branch folds: the robot snaps), or
    where two equilibria exist. The verdict is in the output (JSON `snap_free`); when it snaps, the
    advice names the relative rotation or translation it snaps at and the robot-file limit (e.g.
    domain: {alpha3_minus_alpha2_rad: [-2.4, 2.4]}) that keeps the safe part. Exit 2 on bad input.
    """
    from ctrplan.kinematics.stability import certify, sweep_bytes
    from ctrplan.viz.stability_plot import plot_stability

    if n < 1 or steps < 3:
        raise InputError(f"--n must be >= 1 and --steps >= 3 (got {n}, {steps})")
    model = Robot.load(robot)
    per_step = sweep_bytes(model.n_tubes, 1)
    check_fits("--steps", steps, per_step, "configurations per sweep")
    check_fits("--n", n, sweep_bytes(model.n_tubes, steps), f"sweeps of {steps} configurations")
    check_output_dir(out)  # created when the verdict is written
    console = Console(stderr=True)
    with Progress(TextColumn("stability sweeps"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  console=console, disable=as_json or not console.is_terminal) as bar, \
            PlainProgress("stability", enabled=not console.is_terminal) as plain:
        task = bar.add_task("sweeps", total=n)

        def advance() -> None:
            bar.advance(task)
            plain(f"{int(bar.tasks[task].completed)} of {n} sweeps")

        report, certificate = certify(model, n=n, steps=steps, seed=seed, progress=advance)
    doc = report.to_json()
    folder = output_dir(out)
    doc["plot"] = str(plot_stability(report, folder / "stability.png"))
    if certificate is not None:  # planning then skips the per-state stability test for this robot
        doc["certificate"] = str(certificate)
    with atomic_write(folder / "stability.json") as fh:
        fh.write(json.dumps(doc, indent=2) + "\n")
    if as_json:
        typer.echo(json.dumps(doc, indent=2))
    else:
        verdict = "snap-free" if report.snap_free else "NOT snap-free"
        console.print(f"{model.name}: {verdict} over {report.checked} configurations "
                      f"({100 * report.unstable_fraction:.2f} % flagged: {report.counts})")
        if report.example_q is not None:
            console.print(f"example ({report.example_reason}): q = {[round(v, 4) for v in report.example_q]}")
        if report.advice is not None:
            console.print(f"advice: {report.advice.text}", highlight=False)
        console.print(f"wrote {folder / 'stability.json'} and {doc['plot']}")
