"""`ctrplan fk` and `ctrplan shape`: forward kinematics of the configurations in a CSV file."""

from __future__ import annotations

import sys
import warnings
from contextlib import nullcontext
from pathlib import Path
from typing import Annotated

import numpy as np
import typer

from ctrplan.cli import app
from ctrplan.dataio import TIP_NAMES, Table, atomic_write, format_csv, read_joints
from ctrplan.kinematics import BACKENDS, Backbone, make_backend
from ctrplan.kinematics.base import DEFAULT_POINTS
from ctrplan.robot import JOINT_NAMES, Robot

Configs = Annotated[Path, typer.Argument(
    metavar="CONFIGS.csv", show_default=False,
    help="Joint configurations: header beta1,beta2,beta3,alpha1,alpha2,alpha3 (mm, rad); "
         "other columns are ignored.")]
BackendOpt = Annotated[str, typer.Option(
    "--backend", help=f"Kinematics backend: {' | '.join(BACKENDS)}.")]
RobotOpt = Annotated[str | None, typer.Option(
    "--robot", metavar="R.yaml", show_default=False,
    help="Robot file, or a built-in robot name (nominal); default: nominal.")]
OutputOpt = Annotated[Path | None, typer.Option(
    "-o", "--output", metavar="OUT.csv", show_default=False,
    help="Output CSV, written only when every row is done; default: stdout.")]
OutsideOpt = Annotated[bool, typer.Option(
    "--allow-outside-domain",
    help="Only warn for configurations outside the snap-free domain (impossible ones stay errors).")]


def _solve(configs: Path, backend: str, robot: str | None, allow_outside_domain: bool,
           points: int) -> tuple[Table, Backbone]:
    """Read and validate CONFIGS, solve them in one batched call, report non-converged rows."""
    model = Robot.load(robot)
    kinematics = make_backend(backend, model)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        table = read_joints(configs, model, allow_outside_domain=allow_outside_domain)
    for w in caught:
        typer.echo(f"ctrplan: warning: {w.message}", err=True)
    # the robot file's calibration (an extended robot of `ctrplan diagnose`): backlash on the rows in
    # their order, then sensor offset and registration on the solved backbone
    calib = model.calibration
    backbone = calib.apply(kinematics.forward(calib.effective_joints(table.joints), points=points,
                                              check=False))
    failed = table.lines[~backbone.converged]
    if failed.size:
        listed = ", ".join(map(str, failed[:10])) + (", ..." if failed.size > 10 else "")
        typer.echo(f"ctrplan: note: {failed.size} of {len(table.lines)} configurations did not "
                   f"converge (rows {listed}); their outputs are NaN", err=True)
    return table, backbone


def _emit(output: Path | None, render) -> None:
    """Write ``render()`` to ``output`` atomically (or to stdout) only after it succeeded."""
    with atomic_write(output) if output else nullcontext(sys.stdout) as fh:
        fh.write(render())


@app.command()
def fk(configs: Configs, backend: BackendOpt = "cosserat", robot: RobotOpt = None,
       output: OutputOpt = None, allow_outside_domain: OutsideOpt = False) -> None:
    """Tip positions of tubes 1-3 for every configuration (measured-data CSV format).

    Output columns: beta1..alpha3, tip1_x..tip3_z (mm, robot frame; the measurement frame of an
    extended robot with a calibration), converged (1/0).
    Rows that do not converge get NaN tips, converged = 0 and a note on stderr.
    """

    def render() -> str:
        table, backbone = _solve(configs, backend, robot, allow_outside_domain, points=2)
        rows = np.column_stack([table.joints, backbone.tips_mm.reshape(-1, 9), backbone.converged])
        return format_csv((*JOINT_NAMES, *TIP_NAMES, "converged"), rows,
                          ["%r"] * 6 + ["%.6f"] * 9 + ["%d"])

    _emit(output, render)


@app.command()
def shape(configs: Configs, backend: BackendOpt = "cosserat", robot: RobotOpt = None,
          points: Annotated[int, typer.Option("--points", help="Backbone points per configuration, "
                                              "from s = 0 to the tip l1.")] = DEFAULT_POINTS,
          output: OutputOpt = None, allow_outside_domain: OutsideOpt = False) -> None:
    """Backbone of every configuration, long format: row, s, x, y, z (mm, robot frame).

    ``row`` is the configuration's line number in CONFIGS (header = line 1), as in error messages.
    """

    def render() -> str:
        table, backbone = _solve(configs, backend, robot, allow_outside_domain, points=points)
        n = backbone.s_mm.shape[1]
        rows = np.column_stack([np.repeat(table.lines, n), backbone.s_mm.ravel(),
                                backbone.positions_mm.reshape(-1, 3)])
        return format_csv(("row", "s", "x", "y", "z"), rows, ["%d"] + ["%.6f"] * 4)

    _emit(output, render)
