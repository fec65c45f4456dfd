"""Few-shot fine-tuning on the real-like lab (`tests/independent/lab.real_like`), measured end to end
as a user would: `ctrplan train --measured` on the first 70 % of the rows, then `ctrplan fk --robot
NAME.robot.yaml --model NAME` on the held-out last 30 %, compared with the table `train` printed.

    python scripts/fewshot_lab.py OUT_DIR [--seed S] [--shots N] [-- extra train args]

Prints one JSON document: the stage table of `train` (held-out tail, tube-1 tip, mean/p95 mm), the stage
it kept, and the error of the written model through `fk` on the same rows (it must equal the kept row).
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
    from ctrplan.cli.app import main

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


def run_lab(out: Path, seed: int = 0, shots: int = 500, extra: list[str] | None = None) -> dict:
    """Make the real-like lab data in ``out``, run `ctrplan train --measured` on it and `ctrplan fk`
    with the written model and robot file on the held-out tail; the report (with the model card)."""
    from tests.independent import lab

    out.mkdir(parents=True, exist_ok=True)
    data = lab.real_like(seed=seed)
    csv = out / "measured.csv"
    data.write_csv(csv, tubes=(0,))
    n = len(data.q)
    tail = np.arange(n - int(round(HELDOUT_LAST * n)), n)
    configs = out / "heldout_joints.csv"
    np.savetxt(configs, data.q[tail], delimiter=",", header="beta1,beta2,beta3,alpha1,alpha2,alpha3",
               comments="", fmt="%.17g")
    command = ["train", "--measured", str(csv), "--shots", str(shots), "--heldout-last", str(HELDOUT_LAST),
               *(extra or [])]
    t0 = time.perf_counter()
    card = json.loads(_ctrplan([*command, "--out-dir", str(out), "--name", "ft", "--json"]))
    wall = time.perf_counter() - t0
    fk_pinn = _fk(configs, out / "ft.robot.yaml", out / "ft.safetensors", out / "fk_pinn.csv")
    fk_cosserat = _fk(configs, out / "ft.robot.yaml", None, out / "fk_cosserat.csv")
    measured = data.tips_mm[tail, 0]
    seen = data.q[: n - len(tail)]
    inside = np.all((data.q[tail] >= seen.min(0)) & (data.q[tail] <= seen.max(0)), axis=1)
    table = card["metrics"]["measured_heldout"]
    on = card.get("finetuned_on", {})
    return {"rows": n, "heldout_rows": len(tail), "train_wall_s": round(wall, 1),
            "command": ["ctrplan", *command[:2], "measured.csv", *command[3:]],
            "train_table": {m["key"]: {"mean_mm": round(m["mean_mm"], 3), "p95_mm": round(m["p95_mm"], 3)}
                            for m in table["models"]},
            "fk_written_model": _stats(np.linalg.norm(fk_pinn - measured, axis=1)),
            "fk_cosserat_written_robot": _stats(np.linalg.norm(fk_cosserat - measured, axis=1)),
            "tail_rows_inside_training_range": int(inside.sum()),
            "fk_written_model_inside_outside": [_stats(np.linalg.norm(fk_pinn - measured, axis=1)[m])
                                                for m in (inside, ~inside) if m.any()],
            "kept": on.get("kept"), "learned_lag": on.get("learned_lag"),
            "stage_seconds": on.get("stage_seconds"), "extended_model": on.get("extended_model"),
            "card": card}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("out", type=Path)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--shots", type=int, default=500)
    ns, extra = parser.parse_known_args()   # what follows `--` goes to `ctrplan train`
    report = run_lab(ns.out, ns.seed, ns.shots, [a for a in extra if a != "--"])
    (ns.out / "report.json").write_text(json.dumps(report, indent=1))   # what update_readme renders
    print(json.dumps({k: v for k, v in report.items() if k != "card"}, indent=1))


if __name__ == "__main__":
    main()
