#!/usr/bin/env python3
"""How much of a PINN's tube-1 tip tail sits next to jumps of the exact model (issue 40).

On the configurations of `ctrplan eval-model --n N` (same seed), the exact tube-1 tip is probed a
step of r rad (rotations) and 10 r mm (translations; the ratio of `PROBE_STEP`) either way along
every free coordinate (`ctrplan.training.evaluate.jumps_within`). Where it moves more than
`JUMP_MM`, that step is bisected (the half where the tip moves more, each time) down to
`RESOLUTION_RAD` (0.001 rad, 0.01 mm): a configuration lies within r of a jump of the exact model
when the tip still moves more than `JUMP_MM` across that last step (3,000 mm/rad; the steepest smooth
places of these robots move it 140-300 mm/rad, which a step of 0.03 rad alone would not tell from a
jump). There the robot snaps: two equilibria, and the solver's answer switches between them. The
script prints the plain
tail (the number that counts; it equals eval-model's) and, clearly labelled beside it, the tail
without the configurations within r of a jump, for each r:

    python scripts/tail_near_jumps.py --robot ../shared/real/hjhdog1/robot.yaml --model models/hjhdog1 \\
        --n 5000 --radii 0.003 0.01 0.03 --out docs/training/hjhdog1_jumps.json

A smooth network cannot follow a 10-20 mm jump within 0.01 rad; what the second number shows is how
much of the miss is the exact model's own snapping rather than training time.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from ctrplan.kinematics.pinn import PinnBackend
from ctrplan.model.robot import Robot
from ctrplan.training.evaluate import JUMP_MM, PROBE_STEP, RESOLUTION_RAD, compare, jumps_within
from ctrplan.training.target import meets, tail


def near_jumps(robot: Robot, model: str, n: int, radii: list[float]) -> dict:
    """The plain tube-1 tip tail (mm) on eval-model's ``n`` configurations and, per radius (rad), how
    many lie within it of a jump of the exact model and the tail without them. JSON-ready."""
    cmp = compare(PinnBackend.load(model, robot), robot, n=n, points=2)
    ok = np.flatnonzero(cmp.solved)
    err = np.linalg.norm(cmp.predicted.tips_mm[ok, 0] - cmp.exact.tips_mm[ok, 0], axis=-1)
    plain = tail(err)
    rows = []
    for r in radii:
        jump = jumps_within(robot, cmp.exact.q[ok], cmp.exact.tips_mm[ok, 0], r)
        kept = tail(err[~jump])
        mm_per_rad = PROBE_STEP["translation_mm"] / PROBE_STEP["rotation_rad"]
        rows.append({"radius_rad": r, "translation_mm": mm_per_rad * r, "resolution_rad": RESOLUTION_RAD,
                     "near_jump": int(jump.sum()),
                     "near_jump_errors_mm": sorted((round(float(e), 3) for e in err[jump]), reverse=True),
                     "without_near_jump": kept, "meets_target_without": bool(meets(kept))})
    return {"model": model, "robot": str(robot.name), "configurations": len(ok), "jump_mm": JUMP_MM,
            "plain": plain, "meets_target": bool(meets(plain)), "radii": rows}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--robot", required=True)
    parser.add_argument("--model", required=True)
    parser.add_argument("--n", type=int, default=5000)
    parser.add_argument("--radii", type=float, nargs="+", default=[0.003, 0.01, 0.03])
    parser.add_argument("--out", type=Path)
    ns = parser.parse_args(argv)
    doc = near_jumps(Robot.load(ns.robot), ns.model, ns.n, ns.radii)
    fmt = "mean {mean:.3f}  p99 {p99:.3f}  p99.9 {p99_9:.3f}  max {max:.3f} mm"
    print(f"{doc['model']}: tube-1 tip on {doc['configurations']} configurations: "
          f"{fmt.format(**doc['plain'])} ({'meets' if doc['meets_target'] else 'misses'} the target)")
    for row in doc["radii"]:
        print(f"  without the {row['near_jump']} within {row['radius_rad']} rad of a jump of the exact model "
              f"(> {JUMP_MM} mm within {RESOLUTION_RAD} rad): {fmt.format(**row['without_near_jump'])} "
              f"({'meets' if row['meets_target_without'] else 'misses'})")
    if ns.out:
        ns.out.write_text(json.dumps(doc, indent=2, allow_nan=False) + "\n")


if __name__ == "__main__":
    main()
