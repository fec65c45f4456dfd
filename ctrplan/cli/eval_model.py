"""`ctrplan eval-model`: a PINN's accuracy against the exact solver on unseen configurations, with the
paper's figures."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from ctrplan.base.dataio import atomic_write, check_output_dir, output_dir
from ctrplan.base.errors import InputError
from ctrplan.base.memory import check_backbones
from ctrplan.cli.app import app
from ctrplan.cli.options import ModelOpt, RobotOpt
from ctrplan.kinematics.model_file import DEFAULT_MODEL
from ctrplan.kinematics.pinn import PinnBackend
from ctrplan.model.robot import Robot
from ctrplan.training.evaluate import compare

#: Backbone-sized arrays `eval-model` holds per configuration (the exact and predicted backbones and
#: the error statistics; measured 4.5 with tracemalloc at 100 and 400 points).
EVAL_COPIES = 6.0


@app.command("eval-model")
def eval_model(
    model: ModelOpt = None,
    robot: RobotOpt = None,
    n: Annotated[int, typer.Option("--n", help="Unseen configurations (fixed seed).")] = 100,
    points: Annotated[int, typer.Option("--points", help="Backbone points per configuration.")] = 100,
    out: Annotated[Path, typer.Option(
        "--out", help="Directory for the figures.")] = Path("runs/eval_model"),
    as_json: Annotated[bool, typer.Option("--json", help="Print the metrics as JSON on stdout.")] = False,
) -> None:
    """Accuracy of a PINN against the exact solver on unseen configurations, with the paper's figures:
    3-D shapes (fig4_shapes.png), error band (fig5_error_band.png), states (fig6_states.png)."""
    from ctrplan.viz.model_figures import error_band_figure, shapes_figure, states_figure

    if n < 1 or points < 2:
        raise InputError("--n must be >= 1 and --points >= 2")
    model_robot = Robot.load(robot)
    check_backbones("--n", n, "--points", points, model_robot.n_tubes, EVAL_COPIES)
    check_output_dir(out)  # created when the figures are written
    pinn = PinnBackend.load(model, model_robot)
    cmp = compare(pinn, model_robot, n=n, points=points)
    out = output_dir(out)
    figures = [shapes_figure(cmp, out / "fig4_shapes.png"),
               error_band_figure(cmp, out / "fig5_error_band.png"),
               states_figure(cmp, out / "fig6_states.png")]
    card = pinn.card
    training = {k: card.get(k) for k in ("recipe", "wall_time_s", "hardware", "steps", "seed")}
    training["stages"] = [{"recipe": s["recipe"]["name"], "wall_time_s": s["wall_time_s"],
                           "hardware": s["hardware"], "steps": s["steps"]} for s in card.get("stages", [])]
    training["recipe"] = (training["recipe"] or {}).get("name")
    name = str(model) if model else Path(str(card.get("weights_file", DEFAULT_MODEL))).stem
    metrics = {"model": name, **cmp.metrics(), "inference": pinn.describe(),
               "training": training, "figures": [str(f) for f in figures]}
    with atomic_write(out / "metrics.json") as fh:
        json.dump(metrics, fh, indent=2, allow_nan=False)
    if as_json:
        typer.echo(json.dumps(metrics, indent=2, allow_nan=False))
        return
    e, tip = metrics["backbone_error_pct"], metrics["tip_error_mm"]
    console = Console()
    console.print(f"[bold]{metrics['model']}[/] on {metrics['configurations']} unseen configurations:")
    unsolved = metrics["unsolved"]
    if unsolved["count"]:
        console.print(f"  ({unsolved['count']} of {unsolved['of']} configurations left out: the exact solver "
                      f"could not solve them, so there is nothing to compare with; see `unsolved` in "
                      f"{out / 'metrics.json'} and check the domain with `ctrplan stability`)")
    console.print(f"  backbone error / arc length: mean {e['mean']:.3f} %, p95 {e['p95']:.3f} %, "
                  f"max {e['max']:.3f} %")
    for tube, v in tip.items():
        console.print(f"  {tube} tip error: mean {v['mean']:.3f} mm, p99 {v['p99']:.3f} mm, "
                      f"p99.9 {v['p99_9']:.3f} mm, max {v['max']:.3f} mm")
    for label, key in (("tube1 tip orientation", "tip_orientation_error_deg"),
                       ("orientation along the backbone", "orientation_error_deg")):
        o = metrics[key]
        console.print(f"  {label} error: mean {o['mean']:.2f} deg, p99 {o['p99']:.2f} deg, "
                      f"p99.9 {o['p99_9']:.2f} deg, max {o['max']:.2f} deg")
    console.print(f"  u_z RMSE {metrics['u_z_rmse_1_per_m']:.3f} 1/m, theta RMSE "
                  f"{metrics['theta_rmse_rad']:.4f} rad")
    console.print(f"  figures in {out}/")
