#!/usr/bin/env python3
"""Robots drawn at random from the design space `ctrplan design` searches, for benchmarks that must
not be tuned to one robot (issue 40: train a PINN for a robot nobody tuned for).

For each seed, parameter sets are drawn uniformly from the task's search space (every `vary`
interval, and one nesting set of the catalogue's stock sizes) with ``numpy.random.default_rng(seed)``
until one passes the task's feasibility conditions that concern the robot alone -- the robot loader
accepts it, its pre-curvature strain is within ``max_strain``, and with ``snap_free`` the stability
sweep of `ctrplan stability` finds its domain snap-free -- and that robot is written as
``OUT/design_SEED.yaml`` (its draw index and parameters in the header). The draws depend on the seed
alone: nothing here looks at how well a PINN learns the robot.

    python scripts/design_robots.py scenes/skullbase_design.yaml --seeds 1 2 3 4 5 --out runs/design_robots
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import yaml

from ctrplan.base.errors import InputError
from ctrplan.design.space import DIAMETERS, distributions, max_strain, robot_dict
from ctrplan.design.task import DesignTask, load_task
from ctrplan.kinematics.stability import certify, is_certified
from ctrplan.model.robot import robot_from_dict

#: Draws per seed before giving up (the skull-base task's space is mostly feasible).
MAX_DRAWS = 200


def draw(task: DesignTask, rng: np.random.Generator) -> dict:
    """One parameter set, uniform over the task's search space."""
    out: dict = {}
    for name, dist in distributions(task).items():
        if name == DIAMETERS:
            out[name] = dist.choices[int(rng.integers(len(dist.choices)))]
        else:
            out[name] = float(rng.uniform(dist.low, dist.high))
    return out


def why_infeasible(task: DesignTask, data: dict) -> str | None:
    """The first robot-only feasibility condition ``data`` (a robot-file dict) fails, or None."""
    try:
        robot = robot_from_dict(data, "design")
    except InputError as exc:
        return f"robot: {exc}"
    if max_strain(data) > task.max_strain:
        return f"max_strain {max_strain(data):.4f}"
    if task.snap_free and not is_certified(robot):
        report, _ = certify(robot, stop_at_first=True)
        if not report.snap_free:
            return f"snap_free: {report.example_reason} at {np.round(report.example_q, 3).tolist()}"
    return None


def robot_for_seed(task: DesignTask, seed: int, log=print) -> tuple[dict, dict, int]:
    """The first feasible draw of ``seed``: its robot-file dict, parameters and draw index."""
    rng = np.random.default_rng(seed)
    for k in range(MAX_DRAWS):
        parameters = draw(task, rng)
        data = robot_dict(task, parameters)
        data["name"] = f"design_{seed}"
        why = why_infeasible(task, data)
        log(f"seed {seed} draw {k}: {'feasible' if why is None else why}")
        if why is None:
            return data, parameters, k
    raise SystemExit(f"seed {seed}: no feasible design in {MAX_DRAWS} draws")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("task", type=Path, help="design task file (e.g. scenes/skullbase_design.yaml)")
    parser.add_argument("--seeds", type=int, nargs="+", required=True)
    parser.add_argument("--out", type=Path, required=True, help="folder for design_SEED.yaml")
    ns = parser.parse_args(argv)
    task = load_task(ns.task)
    ns.out.mkdir(parents=True, exist_ok=True)
    for seed in ns.seeds:
        data, parameters, k = robot_for_seed(task, seed, log=lambda m: print(m, file=sys.stderr))
        header = (f"# Drawn by scripts/design_robots.py from {ns.task} (seed {seed}, draw {k}: the first "
                  f"feasible one):\n# " + yaml.safe_dump(parameters, default_flow_style=True, width=10**6))
        (ns.out / f"design_{seed}.yaml").write_text(header + yaml.safe_dump(data, sort_keys=False))


if __name__ == "__main__":
    main()
