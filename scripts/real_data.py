#!/usr/bin/env python
"""Benchmark of `ctrplan diagnose` (and few-shot fine-tuning) on REAL measured data of a robot nobody
here built: `../shared/real/hjhdog1/` (relative to the repository root; 1,307 rows of a three-tube
robot, tube-1 tip tracked). The data have no licence: they are read from there, never copied.

    flock /work/heavy.lock python scripts/real_data.py [--what last,first500,seeds] [--seeds 0,1,2]
        [--code DIR] [--out runs/real.json]
    flock /work/heavy.lock python scripts/real_data.py --what fewshot --init MODEL [--shots 500]

Everything runs through the command line (``python -m ctrplan``), so ``--code DIR`` measures another
checkout with the same script (the numbers "before"). What it measures (tube-1 tip error, mm):

* ``last``     -- `diagnose --heldout-last 0.3` on all rows: fitted on the first 915 rows (its own
  stability splits inside them), the extended model's error on the last 392; and the nominal model's;
* ``first500`` -- the same fitted on the first 500 rows only (a file of those and the last 392);
* ``strict``   -- `diagnose` with the defaults on a file of the first 915 rows only (its own held-out
  blocks inside them: the last 392 rows play no part in choosing the causes either), then `fk --robot
  extended_robot.yaml` on the last 392 rows;
* ``seeds``    -- `diagnose` with the defaults (blocks held out, 1,000 rows) for each ``--seeds``: the
  causes named, held-out error, verdict, wall time (or the crash);
* ``fewshot``  -- `train --measured --heldout-last 0.3 --shots N --init MODEL`, then `fk --robot
  NAME.robot.yaml --model NAME` on the last 392 rows, against the measured tips (``--keep DIR`` keeps
  the model, its card and robot files).

``last`` holds out the last 392 rows from the fitted parameters, but `diagnose`'s main split judges the
candidates on them; ``strict`` and ``seeds`` do not.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "real" / "hjhdog1"
HELDOUT_LAST = 0.3


def ctrplan(code: Path, *args: str, timeout: float = 3600) -> tuple[int, str, str, float]:
    """Run ``python -m ctrplan ARGS`` with the package of checkout ``code``: exit code, stdout, stderr,
    wall seconds."""
    env = {**os.environ, "PYTHONPATH": str(code)}
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "ctrplan", *args], capture_output=True, text=True, env=env,
                       timeout=timeout, cwd=code)
    return p.returncode, p.stdout, p.stderr, time.perf_counter() - t0


def read_rows(path: Path) -> tuple[list[str], list[list[str]]]:
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    return rows[0], rows[1:]


def write_rows(path: Path, header: list[str], rows: list[list[str]]) -> None:
    with open(path, "w", newline="") as fh:
        csv.writer(fh).writerows([header, *rows])


def stats(err: np.ndarray) -> dict:
    return {"mean_mm": float(np.mean(err)), "p95_mm": float(np.percentile(err, 95)),
            "median_mm": float(np.median(err)), "rows": int(len(err))}


def summary(j: dict) -> dict:
    """The numbers of a diagnose JSON document the benchmark reports."""
    named = {k: {"value": v["value"], "std": v.get("std"), "unit": v["unit"]}
             for k, v in j["parameters"].items() if v.get("fitted") is not False}
    return {"cause": j["cause"], "causes": j["causes"], "explained": j["explained"],
            "nominal": {k: j["nominal"][k] for k in ("mean_mm", "p95_mm")},
            "extended": {k: j["extended"][k] for k in ("mean_mm", "p95_mm")},
            "heldout_rows": j["heldout_rows"], "noise_mm": j["noise_mm"], "parameters": named,
            "derived": j["derived"], "implausible_named": [c for c in j["causes"] if c in j["implausible"]],
            "at_bound_named": [k for k, v in j["parameters"].items() if v.get("at_bound")],
            "seconds_inside": j["seconds"], "ties": j["ties"]}


def diagnose(code: Path, data: Path, robot: Path, *extra: str) -> dict:
    rc, out, err, wall = ctrplan(code, "diagnose", str(data), "--robot", str(robot), "--json", *extra)
    if rc != 0:
        return {"crashed": True, "exit": rc, "error": err.strip().splitlines()[-1:] or [""], "wall_s": wall}
    return {**summary(json.loads(out)), "wall_s": wall}


def run_last(code: Path, data: Path, robot: Path) -> dict:
    return diagnose(code, data, robot, "--heldout-last", str(HELDOUT_LAST), "--max-rows", "100000")


def run_first500(code: Path, data: Path, robot: Path, tmp: Path) -> dict:
    header, rows = read_rows(data)
    held = round(HELDOUT_LAST * len(rows))
    path = tmp / "first500_and_last.csv"
    write_rows(path, header, rows[:500] + rows[len(rows) - held:])
    frac = held / (500 + held)
    return diagnose(code, path, robot, "--heldout-last", f"{frac:.12g}", "--max-rows", "100000")


def heldout_configs(data: Path, path: Path) -> np.ndarray:
    """Write the joints of the last ``HELDOUT_LAST`` rows to ``path``; their measured tube-1 tips (H, 3)."""
    header, rows = read_rows(data)
    held = rows[len(rows) - round(HELDOUT_LAST * len(rows)):]
    joints = [h for h in header if h.startswith(("beta", "alpha"))]
    write_rows(path, joints, [[r[header.index(c)] for c in joints] for r in held])
    return np.array([[float(r[header.index(f"tip1_{a}")]) for a in "xyz"] for r in held])


def fk_errors(code: Path, configs: Path, measured: np.ndarray, out: Path, *args: str) -> dict:
    """`fk` of ``configs`` with ``args`` against the measured tips: error statistics (or the failure)."""
    rc, _, err, _ = ctrplan(code, "fk", str(configs), *args, "-o", str(out), "--allow-outside-domain")
    if rc != 0:
        return {"crashed": True, "error": err.strip().splitlines()[-3:]}
    fh, fr = read_rows(out)
    pred = np.array([[float(r[fh.index(f"tip1_{a}")]) for a in "xyz"] for r in fr])
    return stats(np.linalg.norm(pred - measured, axis=1))


def run_strict(code: Path, data: Path, robot: Path, tmp: Path) -> dict:
    header, rows = read_rows(data)
    path = tmp / "first_rows.csv"
    write_rows(path, header, rows[:len(rows) - round(HELDOUT_LAST * len(rows))])
    res = diagnose(code, path, robot, "--max-rows", "100000", "--out", str(tmp / "strict"))
    extended = tmp / "strict" / "extended_robot.yaml"
    if res.get("crashed") or not extended.exists():
        return res
    measured = heldout_configs(data, tmp / "heldout_configs.csv")
    return {**res, "fk_heldout": fk_errors(code, tmp / "heldout_configs.csv", measured, tmp / "fk_strict.csv",
                                           "--robot", str(extended))}


def run_seeds(code: Path, data: Path, robot: Path, seeds: list[int]) -> list[dict]:
    return [{"seed": s, **diagnose(code, data, robot, "--seed", str(s))} for s in seeds]


def run_fewshot(code: Path, data: Path, robot: Path, init: str, shots: int | None, tmp: Path,
                extra: list[str]) -> dict:
    name = f"real_fewshot_{shots or 'all'}"
    args = ["train", "--robot", str(robot), "--init", init, "--measured", str(data), "--heldout-last",
            str(HELDOUT_LAST), "--name", name, "--out-dir", str(tmp), *extra]
    if shots:
        args += ["--shots", str(shots)]
    rc, out, err, wall = ctrplan(code, *args, timeout=7200)
    if rc != 0:
        return {"crashed": True, "error": err.strip().splitlines()[-3:], "wall_s": wall}
    measured = heldout_configs(data, tmp / "heldout_configs.csv")
    card = json.loads((tmp / f"{name}.json").read_text())
    ft = card.get("finetuned_on", {})
    return {"fk_heldout": fk_errors(code, tmp / "heldout_configs.csv", measured, tmp / "fk.csv", "--backend",
                                    "pinn", "--robot", str(tmp / f"{name}.robot.yaml"), "--model",
                                    str(tmp / f"{name}.safetensors")),
            "train_wall_s": wall, "init": init, "kept": ft.get("kept"), "learned_lag": ft.get("learned_lag"),
            "stage_seconds": ft.get("stage_seconds"), "extended_model": ft.get("extended_model"),
            "train_table": [{k: m[k] for k in ("key", "mean_mm", "p95_mm")}
                            for m in card.get("metrics", {}).get("measured_heldout", {}).get("models", [])]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DATA, help="folder with data.csv and robot.yaml")
    ap.add_argument("--what", default="last,first500,seeds", help="last, first500, strict, seeds, fewshot")
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--code", type=Path, default=ROOT, help="the checkout to measure (default: this one)")
    ap.add_argument("--init", help="fewshot: the PINN to start from (name or path)")
    ap.add_argument("--shots", type=int, default=None, help="fewshot: shots (default: all training rows)")
    ap.add_argument("--out", type=Path, help="write the results as JSON here")
    ap.add_argument("--train-args", default="", help="fewshot: more options of `train`, e.g. "
                    "'--adapt-steps 6000'")
    ap.add_argument("--keep", type=Path, help="keep the files the runs write (models, robots) here")
    a = ap.parse_args()
    data, robot = a.data / "data.csv", a.data / "robot.yaml"
    if not data.exists():
        print(f"real_data: {data} not found (the shared real data live beside the repository)",
              file=sys.stderr)
        return 2
    what = set(a.what.split(","))
    result: dict = {"data": str(data), "code": str(a.code), "load_average": os.getloadavg()}
    with tempfile.TemporaryDirectory() as scratch:
        tmp = str(a.keep) if a.keep else scratch
        Path(tmp).mkdir(parents=True, exist_ok=True)
        if "last" in what:
            result["last"] = run_last(a.code, data, robot)
            print("last:", json.dumps(result["last"]), flush=True)
        if "first500" in what:
            result["first500"] = run_first500(a.code, data, robot, Path(tmp))
            print("first500:", json.dumps(result["first500"]), flush=True)
        if "strict" in what:
            result["strict"] = run_strict(a.code, data, robot, Path(tmp))
            print("strict:", json.dumps(result["strict"]), flush=True)
        if "seeds" in what:
            result["seeds"] = run_seeds(a.code, data, robot, [int(s) for s in a.seeds.split(",")])
            for r in result["seeds"]:
                print("seed:", json.dumps(r), flush=True)
        if "fewshot" in what:
            if not a.init:
                print("real_data: --what fewshot needs --init MODEL", file=sys.stderr)
                return 2
            result["fewshot"] = run_fewshot(a.code, data, robot, a.init, a.shots, Path(tmp),
                                            a.train_args.split())
            print("fewshot:", json.dumps(result["fewshot"]), flush=True)
    if a.out:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
