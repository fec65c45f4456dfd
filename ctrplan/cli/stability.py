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
    write_robot: Annotated[Path | None, typer.Option(
        "--write-robot", metavar="R.yaml",
        help="When the robot snaps: write its robot file with the advised limit (named NAME_snapfree) "
             "and check that robot too (its verdict and certificate are printed).")] = None,
) -> None:
    """Check elastic stability over the robot's whole joint domain.

    Sweeps one tube rotation at a time across its interval from N random configurations, following
    the equilibrium by continuation, and flags configurations whose equilibrium is unstable
    (conjugate-point test), where the continuation jumps (the branch folds: the robot snaps), or
    where two equilibria exist. The verdict is in the output (JSON `snap_free`); when it snaps, the
    advice names the relative rotation or translation it snaps at and the robot-file limit (e.g.
    domain: {alpha3_minus_alpha2_rad: [-2.4, 2.4]}) that keeps the safe part; `--write-robot` writes
    that robot file and checks it in the same run (train a PINN on it: a smooth surrogate cannot follow
    a snap). Exit 2 on bad input.
    """
    from ctrplan.kinematics.stability import sweep_bytes
    from ctrplan.viz.stability_plot import plot_stability

    if n < 1 or steps < 3:
        raise InputError(f"--n must be >= 1 and --steps >= 3 (got {n}, {steps})")
    model = Robot.load(robot)
    per_step = sweep_bytes(model.n_tubes, 1)
    check_fits("--steps", steps, per_step, "configurations per sweep")
    check_fits("--n", n, sweep_bytes(model.n_tubes, steps), f"sweeps of {steps} configurations")
    check_output_dir(out)  # created when the verdict is written
    if write_robot is not None:
        check_output_dir(write_robot.parent, "--write-robot")
    console = Console(stderr=True)
    report, certificate = _sweep(model, n, steps, seed, console, as_json)
    doc = report.to_json()
    folder = output_dir(out)
    doc["plot"] = str(plot_stability(report, folder / "stability.png"))
    if certificate is not None:  # planning then skips the per-state stability test for this robot
        doc["certificate"] = str(certificate)
    if write_robot is not None:
        doc["limited_robot"] = _write_limited(model, report, write_robot, n, steps, seed, console, as_json)
    with atomic_write(folder / "stability.json") as fh:
        fh.write(json.dumps(doc, indent=2) + "\n")
    if as_json:
        typer.echo(json.dumps(doc, indent=2))
        return
    verdict = "snap-free" if report.snap_free else "NOT snap-free"
    console.print(f"{model.name}: {verdict} over {report.checked} configurations "
                  f"({100 * report.unstable_fraction:.2f} % flagged: {report.counts})")
    if report.example_q is not None:
        console.print(f"example ({report.example_reason}): q = {[round(v, 4) for v in report.example_q]}")
    if report.advice is not None:
        console.print(f"advice: {report.advice.text}", highlight=False)
    limited = doc.get("limited_robot")
    if limited is not None:
        console.print(limited["text"], highlight=False)
    console.print(f"wrote {folder / 'stability.json'} and {doc['plot']}")


def _sweep(model: Robot, n: int, steps: int, seed: int, console: Console, quiet: bool):
    """`certify` with a progress bar on a terminal (plain lines in a log): (report, certificate)."""
    from ctrplan.kinematics.stability import certify

    with Progress(TextColumn(f"stability sweeps of {model.name}"), BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), console=console, disable=quiet or not console.is_terminal) as bar, \
            PlainProgress("stability", enabled=not console.is_terminal) as plain:
        task = bar.add_task("sweeps", total=n)

        def advance() -> None:
            bar.advance(task)
            plain(f"{model.name}: {int(bar.tasks[task].completed)} of {n} sweeps")

        return certify(model, n=n, steps=steps, seed=seed, progress=advance)


def _write_limited(model: Robot, report, path: Path, n: int, steps: int, seed: int, console: Console,
                   quiet: bool) -> dict:
    """`--write-robot`: the robot limited as the advice says, written to ``path`` and checked with the
    same sweeps; its record (``file`` None when there was nothing to write, and why, in ``text``)."""
    advice = report.advice
    if advice is None or not advice.key:
        why = ("the robot is snap-free: nothing to limit" if advice is None
               else "no single limit keeps the safe part (see the advice)")
        return {"file": None, "text": f"--write-robot: {why}; wrote nothing"}
    limited = advice.limited(model)
    limit = f"{advice.key} {limited.domain.to_dict()[advice.key]}"   # as the file has it
    again, certificate = _sweep(limited, n, steps, seed, console, quiet)
    output_dir(path.parent, "--write-robot")
    limited.save(path, comment=f"{model.name} limited by `ctrplan stability` to its snap-free part: "
                               f"domain {limit}\n"
                               f"{'certified snap-free' if again.snap_free else 'NOT snap-free either'} "
                               f"over {again.checked} configurations ({n} sweeps of {steps}, seed {seed})")
    verdict = ("snap-free (certified: planning skips the per-state stability test for it)"
               if again.snap_free else
               f"NOT snap-free either ({again.counts}): run `ctrplan stability --robot {path}` again")
    return {"file": str(path), "name": limited.name, "fingerprint": limited.fingerprint,
            "snap_free": again.snap_free, "counts": again.counts, "checked": again.checked,
            "certificate": None if certificate is None else str(certificate),
            "text": f"wrote {path} ({limited.name}: {limit}, "
                    f"{100 * advice.kept_share:.0f} % of the domain): {verdict}"}
