"""Few-shot fine-tuning of a trained PINN on measured tips (paper stage b), starting from the best
model of the robot the data supports, judged on held-out rows.

Stages (each timed; the card and the printout say how long each took):

1. **diagnose** the shots (`ctrplan.calibration.diagnose`, its own candidate selection holding out
   part of them): the extended robot -- mechanics (curvatures, stiffnesses, offsets, loads,
   transmission lengths) and calibration (registration, sensor offset, backlash, windup) -- or, when
   the validation shots say it predicts better, a candidate the diagnosis fitted with one cause more,
   one less or one swapped, the opt-in causes (`follower_force`) fitted for it as one more cause of the
   named set and of its best subset (`best_predictor`, `FEWSHOT_DIAGNOSIS`: naming is a claim about
   the robot, the few-shot model wants the best predictor).
2. **adapt** the PINN to the extended mechanics where they differ from the model's robot: the default
   recipe's supervised training on exact solutions of the extended mechanics, started from the given
   PINN, for `ADAPT_STEPS` optimiser steps (hard-example mining included; a step budget, not minutes,
   so that a loaded machine takes longer instead of stopping early). This PINN is about as good a model
   of the extended robot as the start PINN was of its own (measured: `ADAPT_STEPS`).
3. **learn from the shots** what the physics does not explain: first the lag of the joints after a
   reversal (`ctrplan.training.lag`: the cause library's `friction`, Maxwell-slip elements on the
   travel of each joint, fitted on all the fit shots on top of the extended robot), kept when the
   fit shots support it as `diagnose` requires of a cause it names (every fitted element resolved,
   plausible, off its bounds: `ctrplan.calibration.selection.unsupported`) and it lowers the
   validation error; then
   the network (with absolute-angle inputs added at zero weight, so it can learn what breaks the
   rotation symmetry -- a tracker offset fixed in the base frame, an encoder error) is fitted to the
   shots through the extended robot's calibration, with exact solutions of the extended mechanics
   (dense supervision) and the ODE and boundary residuals kept in the loss, so it stays a model of a
   robot; its error against the exact mechanics is reported with the card's metrics.

The last `VALIDATION_FRACTION` of the shots (acquisition order) are fitted by no stage: the PINN
before, adapted and fine-tuned are compared on them and the best one is written (**never a model worse
on them than the one the user started from**); the card and the printout say which was kept. Neither
the extended model nor the PINN sees a held-out row. The held-out table compares the nominal and
extended Cosserat models (with the learned lag) with the PINN before, adapted and fine-tuned; the
held-out rows are predicted as one sequence by themselves, as `ctrplan fk` predicts a file of them with
the robot file written beside the model.
"""

from __future__ import annotations

import copy
import dataclasses
import time
from pathlib import Path

import numpy as np
import torch

from ctrplan.calibration.diagnosis import Diagnosis, diagnose, error_stats
from ctrplan.calibration.options import DiagnoseOptions
from ctrplan.calibration.selection import unsupported
from ctrplan.kinematics.cosserat import CosseratBackend
from ctrplan.kinematics.model_file import file_sha256, read_card, save_model, write_card_field
from ctrplan.kinematics.pinn import PinnBackend
from ctrplan.kinematics.pinn_net import PinnNet
from ctrplan.model.causes import CAUSES, DEFAULT_CAUSES
from ctrplan.model.causes.base import make_effect
from ctrplan.model.robot import Robot
from ctrplan.training.checkpoints import remove_checkpoint
from ctrplan.training.evaluate import compare
from ctrplan.training.fewshot import FewShot, mechanics_joints, model_joints, observations, validation_split
from ctrplan.training.lag import fit_friction
from ctrplan.training.physics import quat_to_matrix
from ctrplan.training.recipes import ADAPT_STEPS, Recipe, get_recipe
from ctrplan.training.trainer import TrainResult, train

#: Rows of the comparison table: key -> label.
MODELS = {"nominal": "nominal Cosserat", "extended": "extended Cosserat",
          "extended_lag": "extended + learned friction", "pinn_start": "PINN before",
          "pinn_adapted": "PINN adapted", "pinn_finetuned": "PINN fine-tuned"}
#: The diagnosis of the shots also fits the causes `diagnose` tries only when named (`follower_force`)
#: as one more cause of the set it names and of that set's best subset: naming stays `diagnose`'s claim,
#: the few-shot model wants the best predictor, and the validation shots choose (`best_predictor`).
FEWSHOT_DIAGNOSIS = DiagnoseOptions(also_fit=tuple(c for c in CAUSES if c not in DEFAULT_CAUSES))
#: The PINN stages one of which is written as the model (the best on the validation shots).
STAGES = ("pinn_start", "pinn_adapted", "pinn_finetuned")


def cosserat_tips(robot: Robot, fs: FewShot, rows: np.ndarray, alone: bool = False) -> np.ndarray:
    """Tips (R, T, 3) mm, tracker frame, of the Cosserat model of ``robot`` (its calibration applied;
    ``alone``: the rows as a sequence by themselves, see `mechanics_joints`); NaN where it does not
    converge."""
    bb = CosseratBackend(robot.mechanics).forward(mechanics_joints(robot, fs, rows, alone), points=2,
                                                  check=False)
    tips = robot.calibration.tracked_tips(bb.tips_mm, bb.rotations[:, -1])
    return np.where(bb.converged[:, None, None], tips, np.nan)


def pinn_tips(net: PinnNet, robot: Robot, fs: FewShot, rows: np.ndarray, alone: bool = False) -> np.ndarray:
    """Tips (R, N, 3) mm, tracker frame, of a PINN for ``robot`` (its calibration applied: joints,
    sensor offset through the predicted tip frame, registration)."""
    q = torch.as_tensor(model_joints(robot, fs, rows, alone), dtype=torch.float32)
    n, net = robot.n_tubes, net.cpu()
    with torch.no_grad():
        ends = q[:, :n] + net.lengths
        x = net((ends / ends[:, :1]).T.reshape(-1), q.repeat(n, 1)).view(n, len(q), -1)
        tips = x[:, :, net.i_p:net.i_p + 3].transpose(0, 1).double().numpy()
        rotation = quat_to_matrix(x[0, :, -4:]).double().numpy()
    return robot.calibration.tracked_tips(tips, rotation)


def heldout_table(fs: FewShot, robot: Robot, predictions: dict[str, np.ndarray]) -> dict:
    """Held-out tip error of each model's ``predictions`` (key of `MODELS` -> tips (H, 3, 3) mm):
    mean/median/p95/max mm and mean % of arc length of tube 1, and per measured tube. Rows some model
    cannot predict (unsolved) are left out for all models."""
    rows = fs.heldout
    measured = fs.data.tips_mm[rows]
    lengths = robot.tube_ends_mm(fs.data.q[rows])
    err = {k: np.linalg.norm(measured - p, axis=-1) for k, p in predictions.items()}   # (H, 3)
    ok = np.all([np.isfinite(e[:, 0]) for e in err.values()], axis=0)
    models = []
    for key, e in err.items():
        e, L = e[ok], lengths[ok]
        per_tube = [dict(tube=t + 1, **error_stats(e[:, t], L[:, t])) for t in fs.data.tubes]
        models.append({"key": key, "model": MODELS[key], **error_stats(e[:, 0], L[:, 0]),
                       "per_tube": per_tube})
    return {"rows": int(ok.sum()), "unsolved_rows": [int(v) for v in fs.data.lines[rows[~ok]]],
            "scope": "held-out rows, tip of tube 1 (per_tube: every measured tube); the rows predicted "
                     "as one sequence by themselves, as `ctrplan fk` predicts a file of them",
            "models": models}


def table_text(table: dict) -> str:
    """The comparison table as aligned text lines (tube-1 tip, held-out rows)."""
    lines = [f"held-out tip error of tube 1 on {table['rows']} rows:",
             f"  {'model':<24s} {'mean mm':>8s} {'median':>8s} {'p95':>8s} {'% length':>9s}"]
    lines += [f"  {m['model']:<24s} {m['mean_mm']:8.3f} {m['median_mm']:8.3f} {m['p95_mm']:8.3f} "
              f"{m['mean_pct_length']:8.3f} %" for m in table["models"]]
    return "\n".join(lines)


def kept_text(kept: dict) -> str:
    """Which stage was written as the model, and why (the card's ``finetuned_on.kept``)."""
    errors = ", ".join(f"{MODELS[k]} {v:.3f}" for k, v in kept["validation_mean_mm"].items())
    text = (f"kept: {MODELS[kept['stage']]} (tube-1 tip error on {kept['validation_rows']} validation "
            f"shots, mean mm: {errors})")
    errs = kept["validation_mean_mm"]
    if kept["stage"] != "pinn_finetuned" and errs:
        worse = "worse" if errs["pinn_finetuned"] > errs[kept["stage"]] else "no better"
        text += (f"; the fine-tuned PINN was {worse} there than the {MODELS[kept['stage']]}, so the "
                 f"{MODELS[kept['stage']]} is written instead")
    return text


def adapt(start: PinnBackend, mechanics: Robot, out: Path, steps: int = ADAPT_STEPS,
          **train_kwargs) -> PinnNet:
    """Stage 2: the start PINN trained on exact solutions of ``mechanics`` (the default recipe for
    ``steps`` Adam steps, however long they take, continuing its weights at a lower learning rate);
    written to ``out`` either way (the start network itself, noted in its card, when the mechanics are
    its robot's or ``steps`` is 0)."""
    if mechanics.fingerprint == start.robot.mechanics.fingerprint or steps <= 0:
        why = "the mechanics are the start model's" if steps > 0 else "--adapt-steps 0"
        save_model(start.net, mechanics, out, {"note": f"the start network unchanged ({why})",
                                              "stages": start.card.get("stages", [])})
        return start.net
    recipe = dataclasses.replace(get_recipe("fast", lr=5e-4, warmup_steps=min(100, steps // 4), steps=steps),
                                 minutes=None)   # no time limit: the steps are the budget
    net = copy.deepcopy(start.net)
    if not mechanics.loads.axisymmetric:     # gravity across the robot breaks the rotation symmetry
        net = net.with_absolute_angles(mechanics)
    net = train(mechanics, recipe, out, init_from=net, **train_kwargs,
                extra_card={"note": f"the extended mechanics {mechanics.name!r} of a diagnosis"}).net
    remove_checkpoint(out)
    return net


def tube1_error_mm(tips: np.ndarray, fs: FewShot, rows: np.ndarray) -> float:
    """Mean tube-1 tip error (mm) of predicted tips (R, T, 3) on ``rows`` (NaN rows left out)."""
    return float(np.nanmean(np.linalg.norm(tips[:, 0] - fs.data.tips_mm[rows, 0], axis=1)))


def best_predictor(diag: Diagnosis, fs: FewShot, val: np.ndarray, say) -> tuple[Robot, dict]:
    """The extended robot of ``diag``, or a neighbour of it among the candidates the diagnosis fitted
    -- one cause more, one less, or one swapped for another, each supported by the rows as `diagnose`
    requires of what it names (`unsupported`) -- whichever predicts the validation shots ``val`` best;
    and its record. `diagnose` names causes only when they are significant and each gains at least
    ``min_gain`` (a claim about the robot, judged on its own split of the fit shots); a few-shot model
    wants the best predictor, so the shots no stage fitted choose among the close contenders."""
    ext = diag.extended_robot
    named = set(diag.causes)

    def near(causes: set[str]) -> bool:   # one cause more, one less, or one swapped
        return causes != named and len(causes - named) <= 1 and len(named - causes) <= 1

    contenders = [c for c in diag.selection.candidates if near(set(c.causes)) and not unsupported(c.fit)]
    label = "+".join(diag.causes) or "nothing named"
    if not contenders or not len(val):
        return ext, {"kept": label, "validation_mean_mm": {}}
    errors = {label: tube1_error_mm(cosserat_tips(ext, fs, val), fs, val)}
    robots = {label: ext}
    for c in contenders:
        errors[c.name] = tube1_error_mm(cosserat_tips(c.fit.robot, fs, val), fs, val)
        robots[c.name] = c.fit.robot.with_changes(name=f"{diag.robot.name}-{c.name}")
    best = min(errors, key=lambda k: (errors[k], k != label))
    say("predictor: " + ", ".join(f"{k} {v:.3f}" for k, v in errors.items())
        + f" mm on the {len(val)} validation shots; kept {best}"
        + ("" if best == label else " (not the set diagnose named: the better predictor)"))
    return robots[best], {"kept": best, "validation_mean_mm": {k: round(v, 4) for k, v in errors.items()}}


def learn_lag(ext: Robot, fs: FewShot, fit: np.ndarray, val: np.ndarray, say) -> tuple[Robot, dict]:
    """The extended robot with the `friction` of its joints fitted on the ``fit`` shots
    (`ctrplan.training.lag`) when the shots support it as `diagnose` requires of a cause it names
    (`unsupported`) and it lowers the extended Cosserat model's error on the validation shots ``val``;
    its record (the fitted friction, in its robot-file form)."""
    learned = fit_friction(ext, fs.data.q[fit], fs.motion.subset(fit), fs.data.tubes, fs.data.tips_mm[fit])
    if learned is None or not len(val):
        say("learned lag: none (no joint reverses in the shots, or no validation shots)")
        return ext, {"kept": False, "reason": "no joint reverses in the shots, or no validation shots"}
    model, doubts = learned.robot, unsupported(learned)
    before = tube1_error_mm(cosserat_tips(ext, fs, val), fs, val)
    after = tube1_error_mm(cosserat_tips(model, fs, val), fs, val)
    keep = after < before and not doubts
    say(f"learned friction of the joints (Maxwell-slip elements on the travel): validation mean "
        f"{before:.3f} -> {after:.3f} mm, {'kept' if keep else 'not kept'}"
        + (f" (the shots do not support it: {', '.join(doubts)})" if doubts else ""))
    friction = make_effect("friction")
    record = {"kept": bool(keep), "friction": friction.write(friction.values(model)),
              "validation_mean_mm": {"without": round(before, 4), "with": round(after, 4)}}
    if doubts:
        record["unsupported"] = doubts
    return (model if keep else ext), record


def choose_stage(fs: FewShot, val: np.ndarray, stages: dict[str, tuple[PinnNet, Robot]]) -> dict:
    """The stage (key of `STAGES`) with the lowest mean tube-1 tip error on the validation shots (the
    earliest of equals: the start model unless another one is better); without validation shots the
    fine-tuned one."""
    if not len(val):
        return {"stage": "pinn_finetuned", "validation_rows": 0, "validation_mean_mm": {}}
    errors = {k: round(tube1_error_mm(pinn_tips(net, robot, fs, val), fs, val), 4)
              for k, (net, robot) in stages.items()}
    return {"stage": min(errors, key=lambda k: (errors[k], STAGES.index(k))), "validation_rows": len(val),
            "validation_mean_mm": errors}


def finetune(fs: FewShot, start: PinnBackend, out: Path, recipe: Recipe, *, init_model: str,
             diagnose_options: DiagnoseOptions | None = None, adapt_steps: int = ADAPT_STEPS,
             log=None, **train_kwargs) -> TrainResult:
    """Fine-tune the PINN ``start`` (loaded as ``init_model``) on the shots of ``fs`` (data read from a
    file) in the three stages of this module; write ``out`` (the stage best on the validation shots),
    ``out.robot.yaml`` (its robot: mechanics and calibration, what `fk` needs to predict the tracker),
    ``out.mechanics.robot.yaml`` (its mechanics: plan with it) and ``out_adapted`` (stage 2). The card
    records the data file (name, SHA-256), the split, every stage's time, the learned lag, the stage
    kept (``finetuned_on.kept``) and the held-out table (``metrics.measured_heldout``). ``log(message)``
    reports the stages; ``train_kwargs`` go to `trainer.train` (seed, device, time_limit_s, ...)."""
    say = log or (lambda _msg: None)
    seconds: dict[str, float] = {}
    fit, val = validation_split(fs)
    t0 = time.perf_counter()
    say(f"stage 1/3: diagnose on {len(fit)} shots (the last {len(val)} shots validate the stages)")
    diag = diagnose(fs.data.subset(fit), start.robot, diagnose_options or FEWSHOT_DIAGNOSIS,
                    motion=fs.motion.subset(fit))
    ext, predictor = best_predictor(diag, fs, val, say)
    seconds["diagnose_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    say(f"stage 2/3: adapt the PINN to the extended mechanics ({predictor['kept']})")
    adapt_kwargs = {k: v for k, v in train_kwargs.items()
                    if k in ("seed", "device", "progress", "mining_worker")}
    adapted = adapt(start, ext.mechanics, out.with_name(out.name + "_adapted"), adapt_steps, **adapt_kwargs)
    seconds["adapt_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    say("stage 3/3: learn from the shots what the physics does not explain")
    model, lag_record = learn_lag(ext, fs, fit, val, say)
    _save_robots(model, out.with_name(out.name + "_adapted"))
    held = fs.heldout
    fixed = {"nominal": cosserat_tips(start.robot, fs, held, True),
             "extended": cosserat_tips(ext, fs, held, True),
             "extended_lag": cosserat_tips(model, fs, held, True),
             "pinn_start": pinn_tips(start.net, start.robot, fs, held, True),
             "pinn_adapted": pinn_tips(adapted, model, fs, held, True)}

    def evaluate(net: PinnNet) -> dict:
        table = heldout_table(fs, ext, {**fixed, "pinn_finetuned": pinn_tips(net, model, fs, held, True)})
        exact = compare(PinnBackend(model.mechanics, net), model.mechanics).metrics()
        return {**exact, "measured_heldout": table}

    card = {"finetuned_on": {**_data_record(fs, diag, fit, val), "predictor": predictor,
                             "learned_lag": lag_record,
                             "init_model": init_model,
                             "init_weights_sha256": start.card.get("weights_sha256")},
            "note": f"fine-tuned from {init_model} on measured tips (paper stage b) as a model of the "
                    f"extended robot ({out.name}.robot.yaml; its mechanics: "
                    f"{out.name}.mechanics.robot.yaml); "
                    f"'metrics' compares it with the exact model of those mechanics, "
                    f"'metrics.measured_heldout' with the measurements"}
    result = train(model, recipe, out, init_from=adapted.with_absolute_angles(model),
                   observations=observations(model, fs, fit), evaluate=evaluate, extra_card=card,
                   **train_kwargs)
    seconds["learn_s"] = time.perf_counter() - t0
    stages = {"pinn_start": (start.net, start.robot), "pinn_adapted": (adapted, model),
              "pinn_finetuned": (result.net, model)}
    kept = choose_stage(fs, val, stages)
    say(kept_text(kept))
    record = {**result.card["finetuned_on"], "stage_seconds": {k: round(v, 1) for k, v in seconds.items()},
              "kept": kept}
    return _write_kept(result, out, stages[kept["stage"]], record)


def _save_robots(robot: Robot, out: Path) -> None:
    """``out.robot.yaml`` (the robot, calibration included) and ``out.mechanics.robot.yaml`` (its
    mechanics, what `plan` takes) beside the model ``out``."""
    robot.save(out.with_suffix(".robot.yaml"),
               comment=f"the robot of {out.name} as the measurements see it (ctrplan train --measured): "
                       f"`fk`/`shape` with --model {out.name} predict the tracker; plan with "
                       f"{out.name}.mechanics.robot.yaml")
    robot.mechanics.save(out.with_suffix(".mechanics.robot.yaml"),
                         comment=f"the mechanics of {out.name} (ctrplan train --measured): plan with it")


def _write_kept(result: TrainResult, out: Path, kept: tuple[PinnNet, Robot], record: dict) -> TrainResult:
    """Write the kept stage's network as ``out`` (the fine-tuned one is there already) with the card of
    the run, its robot files beside it; the card's ``finetuned_on`` is ``record``."""
    net, robot = kept
    card = {**result.card, "finetuned_on": record}
    if net is not result.net:
        table = card["metrics"]["measured_heldout"]
        card["metrics"] = {**compare(PinnBackend(robot.mechanics, net), robot.mechanics).metrics(),
                           "measured_heldout": table}
        save_model(net, robot, out, card)
        card = read_card(out.with_suffix(".safetensors"))
    else:
        write_card_field(out.with_suffix(".safetensors"), "finetuned_on", record)
    _save_robots(robot, out)
    return TrainResult(net=net, steps=result.steps, wall_time_s=result.wall_time_s, history=result.history,
                       card=card)


def _data_record(fs: FewShot, diag: Diagnosis, fit: np.ndarray, val: np.ndarray) -> dict:
    d = fs.data
    j = diag.to_json()
    return {
        "file": Path(d.source).name,
        "sha256": file_sha256(Path(d.source)),
        "format": d.format,
        "rows": len(d),
        "tubes_measured": [t + 1 for t in d.tubes],
        "shots": int(len(fs.shots)),
        "fit_shots": int(len(fit)),
        "validation_shots": int(len(val)),
        "train_rows": fs.train_rows,
        "heldout_rows": int(len(fs.heldout)),
        "heldout_fraction": fs.heldout_fraction,
        "heldout_last": fs.heldout_last,
        "split_seed": fs.seed,
        "outside_domain_rows": [int(v) for v in d.lines[fs.excluded]],
        "extended_model": {"cause": j["cause"], "causes": j["causes"], "parameters": j["parameters"],
                           "diagnose_seconds": j["seconds"]},
    }
