"""`ctrplan train`: train and ship PINN surrogates (`ctrplan eval-model` is in `ctrplan.cli.eval_model`)."""

from __future__ import annotations

import json
import re
import shlex
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

from ctrplan.base.dataio import check_output_dir
from ctrplan.base.errors import InputError
from ctrplan.base.memory import backbone_bytes, check_fits
from ctrplan.cli.app import app
from ctrplan.cli.options import (
    RobotOpt,
    as_option,
    heldout_options,
    heldout_split,
    json_option,
    parse_duration,
    seed_option,
    time_limit_option,
)
from ctrplan.cli.progress import PlainProgress
from ctrplan.kinematics.model_file import DEFAULT_MODEL, MODELS_DIR
from ctrplan.kinematics.pinn import ERROR_BOUND_KEY, PinnBackend
from ctrplan.kinematics.pinn_net import PinnNet
from ctrplan.model.robot import Robot
from ctrplan.training.budget import CLOCKS, MIN_EVAL_CONFIGURATIONS, TimeBudget, now, use_clock
from ctrplan.training.checkpoints import check_checkpoint, checkpoint_meta, remove_checkpoint
from ctrplan.training.evaluate import CALIBRATION_CONFIGURATIONS, calibrate, compare, worst_configurations
from ctrplan.training.recipes import ADAPT_STEPS, DEFAULT_RECIPE, RECIPES, Recipe, get_recipe, pool_size
from ctrplan.training.target import ACCURACY_TARGET, Monitor, summary
from ctrplan.training.trainer import CHECKPOINT_EVERY_S, TrainResult
from ctrplan.training.trainer import train as run_training

if TYPE_CHECKING:
    from ctrplan.training.fewshot import FewShot
    from ctrplan.training.transfer import Transfer

#: A model name: the file stem of models/NAME.safetensors, never a path.
MODEL_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,99}")
#: Memory of the exact pool per solution, in backbones: float64 states plus their float32 copy.
POOL_COPIES = 2.0
#: A run longer than this times its --time-limit says why (the parts no limit cuts).
OVERRUN = 1.05
#: Unseen configurations the model card's accuracy is measured on at the end of `ctrplan train` (the
#: first of `eval-model`'s: the same configurations as `ctrplan eval-model --n 5000`).
CARD_EVAL_CONFIGURATIONS = 5000


NameOpt = Annotated[str | None, typer.Option(
    "--name", help="Model name (letters, digits, _ and -): writes models/NAME.safetensors and "
                   "models/NAME.json (default: ROBOT_RECIPE).")]
RecipeOpt = Annotated[str | None, typer.Option(
    "--recipe", help=f"Recipe: {' | '.join(RECIPES)} (default: {DEFAULT_RECIPE}, "
                     f"{RECIPES[DEFAULT_RECIPE].minutes:g} min; finetune with --measured).")]
StepsOpt = Annotated[int | None, typer.Option("--steps", min=1, help="Optimiser steps (recipe default).")]
TrainTimeLimitOpt = time_limit_option(
    "Time for the whole command, e.g. 25m or 90s; a bare number is minutes: exact data, training, "
    "evaluation and calibration (default: the recipe's budget); what it cuts is reported; the "
    "learning-rate schedule fits it.")
ClockOpt = Annotated[str, typer.Option(
    "--clock", metavar="wall|cpu",
    help="The clock --time-limit, the schedule and the time-to-target read: wall time, or the CPU time "
         "of this process (all its threads; for a machine shared with other jobs).")]
SeedOpt = seed_option()
DeviceOpt = Annotated[str, typer.Option("--device", help="cpu | cuda | cuda:N")]
ThreadsOpt = Annotated[int | None, typer.Option(
    "--threads", min=1, help="CPU cores to use (default: all): with 2 or more, one solves the mining "
                             "rounds in a worker process and torch gets the rest.")]
ResumeOpt = Annotated[bool, typer.Option("--resume", help="Continue from the last checkpoint of NAME.")]
InitOpt = Annotated[str | None, typer.Option(
    "--init", help=f"Start from a model's weights (e.g. `--recipe polish --init NAME`; with "
                   f"--measured the default is {DEFAULT_MODEL}).")]
MeasuredOpt = Annotated[Path | None, typer.Option(
    "--measured", metavar="DATA.csv", show_default=False,
    help="Fine-tune on measured tips (paper stage b): a measured-data CSV or CRL file, split into "
         "training and held-out rows as `ctrplan diagnose` splits it.")]
ShotsOpt = Annotated[int | None, typer.Option(
    "--shots", help="With --measured: training rows used (default: all training rows).")]
HeldoutOpt, HeldoutLastOpt = heldout_options(
    "With --measured: fraction of the rows held out in contiguous blocks (default 0.25).",
    "With --measured: hold out the last FRACTION of the rows in acquisition order instead.")
AdaptOpt = Annotated[int, typer.Option(
    "--adapt-steps", min=0,
    help="With --measured: Adam steps to adapt the PINN to the extended mechanics diagnose finds, "
         "however long they take (4-6 minutes on two cores for the default; 0: fine-tune the PINN as "
         "it is).")]
TransferOpt = Annotated[str, typer.Option(
    "--transfer", metavar="auto|none|NAME",
    help="Start from the layers of a model trained for another robot: auto picks the nearest shipped "
         "or models/ model with the same tube count (by tube and domain parameters), none trains from "
         "scratch, NAME|PATH names one. Not with --init, --measured or --resume.")]
OutDirOpt = Annotated[Path, typer.Option("--out-dir", help="Where models are written.")]
SetOpt = Annotated[list[str] | None, typer.Option(
    "--set", metavar="FIELD=VALUE",
    help="Override a recipe field, e.g. --set dense_batch=16384 (value as JSON; repeatable).")]
CardJsonOpt = json_option("Print the model card as JSON on stdout.")


@app.command()
def train(name: NameOpt = None, robot: RobotOpt = None, recipe: RecipeOpt = None, steps: StepsOpt = None,
          time_limit: TrainTimeLimitOpt = None, clock: ClockOpt = "wall", seed: SeedOpt = 0,
          device: DeviceOpt = "cpu", threads: ThreadsOpt = None, resume: ResumeOpt = False,
          init: InitOpt = None, measured: MeasuredOpt = None, shots: ShotsOpt = None,
          heldout: HeldoutOpt = None, heldout_last: HeldoutLastOpt = None,
          adapt_steps: AdaptOpt = ADAPT_STEPS, transfer: TransferOpt = "auto",
          out_dir: OutDirOpt = MODELS_DIR, settings: SetOpt = None, as_json: CardJsonOpt = False) -> None:
    """Train a PINN on the Cosserat-rod equations (paper III) and write it with its model card.

    The default recipe solves an exact pool, then trains with hard-example mining for its time
    budget; the bar shows the loss and, after each mining round, the network's tube-1 tip error on
    that round's fresh configurations. Checkpoints go to NAME.ckpt.* beside the model every two
    minutes; `--resume` picks them up (Ctrl-C prints the command). The card records the robot (and
    its fingerprint), recipe, sample counts, the configurations the exact solver could not solve,
    wall time, hardware, accuracy on 5,000 unseen configurations, whether it meets the accuracy
    target (meets_target), what the time limit cut, and the calibrated backbone error bound the
    planner adds to the capsule radii when it plans with this model (5,000 more configurations).

    With `--measured DATA.csv --shots N` it continues training a model (default: the shipped one) on
    N measured training rows plus the physics residuals, and prints the held-out tip error of the
    nominal and extended Cosserat models (`diagnose` on the same rows) and of the PINN before, adapted
    and after; the last fifth of the shots choose the stage written (never one worse there than the
    model it started from; it says which), NAME_adapted is written too, and NAME.robot.yaml carries the
    calibration so `fk --robot NAME.robot.yaml --model NAME` predicts what the tracker measures; the card
    records the data file (name, SHA-256), the split, the stage kept and that table.
    """
    if clock not in CLOCKS:
        raise InputError(f"--clock {clock!r}: one of {', '.join(CLOCKS)}")
    use_clock(clock)
    t_start = now()  # --time-limit bounds the command from here, on that clock
    import torch

    if name is not None:
        check_model_name(name, "--name")
    limit_s = parse_duration(time_limit, "min")
    time_limit = None if limit_s is None else limit_s / 60.0  # minutes
    if device.startswith("cuda") and not torch.cuda.is_available():
        raise InputError(f"--device: {device} requested but no CUDA device is available")
    if measured is None and shots is not None:
        raise InputError("--shots: needs --measured DATA.csv")
    mining_worker = _use_cores(threads)
    model_robot = Robot.load(robot)
    if measured is None:
        model_robot.calibration.refuse(model_robot.name, "train")
    rec = _recipe(recipe or (DEFAULT_RECIPE if measured is None else "finetune"), settings or [], steps)
    fewshot = None
    if measured is not None:
        init = init or DEFAULT_MODEL
        fewshot = _measured_split(measured, model_robot, shots, heldout, heldout_last)
    start = PinnBackend.load(init, model_robot) if init else None
    source = _transfer_source(transfer, model_robot, rec,
                              plain=start is not None or measured is not None or resume)
    if name is None:
        name = check_model_name(f"{model_robot.name}_{rec.name}", "the robot's name (give --name)")
    check_fits("--set dense_configs", pool_size(rec),
               POOL_COPIES * backbone_bytes(model_robot.n_tubes, rec.dense_points), "exact solutions")
    out = check_output_dir(out_dir, "--out-dir") / name  # made on save
    console = Console(stderr=True)
    limit_s = time_limit * 60 if time_limit is not None else (rec.minutes * 60 if rec.minutes else None)
    budget = TimeBudget(limit_s, CARD_EVAL_CONFIGURATIONS + CALIBRATION_CONFIGURATIONS, start=t_start)
    if resume:
        meta = check_checkpoint(out, model_robot)
        console.print(f"resuming {name} from step {meta['step']:,} ({meta['elapsed_s'] / 60:.1f} min of "
                      f"training done; checkpoint {meta['file']})")
        source = _resumed_transfer(meta, model_robot)
    try:
        result = _run(model_robot, rec, out, start, fewshot, budget, console,
                      dict(seed=seed, device=device, resume=resume, mining_worker=mining_worker),
                      init=init, adapt_steps=adapt_steps,
                      transfer=source)
    except KeyboardInterrupt:
        _how_to_resume(console, out)
        raise
    remove_checkpoint(out)  # the run finished: nothing to resume
    card = result.card
    _report(console, out, result, budget)
    if fewshot is not None:
        _report_finetune(console, out, card)
    if as_json:
        typer.echo(out.with_suffix(".json").read_text())  # the card as written, with robot and hash


def _use_cores(threads: int | None) -> bool:
    """Share the cores (``--threads``, default: all this process may use) between torch and a
    mining worker: with two or more, one solves the mining rounds (`ctrplan.training.rounds`) and
    torch gets the rest (a second torch thread buys nothing at the default recipe's batch); returns
    whether a worker mines."""
    import torch

    from ctrplan.base.parallel import available_cores

    cores = threads or len(available_cores())
    worker = cores >= 2
    if threads is not None or worker:
        torch.set_num_threads(cores - 1 if worker else cores)
    return worker


def _recipe(name: str, settings: list[str], steps: int | None) -> Recipe:
    """The recipe ``name`` with the ``--set FIELD=VALUE`` overrides and ``--steps``; `InputError`
    naming the option."""
    try:
        overrides = _parse_settings(settings)
        if steps is not None:
            if "steps" in overrides:
                raise InputError("--set: steps is given twice (also as --steps); give it once")
            overrides["steps"] = steps
        return get_recipe(name, **overrides)
    except InputError as exc:
        raise as_option(exc, {"recipe": "--recipe", "overrides": "--set"}) from None


def _report_finetune(console: Console, out: Path, card: dict) -> None:
    """After fine-tuning on measured tips: the stages' times, the files written, the held-out table
    and the stage kept."""
    from ctrplan.training.finetune import kept_text, table_text

    stages = card["finetuned_on"]["stage_seconds"]
    console.print("stages: " + ", ".join(f"{k[:-2]} {v:.0f} s" for k, v in stages.items())
                  + f"; its robot in {out.with_suffix('.robot.yaml')} (with the calibration: `fk`, "
                    f"`shape`), its mechanics in {out.with_suffix('.mechanics.robot.yaml')} (`plan`); "
                    f"the adapted model in {out.name}_adapted.safetensors")
    console.print(table_text(card["metrics"]["measured_heldout"]))
    console.print(kept_text(card["finetuned_on"]["kept"]))


def _transfer_source(choice: str, robot: Robot, recipe: Recipe, plain: bool) -> Transfer | None:
    """The model `--transfer` names (``plain``: a run that starts from a model of this robot, or
    resumes, uses none; `InputError` when it was named explicitly)."""
    from ctrplan.training.transfer import load_transfer, nearest_model

    if choice == "none" or (plain and choice == "auto"):
        return None
    if plain:
        raise InputError("--transfer: not with --init, --measured or --resume (they start from a model "
                         "of this robot or from the checkpoint)")
    if choice != "auto":
        return load_transfer(choice, robot)
    shape = {"features": recipe.features, "harmonics": recipe.harmonics, "hidden": recipe.hidden,
             "layers": recipe.layers}
    return nearest_model(robot, shape)


def _resumed_transfer(meta: dict, robot: Robot) -> Transfer | None:
    """The transfer the checkpointed run started from (its recipe and frame tube depend on it)."""
    from ctrplan.training.transfer import load_transfer

    source = meta.get("transferred_from")
    return load_transfer(source["file"], robot) if source else None


def _run(robot: Robot, rec: Recipe, out: Path, start: PinnBackend | None, fewshot: FewShot | None,
         budget: TimeBudget, console: Console, common: dict, *, init: str | None,
         adapt_steps: int, transfer: Transfer | None) -> TrainResult:
    """Train (or fine-tune on ``fewshot``) with a progress bar on a terminal; the card's evaluation
    and calibration are cut short where the ``budget`` runs out (`ctrplan.training.budget`)."""
    bar = Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.fields[done]}"),
                   TimeElapsedColumn(), TextColumn("{task.fields[info]}"), console=console,
                   disable=not console.is_terminal)  # a log gets plain lines and the summary below
    with bar, PlainProgress("train", enabled=not console.is_terminal) as plain:
        data_task = bar.add_task("exact solutions", total=None, done="", info="")
        task = bar.add_task(f"train {rec.name}", total=1.0, done="", info="", visible=False)

        def data_progress(done: int, total: int) -> None:
            rate = done / max(bar.tasks[data_task].elapsed or 1e-9, 1e-9)
            bar.update(data_task, completed=done, total=total, done=f"{done}/{total}",
                       info=f"{rate:,.0f} solutions/s")
            plain(f"exact solutions {done:,}/{total:,}")

        def progress(step: int, total: int, stats: dict) -> None:
            info = f"loss {stats['loss']:.4g}"
            if "unseen_tip_max_mm" in stats:
                info += (f" | unseen tip p99.9 {stats['unseen_tip_p99_9_mm']:.2f} max "
                         f"{stats['unseen_tip_max_mm']:.2f} mm")
            t, limit = budget.elapsed_s(), budget.limit_s  # the whole command's clock
            bar.update(task, completed=training_fraction(step, total, t, limit),
                       done=progress_text(step, total, t, limit), info=info, visible=True)
            plain(f"step {progress_text(step, total, t, limit)}, {info}")

        if fewshot is not None:
            from ctrplan.training.finetune import finetune

            return finetune(fewshot, start, out, rec, init_model=str(init), log=console.print,
                            adapt_steps=adapt_steps, progress=progress, time_limit_s=budget.limit_s,
                            **common)
        return run_training(robot, rec, out, init_from=start.net if start else None, **common,
                            progress=progress, data_progress=data_progress, budget=budget,
                            monitor=Monitor(robot), transfer=transfer,
                            extra_card={"stages": training_stages(start.card)} if start else None,
                            **card_evaluation(robot, budget))


def card_evaluation(robot: Robot, budget: TimeBudget) -> dict[str, Callable[[PinnNet], dict]]:
    """``evaluate`` and ``calibrate`` of `ctrplan.training.trainer.train` for the model card: the
    accuracy on `CARD_EVAL_CONFIGURATIONS` unseen configurations and the planner's safety margin on
    `CALIBRATION_CONFIGURATIONS` more (as scripts/calibrate_pinn.py measures it), each on fewer when
    the ``budget`` runs out (it shares what is left between them by size and records the cut)."""

    def evaluate(net: PinnNet) -> dict:
        share = CARD_EVAL_CONFIGURATIONS / (CARD_EVAL_CONFIGURATIONS + CALIBRATION_CONFIGURATIONS)
        cmp = compare(PinnBackend(robot, net), robot, n=CARD_EVAL_CONFIGURATIONS,
                      deadline=budget.phase_deadline(share))
        if len(cmp.exact) < CARD_EVAL_CONFIGURATIONS:
            budget.cut(f"evaluation: {len(cmp.exact):,} of {CARD_EVAL_CONFIGURATIONS:,} unseen "
                       f"configurations")
        return {**cmp.metrics(), "worst": worst_configurations(cmp, robot)}

    def calibrate_(net: PinnNet) -> dict:
        bound = calibrate(PinnBackend(robot, net), robot, n=CALIBRATION_CONFIGURATIONS,
                          deadline=budget.phase_deadline(1.0))
        if bound["compared"] < CALIBRATION_CONFIGURATIONS:
            budget.cut(f"calibration: {bound['compared']:,} of {CALIBRATION_CONFIGURATIONS:,} configurations")
        return bound

    return {"evaluate": evaluate, "calibrate": calibrate_}


def _report(console: Console, out: Path, result: TrainResult, budget: TimeBudget) -> None:
    """The summary on stderr: files, accuracy, planning margin, unsolved configurations, whether the
    model meets its accuracy target and what the time limit cut."""
    card = result.card
    m = card["metrics"]
    tip = m["tip_error_pct_length"]
    console.print(f"wrote {out.with_suffix('.safetensors')} and {out.with_suffix('.json')}: "
                  f"{result.steps} steps in {result.wall_time_s / 60:.1f} min (exact data "
                  f"{card['data_generation_s']:.0f} s); on {m['configurations']} unseen configurations "
                  f"(vs the robot file's Cosserat model): tube-1 tip error mean {tip['mean']:.3f} %, "
                  f"max {tip['max']:.3f} % of arc length, backbone error mean "
                  f"{m['backbone_error_pct']['mean']:.3f} %")
    if ERROR_BOUND_KEY in card:
        from ctrplan.kinematics.error_bound import region_bounds_mm
        from ctrplan.scene.objects import PlannerSettings

        coverage = PlannerSettings.surrogate_coverage
        margins = ", ".join(f"{b:.2f}" for b in region_bounds_mm(card[ERROR_BOUND_KEY], coverage))
        console.print(f"planning margin (calibrated error bound at the default coverage {coverage:g}, "
                      f"base to tip): {margins} mm")
    unsolved = card.get("unsolved_configurations", {}).get("count", 0) + m["unsolved"]["count"]
    if unsolved:
        console.print(f"note: the exact solver could not solve {unsolved} configuration(s) of the domain "
                      f"(left out of training and of every statistic; listed in the card). Check the "
                      f"domain with `ctrplan stability --robot ...`: unsolvable configurations usually lie "
                      f"where the robot snaps.")
    if budget.cuts:
        console.print(f"the time limit ({budget.limit_s / 60:g} min, the whole command) cut short: "
                      + "; ".join(budget.cuts) + f"; the command took {budget.elapsed_s():.0f} s")
    if budget.limit_s is not None and budget.elapsed_s() > OVERRUN * budget.limit_s:
        console.print(f"note: the command took {budget.elapsed_s():.0f} s, over its limit of "
                      f"{budget.limit_s:.0f} s: loading torch's optimiser, the first chunk of exact data, "
                      f"the first training step and the smallest evaluation and calibration "
                      f"({MIN_EVAL_CONFIGURATIONS} configurations each) are never cut")
    if "time_to_target" in card:
        judged = card.get("accuracy_target", {}).get("tip_mm", m["tip_error_mm"]["tube1"])
        console.print("accuracy: " + summary(card["time_to_target"], judged, budget.elapsed_s()))
        if not card.get("meets_target") and m.get("worst", {}).get("next_to_jump"):
            w = m["worst"]
            console.print(f"{w['next_to_jump']} of the {w['checked']} configurations with the largest tip "
                          f"error lie within {w['probe_step']['rotation_rad']:g} rad or "
                          f"{w['probe_step']['translation_mm']:g} mm of a jump of the exact model (its tip "
                          f"moves over {w['jump_mm']:g} mm across {w['resolution_rad']:g} rad: the robot "
                          f"snaps there); no training time makes a smooth surrogate follow a jump. Train "
                          f"on the snap-free part: `ctrplan stability --robot R.yaml --write-robot "
                          f"R_snapfree.yaml`, then `ctrplan train --robot R_snapfree.yaml`")
    if card.get("meets_target") is False:
        console.print(f"warning: {target_text(card)}: this model MISSES its accuracy target; train it longer "
                      f"(--time-limit, --steps). Planning with it warns (meets_target: false in "
                      f"{out.with_suffix('.json')}).")


def target_text(card: dict) -> str:
    """``tube-1 tip error p99.9 0.61 mm (target <= 0.5 mm), max 1.2 mm (target <= 1 mm) on 5000
    unseen configurations`` from a card's `accuracy_target`."""
    t = card["accuracy_target"]
    got = t["measured"]
    parts = [f"{k.removeprefix('tube1_tip_').removesuffix('_mm').replace('_', '.')} {got[k]:.3g} mm "
             f"(target <= {t[k]:g} mm)" for k in ACCURACY_TARGET]
    cut = t.get("judged_on") == "monitor"
    on = " (the monitor's: the time limit cut the card's evaluation)" if cut else ""
    return f"tube-1 tip error {', '.join(parts)} on {t['configurations']} unseen configurations{on}"


def _how_to_resume(console: Console, out: Path) -> None:
    """After Ctrl-C: the checkpoint to resume from and the command that does, or that there is none."""
    try:
        meta = checkpoint_meta(out)
    except InputError:
        meta = None
    if meta is None:
        console.print(f"interrupted before the first checkpoint of {out.name} (one is written every "
                      f"{CHECKPOINT_EVERY_S / 60:g} minutes of training): nothing to resume")
        return
    args = sys.argv[1:] + ([] if "--resume" in sys.argv else ["--resume"])
    console.print(f"interrupted: checkpoint {meta['file']} holds step {meta['step']:,} "
                  f"({meta['elapsed_s'] / 60:.1f} min of training); continue with: "
                  f"ctrplan {shlex.join(args)}")


def check_model_name(name: str, option: str) -> str:
    """``name`` if it is a model name (`MODEL_NAME`: letters, digits, ``_`` and ``-``, at most 100,
    starting with a letter or digit); otherwise an `InputError` naming ``option``. A name is never a
    path (no separators, no ``..``), so a model is never written outside its folder, and has no dot
    (NAME.safetensors, NAME.json and NAME.ckpt.* are made from it by suffix)."""
    if not MODEL_NAME.fullmatch(name):
        raise InputError(f"{option}: {name!r} is not a model name (letters, digits, '_' and '-', at most "
                         f"100 characters: no path, no dot); the folder is --out-dir")
    return name


def training_fraction(step: int, steps: int, time_s: float, limit_s: float | None) -> float:
    """How much of the run is done: steps of the budget, or time of the limit, whichever ends it."""
    return min(1.0, max(step / steps, time_s / limit_s if limit_s else 0.0))


def progress_text(step: int, steps: int, time_s: float, limit_s: float | None) -> str:
    """``1200/40000 steps``, or with a time limit ``1200 steps in 3:06 of 30:00`` (minutes:seconds
    of training; the step budget is then only an upper bound)."""
    if limit_s is None:
        return f"{step}/{steps} steps"
    clock = [f"{int(t // 60)}:{int(t % 60):02d}" for t in (time_s, limit_s)]
    return f"{step} steps in {clock[0]} of {clock[1]}"


def _measured_split(path: Path, robot: Robot, shots: int | None, heldout: float | None,
                    heldout_last: float | None) -> FewShot:
    """Read ``path`` and take the fine-tuning shots (all training rows if ``shots`` is None), with
    the held-out rows of `ctrplan diagnose` (its options and default seed)."""
    from ctrplan.calibration.data import read_measured
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
