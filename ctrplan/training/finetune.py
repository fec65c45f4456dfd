"""Few-shot fine-tuning of a trained PINN on measured tips (paper stage b), starting from the best
model of the robot the data supports, judged on held-out rows.

Stages (each timed; the card and the printout say how long each took):

1. **diagnose** the shots (`ctrplan.calibration.diagnose`, its own candidate selection holding out
   part of them): the extended robot -- mechanics (curvatures, stiffnesses, offsets, loads,
   transmission lengths) and calibration (registration, sensor offset, backlash, windup).
2. **adapt** the PINN to the extended mechanics where they differ from the model's robot: the default
   recipe's supervised training on exact solutions of the extended mechanics, started from the given
   PINN and given `ADAPT_MINUTES` (hard-example mining included). This PINN is as good a model of the
   extended robot as the start PINN was of its own.
3. **learn from the shots** what the physics does not explain: the network (with absolute-angle
   inputs added at zero weight, so it can learn what breaks the rotation symmetry -- a tracker offset
   fixed in the base frame, an encoder error) is fitted to the shots through the extended robot's
   calibration, with exact solutions of the extended mechanics (dense supervision) and the ODE and
   boundary residuals kept in the loss, so it stays a model of a robot; its error against the exact
   mechanics is reported with the card's metrics.

Neither the extended model nor the PINN sees a held-out row. The held-out table compares the nominal
and extended Cosserat models with the PINN before, adapted and fine-tuned.
"""

from __future__ import annotations

import copy
import time
from pathlib import Path

import numpy as np
import torch

from ctrplan.calibration.diagnosis import DiagnoseOptions, Diagnosis, diagnose, error_stats
from ctrplan.calibration.fit import Evaluator
from ctrplan.kinematics.model_file import file_sha256, write_card_field
from ctrplan.kinematics.pinn import PinnBackend, PinnNet
from ctrplan.robot import Robot
from ctrplan.training.evaluate import compare
from ctrplan.training.fewshot import FewShot, model_joints, observations
from ctrplan.training.physics import quat_to_matrix
from ctrplan.training.trainer import Recipe, TrainResult, get_recipe, remove_checkpoint, train

#: Minutes of the adaptation stage (the default recipe on the extended mechanics).
ADAPT_MINUTES = 4.0

#: Rows of the comparison table: key -> label.
MODELS = {"nominal": "nominal Cosserat", "extended": "extended Cosserat", "pinn_start": "PINN before",
          "pinn_adapted": "PINN adapted", "pinn_finetuned": "PINN fine-tuned"}


def cosserat_tips(robot: Robot, fs: FewShot, rows: np.ndarray) -> np.ndarray:
    """Tips (R, T, 3) mm, tracker frame, of the Cosserat model of ``robot`` (its calibration applied);
    NaN where it does not converge."""
    pred = Evaluator(fs.data.q[rows], fs.direction[rows]).predict([robot])[0]
    return np.where(pred.converged[:, None, None], pred.tips_mm, np.nan)


def pinn_tips(net: PinnNet, robot: Robot, fs: FewShot, rows: np.ndarray) -> np.ndarray:
    """Tips (R, N, 3) mm, tracker frame, of a PINN for ``robot`` (its calibration applied: joints,
    sensor offset through the predicted tip frame, registration)."""
    q = torch.as_tensor(model_joints(robot, fs, rows), dtype=torch.float32)
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
            "scope": "held-out rows, tip of tube 1 (per_tube: every measured tube)", "models": models}


def table_text(table: dict) -> str:
    """The comparison table as aligned text lines (tube-1 tip, held-out rows)."""
    lines = [f"held-out tip error of tube 1 on {table['rows']} rows:",
             f"  {'model':<20s} {'mean mm':>8s} {'median':>8s} {'p95':>8s} {'% length':>9s}"]
    lines += [f"  {m['model']:<20s} {m['mean_mm']:8.3f} {m['median_mm']:8.3f} {m['p95_mm']:8.3f} "
              f"{m['mean_pct_length']:8.3f} %" for m in table["models"]]
    return "\n".join(lines)


def adapt(start: PinnBackend, mechanics: Robot, out: Path, minutes: float = ADAPT_MINUTES,
          **train_kwargs) -> PinnNet:
    """Stage 2: the start PINN trained on exact solutions of ``mechanics`` (the default recipe for
    ``minutes``, continuing its weights at a lower learning rate); written to ``out``. The start
    network itself when the mechanics are its robot's."""
    if mechanics.fingerprint == start.robot.mechanics.fingerprint or minutes <= 0:
        return start.net
    recipe = get_recipe("fast", lr=5e-4, warmup_steps=100)
    net = copy.deepcopy(start.net)
    if not mechanics.loads.axisymmetric:     # gravity across the robot breaks the rotation symmetry
        net = net.with_absolute_angles(mechanics)
    net = train(mechanics, recipe, out, init_from=net, time_limit_s=minutes * 60, **train_kwargs,
                extra_card={"note": f"the extended mechanics {mechanics.name!r} of a diagnosis"}).net
    remove_checkpoint(out)
    return net


def finetune(fs: FewShot, start: PinnBackend, out: Path, recipe: Recipe, *, init_model: str,
             diagnose_options: DiagnoseOptions | None = None, adapt_minutes: float = ADAPT_MINUTES,
             log=None, **train_kwargs) -> TrainResult:
    """Fine-tune the PINN ``start`` (loaded as ``init_model``) on the shots of ``fs`` (data read from a
    file) in the three stages of this module; write ``out`` (a model of the extended robot, whose
    mechanics are written beside it as ``out.robot.yaml``, the robot file to plan with) and
    ``out_adapted`` (stage 2). The card records the data file (name, SHA-256), the split, every
    stage's time and the held-out table (``metrics.measured_heldout``). ``log(message)`` reports the
    stages; ``train_kwargs`` go to `trainer.train` (seed, device, time_limit_s, progress, ...)."""
    say = log or (lambda _msg: None)
    seconds: dict[str, float] = {}
    t0 = time.perf_counter()
    say(f"stage 1/3: diagnose on {len(fs.shots)} shots")
    diag = diagnose(fs.data.subset(fs.shots), start.robot, diagnose_options, direction=fs.direction[fs.shots])
    ext = diag.extended_robot
    held = fs.heldout
    fixed = {"nominal": cosserat_tips(start.robot, fs, held), "extended": cosserat_tips(ext, fs, held),
             "pinn_start": pinn_tips(start.net, start.robot, fs, held)}
    seconds["diagnose_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    say(f"stage 2/3: adapt the PINN to the extended mechanics (named: {diag.cause})")
    adapt_kwargs = {k: v for k, v in train_kwargs.items() if k in ("seed", "device", "progress")}
    adapted = adapt(start, ext.mechanics, out.with_name(out.name + "_adapted"), adapt_minutes, **adapt_kwargs)
    fixed["pinn_adapted"] = pinn_tips(adapted, ext, fs, held)
    seconds["adapt_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    say("stage 3/3: learn from the shots what the physics does not explain")

    def evaluate(net: PinnNet) -> dict:
        table = heldout_table(fs, ext, {**fixed, "pinn_finetuned": pinn_tips(net, ext, fs, held)})
        exact = compare(PinnBackend(ext.mechanics, net), ext.mechanics).metrics()
        return {**exact, "measured_heldout": table}

    card = {"finetuned_on": {**_data_record(fs, diag), "init_model": init_model,
                             "init_weights_sha256": start.card.get("weights_sha256")},
            "note": f"fine-tuned from {init_model} on measured tips (paper stage b) as a model of the "
                    f"extended robot (its mechanics: {out.name}.robot.yaml); 'metrics' compares it with the "
                    f"exact model of that robot's mechanics, 'metrics.measured_heldout' with the "
                    f"measurements"}
    result = train(ext, recipe, out, init_from=adapted.with_absolute_angles(ext),
                   observations=observations(ext, fs), evaluate=evaluate, extra_card=card, **train_kwargs)
    seconds["learn_s"] = time.perf_counter() - t0
    ext.mechanics.save(out.with_suffix(".robot.yaml"),
                       comment=f"the extended mechanics of {out.name} (ctrplan train --measured): plan with "
                               f"it; the measurement side is in the model card")
    record = {**result.card["finetuned_on"], "stage_seconds": {k: round(v, 1) for k, v in seconds.items()}}
    write_card_field(out.with_suffix(".safetensors"), "finetuned_on", record)
    result.card["finetuned_on"] = record
    return result


def _data_record(fs: FewShot, diag: Diagnosis) -> dict:
    d = fs.data
    j = diag.to_json()
    return {
        "file": Path(d.source).name,
        "sha256": file_sha256(Path(d.source)),
        "format": d.format,
        "rows": len(d),
        "tubes_measured": [t + 1 for t in d.tubes],
        "shots": int(len(fs.shots)),
        "train_rows": fs.train_rows,
        "heldout_rows": int(len(fs.heldout)),
        "heldout_fraction": fs.heldout_fraction,
        "heldout_last": fs.heldout_last,
        "split_seed": fs.seed,
        "outside_domain_rows": [int(v) for v in d.lines[fs.excluded]],
        "extended_model": {"cause": j["cause"], "causes": j["causes"], "parameters": j["parameters"],
                           "diagnose_seconds": j["seconds"]},
    }
