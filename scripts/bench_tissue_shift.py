"""Tissue that moves: repair times of a roadmap against the shift of a skull-base structure.

For each structure and shift (1, 2, 4, 8 mm, along the direction that brings it towards the pituitary),
the structure is moved from its place in the scene file and the roadmap repaired (`LiveRoadmap.move`:
index look-up, collision world, shortest-path tree; timed); then the scene's target is answered from
the repaired roadmap (timed: the lazy checks of SUSPECT elements on its path count there) and checked
by the exact model in the moved scene (``collision_free``, the exact clearance to the moved
structure); then every SUSPECT element is checked (`resolve_all`, timed: what an eager repair costs)
to count what the shift invalidated; then the structure goes back (a repair too). Needs the roadmap's
sweep index (``roadmap build`` makes it; else ``scripts/index_roadmap.py``).

    python scripts/bench_tissue_shift.py --roadmap DIR [--out results.json]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
#: structure -> unit direction of its shift (scene frame: x left, y superior, z posterior).
MOVES = {"right_internal_carotid": (1.0, 0.0, 0.0), "optic_chiasm": (0.0, -1.0, 0.0),
         "sella_turcica": (0.0, 0.0, -1.0), "left_internal_carotid": (-1.0, 0.0, 0.0)}
SHIFTS_MM = (1.0, 2.0, 4.0, 8.0)


def one_shift(live, name: str, shift: np.ndarray, resolve: bool = True) -> dict:
    """Move, plan the scene's target, resolve every SUSPECT element (with ``resolve``), move back:
    the record."""
    from ctrplan.planning.roadmap.query import RoadmapPlanner
    from ctrplan.planning.roadmap.repair import BLOCKED
    from ctrplan.viz.plan_outputs import structure_clearances

    rep = live.move(name, shift)
    t0 = time.perf_counter()
    ans = RoadmapPlanner(live.ctx, live.roadmap, live).answer(live.ctx.scene.target)
    plan_s = time.perf_counter() - t0
    clear = None
    if ans.dense is not None:
        found = structure_clearances(live.ctx.scene, ans.dense.exact, live.ctx.checker.world)
        clear = round(next(c.distance_mm for c in found if c.name == name), 3)
    t1 = time.perf_counter()
    if resolve:
        live.resolve_all()
    resolve_s = time.perf_counter() - t1
    blocked = {"nodes": int((live.node_state == BLOCKED).sum()),
               "edges": int((live.edge_state == BLOCKED).sum())}
    back = live.move(name, np.zeros(3))
    if resolve:
        live.resolve_all()
    return {"structure": name, "shift_mm": float(np.linalg.norm(shift)), **rep.to_json(),
            "first_plan_s": round(plan_s, 4), "first_plan_query_s": round(ans.query_time_s, 4),
            "first_plan_steps": ans.steps, "target_solved": ans.solved,
            "exact_collision_free": None if ans.validated is None else ans.validated.collision_free,
            "clearance_to_moved_mm": clear, "resolve_all_s": round(resolve_s, 3), "invalidated": blocked,
            "invalidated_fraction": {k: round(blocked[k] / rep.total[k], 5) for k in blocked},
            "suspect_fraction": {k: round(rep.suspect[k] / rep.total[k], 5) for k in blocked},
            "back_s": round(back.seconds["total_s"], 4)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--roadmap", type=Path, required=True)
    ap.add_argument("--scene", type=Path, default=REPO / "scenes" / "skullbase.yaml")
    ap.add_argument("--out", type=Path, default=REPO / "runs" / "bench_tissue_shift.json")
    ap.add_argument("--no-resolve", action="store_true",
                    help="skip checking every SUSPECT element (no invalidated counts; minutes faster)")
    args = ap.parse_args()

    from ctrplan.kinematics import make_backend
    from ctrplan.planning.roadmap._adapter import planning_context
    from ctrplan.planning.roadmap.repair import LiveRoadmap
    from ctrplan.planning.roadmap.store import fingerprints, load_roadmap
    from ctrplan.planning.roadmap.sweep import SweepIndex
    from ctrplan.scene.loader import load_scene

    sc = load_scene(args.scene)
    be = make_backend("pinn", sc.robot)
    rm = load_roadmap(args.roadmap, fingerprints(sc, be))
    index = SweepIndex.load(args.roadmap, rm)
    if index is None:
        raise SystemExit(f"{args.roadmap}: no sweep index (run scripts/index_roadmap.py)")
    live = LiveRoadmap(planning_context(sc, be), rm, index)
    for name in MOVES:  # each structure's own distance grid, once (cached on disk), before the clock
        live.grid(name)
    rows = []
    for name, direction in MOVES.items():
        for shift in SHIFTS_MM:
            row = one_shift(live, name, shift * np.asarray(direction), resolve=not args.no_resolve)
            rows.append(row)
            print(json.dumps({k: row[k] for k in ("structure", "shift_mm", "suspect", "reopened", "seconds",
                                                  "first_plan_s", "target_solved", "exact_collision_free",
                                                  "clearance_to_moved_mm", "invalidated", "resolve_all_s")}),
                  flush=True)
            args.out.parent.mkdir(parents=True, exist_ok=True)
            args.out.write_text(json.dumps({"roadmap": str(args.roadmap), "nodes": rm.n_nodes,
                                            "edges": len(rm.edges), "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
