#!/usr/bin/env python
"""Calibrate a PINN's backbone position error bound and store it in its model card.

    python scripts/calibrate_pinn.py [MODEL] [--robot ROBOT.yaml] [--n 5000]

Split-conformal: the exact Cosserat model is the truth on N configurations drawn with
`CALIBRATION_SEED` (a seed no training or evaluation uses); per arc-length region and coverage
(`COVERAGES`) the bound is the conformal quantile of the largest position error in that region (see
`ctrplan.training.evaluate.error_bound`). The planner adds the bound of each region, at the scene's
``surrogate_coverage``, to the capsule radii there while planning with the PINN. The weights (and
their hash in the card) are untouched. The bound holds for the backend as loaded (its network nodes,
`ctrplan.kinematics.pinn.DEFAULT_NODES`): recalibrate after changing them. `ctrplan train` writes
the same bound into every card it makes; this script recalibrates an existing model.
"""

from __future__ import annotations

import argparse
import json

from ctrplan.kinematics.model_file import resolve_model, write_card_field
from ctrplan.kinematics.pinn import ERROR_BOUND_KEY, PinnBackend
from ctrplan.model.robot import Robot
from ctrplan.training.evaluate import calibrate


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", nargs="?", default=None, help="model name or path (default: the shipped one)")
    ap.add_argument("--robot", default=None, help="robot file or name (default: nominal)")
    ap.add_argument("--n", type=int, default=5000, help="calibration configurations")
    args = ap.parse_args()
    if args.n < 100:
        ap.error("--n must be >= 100")
    robot = Robot.load(args.robot)
    pinn = PinnBackend.load(args.model, robot)
    bound = calibrate(pinn, robot, n=args.n)
    write_card_field(resolve_model(args.model), ERROR_BOUND_KEY, bound)
    print(json.dumps(bound, indent=2))


if __name__ == "__main__":
    main()
