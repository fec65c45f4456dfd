"""Plan through the skull-base scene, validate with the exact model, and draw the result.

    python examples/plan_and_plot.py [--scene scenes/skullbase.yaml] [--backend pinn] [--seed 0]

Writes examples/output/plan/plan.png (scene + backbones along the path, three views) and
plan.html (interactive, offline), and prints the exact-model validation.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from ompl import util as ou

from ctrplan.planning import plan
from ctrplan.scene.loader import load_scene
from ctrplan.viz import plot_plan, viewer_data, write_viewer
from ctrplan.viz.style import CLEARANCE_CAP_MM

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default=str(ROOT / "scenes" / "skullbase.yaml"))
    ap.add_argument("--backend", default="pinn", help="pinn | cosserat | hybrid (default: pinn)")
    ap.add_argument("--planner", default="rrtconnect")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--time-limit", type=float, default=10.0)
    ap.add_argument("--out", default=str(ROOT / "examples" / "output" / "plan"))
    args = ap.parse_args()
    ou.setLogLevel(ou.LOG_WARN)

    scene = load_scene(args.scene)
    stages: list[str] = []

    def progress(stage: str, **info) -> None:
        if not stages or stages[-1] != stage:
            stages.append(stage)
            print(f"  {stage} ...")

    result = plan(scene, args.backend, planner=args.planner, seed=args.seed,
                  time_limit_s=args.time_limit, progress=progress, clearances=True)
    print(f"{scene.name}: {result.message} ({result.planner}/{result.backend}, "
          f"{result.planning_time_s:.2f} s, {result.kinematics_calls} kinematics calls)")
    if result.dense is None:
        return
    v = result.validated
    print(f"exact model: collision-free {v.collision_free}, min clearance {v.min_clearance_mm:.2f} mm "
          f"({v.nearest_obstacle}), max backbone error {v.max_position_error_mm:.2f} mm, "
          f"tip {np.round(v.tip_mm, 2)} in target: {v.tip_in_target}")

    out = Path(args.out)
    backbones = scene.to_scene(result.dense.exact.positions_mm)  # exact model, scene frame
    png = plot_plan(scene, backbones, out / "plan.png", tip_path=backbones[:, -1])
    clearance = np.minimum(result.dense.clearance_mm, CLEARANCE_CAP_MM)  # per capsule, mm: colours it
    html = write_viewer(out / "plan.html", viewer_data(scene, backbones, result.dense.exact.radius_mm,
                                                       {"result": result.message}, clearance),
                        title=f"ctrplan: {scene.name}")
    print(f"wrote {png} and {html}")


if __name__ == "__main__":
    main()
