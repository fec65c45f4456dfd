#!/usr/bin/env python
"""What an extended robot leaves unexplained on measured data, and which physics could take it: the
benchmark behind the "what is left" paragraph of docs/benchmarks.md (issue 37).

    python scripts/residual_left.py EXTENDED.robot.yaml [--data ../shared/real/hjhdog1/data.csv]
        [--heldout-last 0.3] [--out runs/residual_left.json]

``EXTENDED.robot.yaml`` is what `ctrplan diagnose --heldout-last 0.3 --out DIR` wrote
(``DIR/extended_robot.yaml``). Its tube-1 tip residual (measured minus predicted, each row with the
motion history of the whole file) is explained by candidate effects **linearised** about that model:
each candidate is a set of regressor columns (R, 3) -- the model's sensitivity to a parameter, e.g.
d(tip)/d(alpha2) times the direction of motion of alpha2 for a backlash of alpha2 -- fitted by
least squares. Every candidate is judged twice, on rows nobody fitted:

* ``validation``: fitted on the first 80 % of the training rows, scored on the last 20 % (what a
  user who holds the file's last rows back could have measured);
* ``heldout``: fitted on all training rows, scored on the held-out rows (the last 30 % of the file).

Candidates cover the cause library's joint-side effects (joint offsets, backlash, a lag that depends on
the configuration) and loads the library has only partly: a tip force fixed in the robot frame (the
library's ``tip_force``) and one fixed in the tip frame of tube 1 (a follower load: a cable or lead
in tension at the tip), each also switching sign with the direction of motion of a joint (sliding
friction). Two local smoothers (the mean residual of the k nearest training configurations, with and
without the directions of motion as coordinates) bound what any function of configuration (and
direction) could take. Linearised: a candidate that wins here is worth building into the library, where
`diagnose` fits and judges it exactly.

The data are read from beside the repository and never copied into it.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from ctrplan.calibration.data import read_measured
from ctrplan.kinematics.cosserat import CosseratBackend
from ctrplan.model.robot import Robot
from ctrplan.training.fewshot import mechanics_joints, split_shots

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "real" / "hjhdog1" / "data.csv"
#: Finite-difference steps: mm for a translation, rad for a rotation, N for a force.
STEP = {"beta": 0.5, "alpha": 0.01, "force": 0.05}
#: Share of the training rows (the last ones) that validate.
VALIDATION = 0.2


def tube1_tips(robot: Robot, q_mech: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tube-1 tips (R, 3) mm in the tracker frame (NaN where unsolved) and tip rotations (R, 3, 3)
    robot <- tip of ``robot``'s mechanics at mechanics joints ``q_mech``."""
    bb = CosseratBackend(robot.mechanics).forward(q_mech, points=2, check=False)
    tips = robot.calibration.tracked_tips(bb.tips_mm, bb.rotations[:, -1])[:, 0]
    return np.where(bb.converged[:, None], tips, np.nan), bb.rotations[:, -1]


def sensitivities(robot: Robot, q_mech: np.ndarray, moving: list[int]) -> dict[str, np.ndarray]:
    """Central differences of the tracked tube-1 tip (R, 3) with respect to every moving joint
    (``dq{j}``, mm per mm or rad) and to a tip force along robot x, y, z (``F{i}``, mm/N)."""
    n = robot.n_tubes
    out = {}
    for j in moving:
        h = STEP["beta"] if j < n else STEP["alpha"]
        d = np.zeros(q_mech.shape[1])
        d[j] = h
        out[f"dq{j}"] = (tube1_tips(robot, q_mech + d)[0] - tube1_tips(robot, q_mech - d)[0]) / (2 * h)
    for i in range(3):
        f = np.zeros(3)
        f[i] = STEP["force"]
        pushed, pulled = (robot.with_changes(loads=replace(
            robot.loads, tip_force_n=tuple(robot.loads.tip_force_n + sign * f))) for sign in (1, -1))
        out[f"F{i}"] = (tube1_tips(pushed, q_mech)[0] - tube1_tips(pulled, q_mech)[0]) / (2 * STEP["force"])
    return out


def candidates(sens: dict, rotation: np.ndarray, direction: np.ndarray, q: np.ndarray,
               moving: list[int], n_tubes: int, names: list[str]) -> dict[str, list[np.ndarray]]:
    """Candidate name -> regressor columns (R, 3), linearised about the extended model."""
    world = [sens[f"F{i}"] for i in range(3)]
    C = np.stack(world, -1)                                        # (R, 3, 3) mm/N, robot-frame force
    follower = [np.einsum("rij,rj->ri", C, rotation[:, :, i]) for i in range(3)]   # tip-frame force
    rel = q[:, n_tubes] - q[:, n_tubes + 1] if n_tubes > 1 else np.zeros(len(q))
    shape = [np.ones(len(q)), np.cos(rel), np.sin(rel)]
    rotations = [j for j in moving if j >= n_tubes]
    sign = {j: direction[:, j][:, None] for j in moving}
    out = {
        "joint offsets": [sens[f"dq{j}"] for j in moving],
        "backlash of every moving joint": [sens[f"dq{j}"] * sign[j] for j in moving],
        "lag depending on the relative angle (every moving joint)":
            [sens[f"dq{j}"] * sign[j] * p[:, None] for j in moving for p in shape],
        "tip force, robot frame (library: tip_force)": world,
        "tip force, tip frame (follower load)": follower,
        "joint offsets + follower load": [sens[f"dq{j}"] for j in moving] + follower,
        "sensor offset (library: sensor_offset)": [rotation[:, :, i] for i in range(3)],
        "sensor offset + follower load": [rotation[:, :, i] for i in range(3)] + follower,
    }
    for j in moving:
        out[f"lag of {names[j]} depending on the relative angle"] = [sens[f"dq{j}"] * sign[j] * p[:, None]
                                                                     for p in shape]
    for frame, cols in (("robot", world), ("tip", follower)):
        out[f"tip force, {frame} frame, + its sliding friction with every moving joint"] = \
            cols + [c * sign[j] for j in moving for c in cols]
        for j in moving:
            out[f"tip force, {frame} frame, + its sliding friction with {names[j]}"] = \
                cols + [c * sign[j] for c in cols]
    if len(rotations) > 1:
        both = [moving[0]] + rotations[-1:]
        out[f"follower load + its sliding friction with {' and '.join(names[j] for j in both)}"] = \
            follower + [c * sign[j] for j in both for c in follower]
    return out


def least_squares(cols: list[np.ndarray], r: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Coefficients of ``r ~ sum_k c_k cols_k`` on ``rows`` and their standard errors."""
    A = np.stack(cols, -1)[rows].reshape(-1, len(cols))
    b = r[rows].reshape(-1)
    c, *_ = np.linalg.lstsq(A, b, rcond=None)
    s2 = float(np.sum((b - A @ c) ** 2) / max(len(b) - len(c), 1))
    return c, np.sqrt(np.diag(s2 * np.linalg.pinv(A.T @ A)))


def stats(e: np.ndarray) -> dict:
    return {"mean_mm": round(float(e.mean()), 3), "p95_mm": round(float(np.percentile(e, 95)), 3)}


def judge(predict, r: np.ndarray, fit: np.ndarray, val: np.ndarray, train: np.ndarray,
          held: np.ndarray) -> dict:
    """A predictor ``predict(fit_rows, test_rows) -> (test, 3)`` scored on validation and held-out rows."""
    return {"validation": stats(np.linalg.norm(r[val] - predict(fit, val), axis=1)),
            "heldout": stats(np.linalg.norm(r[held] - predict(train, held), axis=1))}


def nearest_mean(x: np.ndarray, r: np.ndarray, k: int):
    """The local smoother: mean residual of the ``k`` nearest fitted rows in coordinates ``x``."""
    def predict(fit: np.ndarray, test: np.ndarray) -> np.ndarray:
        _, nb = cKDTree(x[fit]).query(x[test], k)
        return r[fit][nb].mean(1)
    return predict


def smoothers(data, direction: np.ndarray, moving: list[int], n_tubes: int, r: np.ndarray,
              rows: tuple) -> dict:
    """The local smoothers of ``r`` over the configuration (beta in mm, alpha as 30 mm chords), with and
    without the directions of motion (15 mm a unit), judged on ``rows`` (fit, val, train, held)."""
    x_cfg = np.column_stack([data.q[:, j] if j < n_tubes else 30.0 * np.column_stack(
        [np.cos(data.q[:, j]), np.sin(data.q[:, j])]) for j in moving])
    with_direction = np.column_stack([x_cfg, 15.0 * direction[:, moving]])
    coordinates = {"configuration": x_cfg, "configuration and direction of motion": with_direction}
    return {f"{label}, {k} nearest": judge(nearest_mean(x, r, k), r, *rows)
            for label, x in coordinates.items() for k in (20, 50)}


def print_table(result: dict, name: str) -> None:
    rows = result["rows"]
    print(f"tube-1 tip residual of {name}: mean / p95 mm, validation ({rows['fit']} fit, "
          f"{rows['validation']} scored) | held-out ({rows['train']} fit, {rows['heldout']} scored)")
    table = [("extended model as it is", result["extended"])]
    table += sorted(result["linearised"].items(), key=lambda t: t[1]["validation"]["mean_mm"])
    table += [("local smoother: " + k, v) for k, v in result["smoothers"].items()]
    for label, v in table:
        print(f"  {label:78s} {v['validation']['mean_mm']:6.3f} / {v['validation']['p95_mm']:6.3f} | "
              f"{v['heldout']['mean_mm']:6.3f} / {v['heldout']['p95_mm']:6.3f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("robot", type=Path, help="the extended robot file diagnose wrote")
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--heldout-last", type=float, default=0.3)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    robot = Robot.load(args.robot)
    data = read_measured(args.data, robot)
    fs = split_shots(data, heldout_fraction=args.heldout_last, heldout_last=True)
    q_mech = mechanics_joints(robot, fs, np.arange(len(data)))
    tips, rotation = tube1_tips(robot, q_mech)
    r = data.tips_mm[:, 0] - tips
    n = robot.n_tubes
    moving = [j for j in range(2 * n) if np.ptp(data.q[:, j]) > 1e-9]
    sens = sensitivities(robot, q_mech, moving)
    ok = np.isfinite(r).all(1) & np.all([np.isfinite(v).all(1) for v in sens.values()], axis=0)
    train, held = fs.shots[ok[fs.shots]], fs.heldout[ok[fs.heldout]]
    k_val = int(round(VALIDATION * len(train)))
    rows = (train[:-k_val], train[-k_val:], train, held)
    direction = data.motion().direction
    result = {"robot": str(args.robot), "data": args.data.name,
              "rows": {"fit": len(rows[0]), "validation": k_val, "train": len(train), "heldout": len(held)},
              "extended": judge(lambda a, b: np.zeros((len(b), 3)), r, *rows), "linearised": {},
              "smoothers": smoothers(data, direction, moving, n, r, rows)}
    names = list(robot.joint_names)
    for name, cols in candidates(sens, rotation, direction, data.q, moving, n, names).items():
        def predict(a, b, cols=cols):
            return np.stack(cols, -1)[b] @ least_squares(cols, r, a)[0]
        c, se = least_squares(cols, r, train)
        result["linearised"][name] = {**judge(predict, r, *rows),
                                      "coefficients": [round(float(v), 5) for v in c],
                                      "std": [round(float(v), 5) for v in se]}
    print_table(result, f"{args.robot.name} on {args.data.name}")
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
