"""Few-shot fine-tuning on the real-like lab (`tests/independent/lab.real_like`), measured end to end
as a user would: `ctrplan train --measured` on the first 70 % of the rows, then `ctrplan fk --robot
NAME.robot.yaml --model NAME` on the held-out last 30 %, compared with the table `train` printed.

    python scripts/fewshot_lab.py OUT_DIR [--seed S] [--shots N] [-- extra train args]

Prints one JSON document: the stage table of `train` (held-out tail, tube-1 tip, mean/p95 mm), the fk
errors of the written model (PINN and, for the extended Cosserat, the written robot file) and the
largest difference between the tips `train` evaluated and the ones `fk` writes.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

HELDOUT_LAST = 0.3


def _ctrplan(args: list[str]) -> str:
    from ctrplan.cli import main

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        rc = main(args)
    if rc != 0:
        raise SystemExit(f"ctrplan {' '.join(args)} exited {rc}")
    return out.getvalue()


def _fk(configs: Path, robot: Path, model: Path | None, out: Path) -> np.ndarray:
    """Tube-1 tips (R, 3) mm that `ctrplan fk` writes for ``configs``."""
    args = ["fk", str(configs), "--robot", str(robot), "-o", str(out)]
    if model is not None:
        args += ["--backend", "pinn", "--model", str(model)]
    _ctrplan(args)
    table = np.genfromtxt(out, delimiter=",", names=True)
    return np.column_stack([table["tip1_x"], table["tip1_y"], table["tip1_z"]])


def _stats(err: np.ndarray) -> dict:
    return {"mean_mm": round(float(np.mean(err)), 3), "p95_mm": round(float(np.percentile(err, 95)), 3)}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("out", type=Path)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--shots", type=int, default=500)
    parser.add_argument("extra", nargs="*")
    ns = parser.parse_args()
    from tests.independent import lab

    ns.out.mkdir(parents=True, exist_ok=True)
    data = lab.real_like(seed=ns.seed)
    csv = ns.out / "measured.csv"
    data.write_csv(csv, tubes=(0,))
    n = len(data.q)
    tail = np.arange(n - int(round(HELDOUT_LAST * n)), n)
    configs = ns.out / "heldout_joints.csv"
    np.savetxt(configs, data.q[tail], delimiter=",", header="beta1,beta2,beta3,alpha1,alpha2,alpha3",
               comments="", fmt="%.9g")
    t0 = time.perf_counter()
    card = json.loads(_ctrplan(["train", "--measured", str(csv), "--shots", str(ns.shots), "--heldout-last",
                                str(HELDOUT_LAST), "--out-dir", str(ns.out), "--name", "ft", "--json",
                                *ns.extra]))
    wall = time.perf_counter() - t0
    measured = data.tips_mm[tail, 0]
    model = ns.out / "ft.safetensors"
    fk_pinn = _fk(configs, ns.out / "ft.robot.yaml", model, ns.out / "fk_pinn.csv")
    table = card["metrics"]["measured_heldout"]
    report = {"rows": n, "heldout_rows": len(tail), "train_wall_s": round(wall, 1),
              "train_table": {m["key"]: {"mean_mm": m["mean_mm"], "p95_mm": m["p95_mm"]}
                              for m in table["models"]},
              "fk_finetuned": _stats(np.linalg.norm(fk_pinn - measured, axis=1)),
              "kept": card.get("finetuned_on", {}).get("kept"),
              "stage_seconds": card.get("finetuned_on", {}).get("stage_seconds"),
              "extended_model": card.get("finetuned_on", {}).get("extended_model")}
    tips = table.get("tips_mm")
    if tips is not None:        # the tips train evaluated, when the card records them
        report["train_vs_fk_max_mm"] = float(np.nanmax(np.linalg.norm(np.asarray(tips) - fk_pinn, axis=1)))
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
