#!/usr/bin/env python3
"""Would `diagnose`'s own significance test keep a few-shot model's learned friction? (issue 37)

Takes the robot file `ctrplan train --measured` wrote beside a model (NAME.robot.yaml, its calibration
holding the learned ``friction``), the same split `train --measured --heldout-last 0.3 --shots N` used,
and compares the extended Cosserat model with and without that friction on the validation shots and
on the held-out last rows: tube-1 mean / p95 mm and the test `diagnose` names a cause by (one-sided
Wilcoxon over configuration groups, alpha 0.01, a gain of at least 5 %; all tubes)::

    python scripts/friction_significance.py runs/real_fewshot_500.robot.yaml --shots 500

The data stay outside the repository (``--data``, default ``../shared/real/hjhdog1/data.csv``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from ctrplan.base.yamlio import load_yaml
from ctrplan.calibration.data import read_measured
from ctrplan.calibration.options import DiagnoseOptions
from ctrplan.calibration.selection import compare, configuration_groups
from ctrplan.model.robot import Robot, robot_from_dict
from ctrplan.training.fewshot import split_shots, validation_split
from ctrplan.training.finetune import cosserat_tips

REAL = Path(__file__).resolve().parents[1].parent / "shared" / "real" / "hjhdog1"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("robot", type=Path, help="NAME.robot.yaml written by train --measured")
    ap.add_argument("--shots", type=int, default=None, help="the --shots of that run (all training rows)")
    ap.add_argument("--data", type=Path, default=REAL / "data.csv")
    ap.add_argument("--base-robot", type=Path, default=REAL / "robot.yaml")
    ns = ap.parse_args()
    data = read_measured(ns.data, Robot.load(ns.base_robot))
    fs = split_shots(data, ns.shots, 0.3, heldout_last=True)
    _, val = validation_split(fs)
    doc = load_yaml(ns.robot).data
    with_friction = robot_from_dict(doc, str(ns.robot))
    calibration = {k: v for k, v in doc.get("calibration", {}).items() if k != "friction"}
    without = robot_from_dict({**doc, "calibration": calibration}, str(ns.robot))
    opt = DiagnoseOptions()
    for label, rows, alone in (("validation shots", val, False), ("held-out last rows", fs.heldout, True)):
        err = [np.linalg.norm(cosserat_tips(r, fs, rows, alone) - data.tips_mm[rows], axis=2)
               for r in (without, with_friction)]
        groups = configuration_groups(data.q[rows], fs.motion.subset(rows).direction)
        gain, p, kept = compare(err[1], err[0], opt.alpha, opt.min_gain, groups)
        stats = [f"{np.nanmean(e[:, 0]):.3f} / {np.nanpercentile(e[:, 0], 95):.3f}" for e in err]
        print(f"{label} ({len(rows)} rows): tube-1 mean / p95 mm without friction {stats[0]}, with "
              f"{stats[1]}; gain {gain:+.1%}, p = {p:.2g}: {'significant' if kept else 'not significant'}")


if __name__ == "__main__":
    main()
