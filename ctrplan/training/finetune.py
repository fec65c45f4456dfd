"""Few-shot fine-tuning of a trained PINN on measured tips (paper stage b), judged on held-out rows
against the nominal Cosserat model, the extended Cosserat model that `diagnose` fits on the same
shots, and the PINN it started from.

`finetune` runs `diagnose` on the shots only (its own candidate selection holds out part of them),
so neither the extended model nor the fine-tuned PINN sees a held-out row.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from ctrplan.calibration.diagnosis import DiagnoseOptions, Diagnosis, diagnose, error_stats
from ctrplan.calibration.fit import Evaluator
from ctrplan.kinematics.model_file import file_sha256
from ctrplan.kinematics.pinn import PinnBackend, PinnNet
from ctrplan.robot import Robot
from ctrplan.training.evaluate import compare
from ctrplan.training.fewshot import FewShot, check_trainable, model_joints, observations
from ctrplan.training.losses import tube_tips
from ctrplan.training.physics import TubeTensors
from ctrplan.training.trainer import Recipe, TrainResult, train

#: Rows of the comparison table: key -> label.
MODELS = {"nominal": "nominal Cosserat", "extended": "extended Cosserat", "pinn_start": "PINN before",
          "pinn_finetuned": "PINN fine-tuned"}


def cosserat_tips(robot: Robot, fs: FewShot, rows: np.ndarray) -> np.ndarray:
    """Tips (R, T, 3) mm, tracker frame, of the Cosserat model of ``robot`` (its calibration applied);
    NaN where it does not converge."""
    pred = Evaluator(fs.data.q[rows], fs.direction[rows]).predict([robot])[0]
    return np.where(pred.converged[:, None, None], pred.tips_mm, np.nan)


def pinn_tips(net: PinnNet, robot: Robot, fs: FewShot, rows: np.ndarray) -> np.ndarray:
    """Tips (R, 3, 3) mm, measurement frame, of a PINN for ``robot`` (its calibration applied)."""
    q = torch.as_tensor(model_joints(robot, fs, rows), dtype=torch.float32)
    with torch.no_grad():
        tips = tube_tips(net.cpu(), q, TubeTensors.from_robot(robot)).double().numpy()
    return robot.calibration.to_tracker_frame(tips)


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


def finetune(fs: FewShot, start: PinnBackend, out: Path, recipe: Recipe, *, init_model: str,
             diagnose_options: DiagnoseOptions | None = None, **train_kwargs) -> TrainResult:
    """Fine-tune the PINN ``start`` (loaded as ``init_model``) on the shots of ``fs`` (data
    read from a file) with ``recipe``; write ``out`` with a card that records the data file (name,
    SHA-256), the split and the held-out table (``metrics.measured_heldout``). ``train_kwargs`` go to
    `trainer.train` (seed, device, time_limit_s, progress, ...)."""
    robot = start.robot
    check_trainable(robot)
    diag = diagnose(fs.data.subset(fs.shots), robot, diagnose_options, direction=fs.direction[fs.shots])
    held = fs.heldout
    fixed = {"nominal": cosserat_tips(robot, fs, held),
             "extended": cosserat_tips(diag.extended_robot, fs, held),
             "pinn_start": pinn_tips(start.net, robot, fs, held)}

    def evaluate(net: PinnNet) -> dict:
        table = heldout_table(fs, robot, {**fixed, "pinn_finetuned": pinn_tips(net, robot, fs, held)})
        return {**compare(PinnBackend(robot, net), robot).metrics(), "measured_heldout": table}

    card = {"finetuned_on": {**_data_record(fs, diag), "init_model": init_model,
                             "init_weights_sha256": start.card.get("weights_sha256")},
            "note": f"fine-tuned from {init_model} on measured tips (paper stage b); 'metrics' compares "
                    f"it with the exact model of the robot file, 'metrics.measured_heldout' with the "
                    f"measurements"}
    return train(robot, recipe, out, init_from=start.net, observations=observations(robot, fs),
                 evaluate=evaluate, extra_card=card, **train_kwargs)


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
