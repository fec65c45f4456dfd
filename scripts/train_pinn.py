"""Train and evaluate a PINN without the CLI's other dependencies (for GPU machines).

Usage: python scripts/train_pinn.py OUT RECIPE DEVICE MINUTES [key=value recipe overrides...]
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from ctrplan.kinematics.pinn import PinnBackend
from ctrplan.robot import Robot
from ctrplan.training.evaluate import compare
from ctrplan.training.trainer import get_recipe, train


def main() -> None:
    out, recipe_name, device, minutes = sys.argv[1], sys.argv[2], sys.argv[3], float(sys.argv[4])
    overrides = {}
    for kv in sys.argv[5:]:
        k, v = kv.split("=", 1)
        overrides[k] = json.loads(v)
    robot = Robot.nominal()
    init_name = overrides.get("init")
    recipe = get_recipe(recipe_name, **{k: v for k, v in overrides.items() if k != "init"})
    if init_name:
        overrides = {"init": init_name}
    t0 = time.time()

    def progress(step: int, total: int, stats: dict) -> None:
        if step % 1000 == 0 or (recipe.optimizer == "lbfgs" and step % 20 == 0):
            print(f"[{time.time() - t0:7.1f}s] step {step}/{total} "
                  + " ".join(f"{k}={v:.4g}" for k, v in stats.items()), flush=True)

    def evaluate(net) -> dict:
        return compare(PinnBackend(robot, net), robot).metrics()

    init = PinnBackend.load(overrides.pop("init"), robot).net if "init" in overrides else None
    res = train(robot, recipe, Path(out), device=device, time_limit_s=minutes * 60,
                progress=progress, evaluate=evaluate, init_from=init)
    print(json.dumps({"steps": res.steps, "wall_time_s": res.wall_time_s,
                      "metrics": res.card["metrics"]}, indent=1))


if __name__ == "__main__":
    main()
