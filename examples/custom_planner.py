"""Plan with any OMPL planner from user code, using ctrplan's state space, validity checker,
batched motion validator and IK-sampled goal; then check the path with the exact model.

    python examples/custom_planner.py [scenes/open.yaml] [--backend cosserat]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from ompl import geometric as og
from ompl import util as ou

from ctrplan.planning import build_problem, resolve_backend, validate_path
from ctrplan.scene.loader import load_scene

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", nargs="?", default=str(ROOT / "scenes" / "open.yaml"))
    ap.add_argument("--backend", default="cosserat", help="pinn | cosserat | hybrid")
    ap.add_argument("--time", type=float, default=10.0)
    args = ap.parse_args()
    ou.setLogLevel(ou.LOG_WARN)

    scene = load_scene(args.scene)
    backend = resolve_backend(args.backend, scene.robot)
    problem = build_problem(scene, backend, rng=np.random.default_rng(0))

    planner = og.LBKPIECE1(problem.si)  # any geometric planner works (not PRM: several goals)
    planner.setRange(15.0)  # mm in the planning metric (rotations weighted by mm_per_rad)
    planner.setProblemDefinition(problem.pdef)
    planner.setup()
    status = planner.solve(args.time)
    path = problem.solution() if problem.pdef.hasExactSolution() else None
    print(f"{planner.getName()}: {status.asString()}, "
          f"{problem.checker.counters.kinematics_calls} kinematics calls")
    if path is None:
        return
    report = validate_path(scene, path, backend).report  # exact Cosserat model, dense
    print(f"{len(path)} waypoints; exact model: collision-free {report.collision_free}, "
          f"clearance {report.min_clearance_mm:.2f} mm, tip in target {report.tip_in_target}, "
          f"max backbone error of {backend.name} {report.max_position_error_mm:.2f} mm")


if __name__ == "__main__":
    main()
