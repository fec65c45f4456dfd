"""`ctrplan fk` and `ctrplan shape`: forward kinematics of the configurations in a CSV file.

Every row is read and checked before any is solved; the rows are then solved and written in chunks,
so memory stays bounded on long inputs, with a progress bar on stderr when it is a terminal.
"""

from __future__ import annotations

import sys
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager, nullcontext
from dataclasses import replace
from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from ctrplan.base.dataio import atomic_write, format_csv, tip_names
from ctrplan.base.errors import InputError
from ctrplan.base.memory import backbone_bytes, check_fits
from ctrplan.cli.app import app
from ctrplan.cli.options import BackendOpt, ModelOpt, RobotOpt, load_backend
from ctrplan.kinematics import Backbone
from ctrplan.kinematics.base import DEFAULT_POINTS
from ctrplan.kinematics.registry import EXACT_MODEL
from ctrplan.model.robot import Robot, read_joints

#: Output rows (configurations x backbone points) solved and written per chunk.
CHUNK_ROWS = 10_000
#: Memory (bytes) of one output row while its chunk is formatted: its numbers as Python floats and
#: its line of text.
CSV_ROW_BYTES = 300

Configs = Annotated[Path, typer.Argument(
    metavar="CONFIGS.csv", show_default=False,
    help="Joint configurations: header beta1..betaN,alpha1..alphaN for the robot's N tubes (three "
         "tubes: beta1,beta2,beta3,alpha1,alpha2,alpha3), mm and rad; other columns are ignored.")]
OutputOpt = Annotated[Path | None, typer.Option(
    "-o", "--output", metavar="OUT.csv", show_default=False,
    help="Output CSV, written only when every row is done (through a symbolic link to its target; "
         "a device or named pipe is written in place); default: stdout.")]
OutsideOpt = Annotated[bool, typer.Option(
    "--allow-outside-domain",
    help="Only warn for configurations outside the snap-free domain (impossible ones stay errors).")]


@contextmanager
def progress_bar(total: int, what: str) -> Iterator[Callable[[int], None]]:
    """``advance(n)`` for a transient rich progress bar on stderr, shown only when stderr is a
    terminal (stdout is never touched)."""
    from rich.console import Console

    console = Console(stderr=True)
    if not console.is_terminal:
        yield lambda n: None
        return
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    with Progress(TextColumn(what), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                  console=console, transient=True,
                  redirect_stdout=False, redirect_stderr=False) as bar:
        task = bar.add_task(what, total=total)
        yield lambda n: bar.update(task, advance=n)


def _run(configs: Path, backend: str, robot: str | None, model: str | None, allow_outside_domain: bool,
         output: Path | None, points: int, header: Callable[[Robot], tuple[str, ...]],
         rows: Callable[[np.ndarray, Backbone], tuple[np.ndarray, list[str]]],
         stability: bool = False) -> None:
    """Check every row of CONFIGS, then solve and write them chunk by chunk (``rows(lines, backbone)``
    gives a chunk's output rows and formats, ``header(robot)`` the columns); note non-converged rows
    on stderr. With ``stability`` the backbones carry elastic stability where the backend computes it."""
    robot_model = Robot.load(robot)
    # a chunk holds max(CHUNK_ROWS, points) points: two backbones' worth each, and its CSV text
    check_fits("--points", points, 2 * backbone_bytes(robot_model.n_tubes, 1) + CSV_ROW_BYTES,
               "backbone points per configuration")
    with atomic_write(output) if output else nullcontext(sys.stdout) as fh:
        kinematics = load_backend(backend, robot_model, model)
        if stability:
            kinematics = kinematics.checking_stability()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            table = read_joints(configs, robot_model, allow_outside_domain=allow_outside_domain)
        for w in caught:
            typer.echo(f"ctrplan: warning: {w.message}", err=True)
        # the robot file's calibration (an extended robot of `ctrplan diagnose`): backlash and windup
        # on the rows in their order, then sensor offset and registration on each solved backbone
        calib = robot_model.calibration
        reached = calib.mechanics_joints(table.joints)
        chunk = max(1, CHUNK_ROWS // points)
        failed = []
        fh.write(",".join(header(robot_model)) + "\n")
        with progress_bar(len(table.lines), "configurations") as advance:
            for start in range(0, len(table.lines), chunk):
                rows_ = slice(start, start + chunk)
                lines = table.lines[rows_]
                backbone = calib.apply(kinematics.forward(reached[rows_], points=points, check=False))
                backbone = replace(backbone, q=table.joints[rows_])  # outputs name the commanded joints
                failed.append(lines[~backbone.converged])
                fh.write(format_csv(None, *rows(lines, backbone)))
                advance(len(lines))
    failed = np.concatenate(failed)
    if failed.size:
        listed = ", ".join(map(str, failed[:10])) + (", ..." if failed.size > 10 else "")
        typer.echo(f"ctrplan: note: {failed.size} of {len(table.lines)} configurations did not "
                   f"converge (rows {listed}); their outputs are NaN", err=True)


@app.command()
def fk(configs: Configs, backend: BackendOpt = EXACT_MODEL, robot: RobotOpt = None, model: ModelOpt = None,
       output: OutputOpt = None, allow_outside_domain: OutsideOpt = False) -> None:
    """Tip positions of tubes 1-N for every configuration (measured-data CSV format).

    Output columns: beta1..alphaN, tip1_x..tipN_z (mm, robot frame; the measurement frame of an
    extended robot with a calibration), converged (1/0), stable (1/0: the equilibrium is elastically
    stable; nan where the backend cannot tell -- the PINN).
    Rows that do not converge get NaN tips, converged = 0 and a note on stderr.
    """

    def rows(lines: np.ndarray, b: Backbone) -> tuple[np.ndarray, list[str]]:
        n = b.n_tubes
        stable = b.stable.astype(float) if b.stability is not None else np.full(len(b), np.nan)
        return (np.column_stack([b.q, b.tips_mm.reshape(-1, 3 * n), b.converged, stable]),
                ["%r"] * (2 * n) + ["%.6f"] * (3 * n) + ["%d", "%.0f"])

    _run(configs, backend, robot, model, allow_outside_domain, output, 2,
         lambda r: (*r.joint_names, *tip_names(r.n_tubes), "converged", "stable"), rows, stability=True)


@app.command()
def shape(configs: Configs, backend: BackendOpt = EXACT_MODEL, robot: RobotOpt = None, model: ModelOpt = None,
          points: Annotated[int, typer.Option("--points", help="Backbone points per configuration, "
                                              "from s = 0 to the tip l1.")] = DEFAULT_POINTS,
          output: OutputOpt = None, allow_outside_domain: OutsideOpt = False) -> None:
    """Backbone of every configuration, long format: row, s, x, y, z (mm, robot frame).

    ``row`` is the configuration's line number in CONFIGS (header = line 1), as in error messages.
    """
    if points < 2:
        raise InputError(f"--points: need at least 2 backbone points, got {points}")

    def rows(lines: np.ndarray, b: Backbone) -> tuple[np.ndarray, list[str]]:
        n = b.s_mm.shape[1]
        return (np.column_stack([np.repeat(lines, n), b.s_mm.ravel(), b.positions_mm.reshape(-1, 3)]),
                ["%d"] + ["%.6f"] * 4)

    _run(configs, backend, robot, model, allow_outside_domain, output, points,
         lambda r: ("row", "s", "x", "y", "z"), rows)
