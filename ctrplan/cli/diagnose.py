"""`ctrplan diagnose`: what the model gets wrong on measured tips, the physical cause, the gain."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated

import typer

from ctrplan.base.dataio import check_output_dir
from ctrplan.base.errors import InputError
from ctrplan.calibration import CAUSES, DEFAULT_CAUSES
from ctrplan.cli.app import app
from ctrplan.cli.options import heldout_split
from ctrplan.cli.progress import StatusLine

Data = Annotated[Path, typer.Argument(
    metavar="DATA.csv", show_default=False,
    help="Measured tips: header beta1,beta2,beta3,alpha1,alpha2,alpha3,tip1_x,tip1_y,tip1_z"
         "[,tip2_*,tip3_*] (mm, rad, robot frame, rows in acquisition order), or a "
         "CRL-Dataset-CTCR-Pose file (40 columns, no header).")]
RobotOpt = Annotated[str | None, typer.Option(
    "--robot", metavar="R.yaml", show_default=False,
    help="Robot file (may be an extended robot file), or a built-in name; default: nominal.")]
OutOpt = Annotated[Path | None, typer.Option(
    "--out", metavar="DIR", show_default=False,
    help="Write extended_robot.yaml (not when undetermined), experiment.csv (when explanations tie), "
         "report.json, report.txt and residual plots here.")]
JsonOpt = Annotated[bool, typer.Option("--json", help="Print one JSON document on stdout, nothing else.")]
CandidatesOpt = Annotated[str | None, typer.Option(
    "--candidates", show_default=False,
    help=f"Comma-separated candidate causes to try (default: {', '.join(DEFAULT_CAUSES)}; also in the "
         f"library, tried when named: {', '.join(c for c in CAUSES if c not in DEFAULT_CAUSES)}).")]
HeldoutOpt = Annotated[float | None, typer.Option(
    "--heldout", metavar="FRACTION", show_default=False,
    help="Hold out this fraction of the rows in contiguous blocks drawn with --seed (default 0.25).")]
HeldoutLastOpt = Annotated[float | None, typer.Option(
    "--heldout-last", metavar="FRACTION", show_default=False,
    help="Hold out the last FRACTION of the rows in acquisition order instead (evaluation on future "
         "data; the stability check then resamples the training rows only).")]
SeedOpt = Annotated[int, typer.Option("--seed", min=0, help="Seed of the held-out block draw.")]
MaxRowsOpt = Annotated[int, typer.Option(
    "--max-rows", help="Diagnose at most this many rows (larger files: contiguous runs spread over the "
                       "file; the direction of motion still comes from the full sequence).")]
PairsOpt = Annotated[int, typer.Option(
    "--pairs", help="Grow cause sets by trying this many partners per step (0: single causes only).")]
ExperimentOpt = Annotated[int, typer.Option(
    "--experiment-rows", metavar="N",
    help="When explanations tie: write N configurations (in the domain, stable) where their predicted "
         "tips differ most to DIR/experiment.csv; measure them, append them, diagnose again.")]

@app.command()
def diagnose(data: Data, robot: RobotOpt = None, out: OutOpt = None, json_: JsonOpt = False,
             candidates: CandidatesOpt = None, heldout: HeldoutOpt = None,
             heldout_last: HeldoutLastOpt = None, seed: SeedOpt = 0, pairs: PairsOpt = 3,
             max_rows: MaxRowsOpt = 1000, experiment_rows: ExperimentOpt = 20) -> None:
    """Show what the model gets wrong on measured tips, name the physical cause, extend the model.

    Fits every candidate cause on the training rows and names the simplest that beats the nominal
    model (training BIC and held-out error) with plausible parameters on most of several splits, and
    reports the held-out error before and after against the measurement noise (estimated from the
    data). `none` only when the nominal model already matches to the noise; `undetermined` when the
    rows cannot identify a cause (nothing named, no extended robot); `unexplained` when no cause helps.
    """
    from ctrplan.calibration import DiagnoseOptions, make_effect, read_measured, write_outputs
    from ctrplan.calibration import diagnose as run_diagnosis
    from ctrplan.model.robot import Robot

    names = DEFAULT_CAUSES if candidates is None else tuple(
        c.strip() for c in candidates.split(",") if c.strip())
    if not names:
        raise InputError("--candidates: give at least one cause")
    for c in names:
        try:
            make_effect(c)
        except InputError as exc:
            raise InputError(f"--candidates: {exc}") from None
    fraction, last = heldout_split(heldout, heldout_last)
    if max_rows < 30:
        raise InputError(f"--max-rows: must be >= 30, got {max_rows}")
    if pairs < 0:
        raise InputError(f"--pairs: must be >= 0, got {pairs}")
    if experiment_rows < 1:
        raise InputError(f"--experiment-rows: must be >= 1, got {experiment_rows}")
    if out is not None:
        check_output_dir(out)  # created when the outputs are written
    model = Robot.load(robot)
    measured = read_measured(data, model)
    opts = DiagnoseOptions(candidates=names, heldout=fraction, heldout_last=last, seed=seed, pairs=pairs,
                           max_rows=max_rows, experiment_rows=experiment_rows)
    with _progress() as progress:
        diag = run_diagnosis(measured, model, opts, progress=progress)
    dropped = diag.rows_in_file - len(diag.data)
    if dropped:
        typer.echo(f"ctrplan: note: --max-rows {max_rows}: {dropped} of {diag.rows_in_file} rows dropped "
                   f"(diagnosing {len(diag.data)} rows in contiguous runs spread over the file)", err=True)
    written = []
    if out is not None:
        from ctrplan.viz.diagnosis_plots import write_plots

        written = write_outputs(diag, out) + write_plots(diag, out)
    if json_:
        sys.stdout.write(json.dumps(diag.to_json(), indent=2, allow_nan=False) + "\n")
    else:
        typer.echo(diag.summary())
        if written:
            typer.echo(f"wrote {', '.join(p.name for p in written)} to {out}/")


def _progress() -> StatusLine:
    """What `diagnose` is doing, on stderr: a rich status line with the elapsed time on a terminal,
    else a plain line about every 10 s (a timer thread: one fit can take longer)."""
    from rich.console import Console

    return StatusLine(Console(stderr=True, highlight=False), "diagnose", "reading", timed=True)
