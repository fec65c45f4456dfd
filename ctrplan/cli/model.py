"""`ctrplan train` and `ctrplan eval-model`: train, ship and evaluate PINN surrogates."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from ctrplan.cli import app
from ctrplan.cli.kinematics import ModelOpt, RobotOpt, as_option
from ctrplan.dataio import atomic_write, output_dir
from ctrplan.errors import InputError
from ctrplan.kinematics.model_file import DEFAULT_MODEL, MODELS_DIR
from ctrplan.kinematics.pinn import PinnBackend
from ctrplan.robot import Robot
from ctrplan.training.evaluate import compare
from ctrplan.training.trainer import RECIPES, get_recipe
from ctrplan.training.trainer import train as run_training

if TYPE_CHECKING:
    from ctrplan.training.fewshot import FewShot

@app.command()
def train(
    name: Annotated[str | None, typer.Option(
        "--name", help="Model name: writes models/NAME.safetensors and models/NAME.json "
                       "(default: ROBOT_RECIPE).")] = None,
    robot: RobotOpt = None,
    recipe: Annotated[str | None, typer.Option(
        "--recipe", help=f"Recipe: {' | '.join(RECIPES)} (default: fast; finetune with --measured).")] = None,
    steps: Annotated[int | None, typer.Option(
        "--steps", help="Optimiser steps (recipe default).")] = None,
    time_limit: Annotated[float | None, typer.Option(
        "--time-limit", help="Stop after this many minutes (the learning-rate schedule fits it).")] = None,
    seed: Annotated[int, typer.Option("--seed")] = 0,
    device: Annotated[str, typer.Option("--device", help="cpu | cuda | cuda:N")] = "cpu",
    threads: Annotated[int | None, typer.Option("--threads", help="CPU threads for torch.")] = None,
    resume: Annotated[bool, typer.Option(
        "--resume", help="Continue from the last checkpoint of NAME.")] = False,
    init: Annotated[str | None, typer.Option(
        "--init", help=f"Start from a model's weights (e.g. `--recipe polish --init NAME`; with "
                       f"--measured the default is {DEFAULT_MODEL}).")] = None,
    measured: Annotated[Path | None, typer.Option(
        "--measured", metavar="DATA.csv", show_default=False,
        help="Fine-tune on measured tips (paper stage b): a measured-data CSV or CRL file, split into "
             "training and held-out rows as `ctrplan diagnose` splits it.")] = None,
    shots: Annotated[int | None, typer.Option(
        "--shots", help="With --measured: training rows used (default: all training rows).")] = None,
    heldout: Annotated[float | None, typer.Option(
        "--heldout", metavar="FRACTION", show_default=False,
        help="With --measured: fraction of the rows held out in contiguous blocks (default 0.25).")] = None,
    heldout_last: Annotated[float | None, typer.Option(
        "--heldout-last", metavar="FRACTION", show_default=False,
        help="With --measured: hold out the last FRACTION of the rows in acquisition order instead.")] = None,
    out_dir: Annotated[Path, typer.Option("--out-dir", help="Where models are written.")] = MODELS_DIR,
    settings: Annotated[list[str] | None, typer.Option(
        "--set", metavar="FIELD=VALUE",
        help="Override a recipe field, e.g. --set dense_batch=16384 (value as JSON; repeatable).")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the model card as JSON on stdout.")] = False,
) -> None:
    """Train a PINN on the Cosserat-rod equations (paper III) and write it with its model card.

    Checkpoints go to NAME.ckpt.* beside the model every two minutes; `--resume` picks them up.
    The card records the robot (and its fingerprint), recipe, sample counts, wall time, hardware and
    accuracy on 100 unseen configurations.

    With `--measured DATA.csv --shots N` it continues training a model (default: the shipped one) on
    N measured training rows plus the physics residuals, and prints the held-out tip error of the
    nominal and extended Cosserat models (`diagnose` on the same rows) and of the PINN before and
    after; the card records the data file (name, SHA-256), the split and that table.
    """
    import torch

    if device.startswith("cuda") and not torch.cuda.is_available():
        raise InputError(f"--device: {device} requested but no CUDA device is available")
    if measured is None and shots is not None:
        raise InputError("--shots: needs --measured DATA.csv")
    if threads:
        torch.set_num_threads(threads)
    model_robot = Robot.load(robot)
    if measured is None:
        model_robot.calibration.refuse(model_robot.name, "train")
    recipe = recipe or ("fast" if measured is None else "finetune")
    try:
        rec = get_recipe(recipe, steps=steps, **_parse_settings(settings or []))
    except InputError as exc:
        raise as_option(exc, {"recipe": "--recipe", "overrides": "--set"}) from None
    fewshot = None
    if measured is not None:
        init = init or DEFAULT_MODEL
        fewshot = _measured_split(measured, model_robot, shots, heldout, heldout_last)
    start = PinnBackend.load(init, model_robot) if init else None
    out = output_dir(out_dir, "--out-dir") / (name or f"{model_robot.name}_{rec.name}")
    console = Console(stderr=True)
    bar = Progress(TextColumn("train {task.fields[recipe]}"), BarColumn(), MofNCompleteColumn(),
                   TimeElapsedColumn(), TextColumn("loss {task.fields[loss]}"), console=console)
    with bar:
        task = bar.add_task("train", total=rec.steps, recipe=rec.name, loss="-")

        def progress(step: int, total: int, stats: dict) -> None:
            bar.update(task, completed=step, loss=f"{stats['loss']:.4g}")

        common = dict(seed=seed, device=device, resume=resume, progress=progress,
                      time_limit_s=time_limit * 60 if time_limit else None)
        if fewshot is not None:
            from ctrplan.training.finetune import finetune, table_text

            result = finetune(fewshot, start, out, rec, init_model=str(init), **common)
        else:
            result = run_training(
                model_robot, rec, out, init_from=start.net if start else None, **common,
                extra_card={"stages": training_stages(start.card)} if start else None,
                evaluate=lambda net: compare(PinnBackend(model_robot, net), model_robot).metrics())
    m = result.card["metrics"]["backbone_error_pct"]
    console.print(f"wrote {out.with_suffix('.safetensors')} and {out.with_suffix('.json')}: "
                  f"{result.steps} steps in {result.wall_time_s / 60:.1f} min; backbone error on 100 "
                  f"unseen configurations: mean {m['mean']:.3f} % (vs the robot file's Cosserat model), "
                  f"max {m['max']:.3f} %")
    if fewshot is not None:
        console.print(table_text(result.card["metrics"]["measured_heldout"]))
    if as_json:
        typer.echo(out.with_suffix(".json").read_text())  # the card as written, with robot and hash


def _measured_split(path: Path, robot: Robot, shots: int | None, heldout: float | None,
                    heldout_last: float | None) -> FewShot:
    """Read ``path`` and take the fine-tuning shots (all training rows if ``shots`` is None), with
    the held-out rows of `ctrplan diagnose` (its options and default seed)."""
    from ctrplan.calibration.data import read_measured
    from ctrplan.cli.diagnose import heldout_split
    from ctrplan.training.fewshot import split_shots

    if shots is not None and shots < 1:
        raise InputError(f"--shots: must be >= 1, got {shots}")
    fraction, last = heldout_split(heldout, heldout_last)
    data = read_measured(path, robot)
    try:
        return split_shots(data, shots, fraction, heldout_last=last)
    except InputError as exc:
        raise as_option(exc, {"shots": "--shots"}) from None


def _parse_settings(items: list[str]) -> dict:
    """``["dense_batch=16384", "lr=1e-3"]`` -> ``{"dense_batch": 16384, "lr": 0.001}``."""
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise InputError(f"--set: expected FIELD=VALUE, got {item!r}")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def training_stages(card: dict) -> list[dict]:
    """The training stages recorded in a model card (a card without ``stages`` is one stage)."""
    if card.get("stages"):
        return card["stages"]
    return [{k: card.get(k) for k in ("recipe", "steps", "wall_time_s", "hardware", "seed")}]


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
    metrics = {"model": str(model or DEFAULT_MODEL), **cmp.metrics(), "inference": pinn.describe(),
               "training": training, "figures": [str(f) for f in figures]}
    with atomic_write(out / "metrics.json") as fh:
        json.dump(metrics, fh, indent=2)
    if as_json:
        typer.echo(json.dumps(metrics, indent=2))
        return
    e, tip = metrics["backbone_error_pct"], metrics["tip_error_mm"]
    console = Console()
    console.print(f"[bold]{metrics['model']}[/] on {n} unseen configurations:")
    console.print(f"  backbone error / arc length: mean {e['mean']:.3f} %, p95 {e['p95']:.3f} %, "
                  f"max {e['max']:.3f} %")
    for tube, v in tip.items():
        console.print(f"  {tube} tip error: mean {v['mean']:.3f} mm, p99 {v['p99']:.3f} mm, "
                      f"p99.9 {v['p99_9']:.3f} mm, max {v['max']:.3f} mm")
    o = metrics["orientation_error_deg"]
    console.print(f"  u_z RMSE {metrics['u_z_rmse_1_per_m']:.3f} 1/m, theta RMSE "
                  f"{metrics['theta_rmse_rad']:.4f} rad, orientation error mean {o['mean']:.2f} deg, "
                  f"p99 {o['p99']:.2f} deg, max {o['max']:.2f} deg")
    console.print(f"  figures in {out}/")
