"""Roadmap queries on targets nobody tuned for: scattered over the sella (both halves of the gland), the
clivus, the medial walls of both cavernous sinuses and the tuberculum sellae of ``skullbase.yaml`` (the
regions of ``scenes/skullbase_design.yaml``: the contralateral ones need the tip to bend across the
fossa, the tuberculum a steep approach), each answered from a roadmap and planned from scratch by
single-query RRTConnect, as ``ctrplan bench roadmap`` does for random targets in the scene's region.

    python scripts/bench_scattered_targets.py --roadmap DIR [--single-time-limit 10] [--out DIR]
        [--query-module OLD_QUERY.py]

``--query-module`` answers with the `RoadmapPlanner` of another version of
``ctrplan/planning/roadmap/query.py`` (e.g. ``git show REV:ctrplan/planning/roadmap/query.py >
old.py``): the same roadmap and targets before and after a change.

Writes ``targets.csv`` (the targets: header x,y,z,tolerance_mm, usable with ``plan --roadmap
--targets``), ``results.json`` (every run, the summary per planner and per region) and prints the
summary. Targets are drawn with a fixed seed: the same on every machine.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
#: (region, centre (mm), semi-axes (mm), targets): the regions of skullbase_design.yaml, widened.
REGIONS = (
    ("sella", (0.0, 22.0, 81.0), (6.0, 2.5, 3.5), 14),
    ("clivus", (0.0, 9.0, 73.6), (2.5, 2.5, 1.5), 8),
    ("cavernous_right", (-5.5, 22.0, 80.5), (1.0, 2.0, 2.0), 5),
    ("cavernous_left", (5.5, 22.0, 80.5), (1.0, 2.0, 2.0), 5),
    ("tuberculum", (0.0, 28.0, 73.6), (1.5, 1.0, 1.5), 4),
)
TOLERANCE_MM = 1.0
SEED = 38


def scattered_targets() -> list[tuple[str, np.ndarray]]:
    """(region, centre) of every target, uniform in each region's ellipsoid (seeded)."""
    rng = np.random.default_rng(SEED)
    out = []
    for name, centre, axes, n in REGIONS:
        d = rng.normal(size=(n, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        r = rng.uniform(size=(n, 1)) ** (1.0 / 3.0)
        out += [(name, np.round(np.asarray(centre) + p * np.asarray(axes), 3)) for p in d * r]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--roadmap", type=Path, required=True)
    ap.add_argument("--scene", type=Path, default=REPO / "scenes" / "skullbase.yaml")
    ap.add_argument("--single-time-limit", type=float, default=10.0, help="s; 0 skips single-query planning")
    ap.add_argument("--out", type=Path, default=REPO / "runs" / "bench_scattered")
    ap.add_argument("--query-module", type=Path, help="another query.py to answer with")
    args = ap.parse_args()

    from ctrplan.bench import roadmap as bench
    from ctrplan.kinematics import make_backend
    from ctrplan.planning.roadmap._adapter import planning_context
    from ctrplan.planning.roadmap.query import RoadmapPlanner
    from ctrplan.planning.roadmap.store import fingerprints, load_roadmap
    from ctrplan.scene.loader import load_scene
    from ctrplan.scene.objects import TargetRegion

    sc = load_scene(args.scene)
    be = make_backend("pinn", sc.robot)
    rm = load_roadmap(args.roadmap, fingerprints(sc, be))
    ctx = planning_context(sc, be)
    if args.query_module is not None:
        import importlib.util

        name = "ctrplan.planning.roadmap._query_other"
        spec = importlib.util.spec_from_file_location(name, args.query_module)
        other = importlib.util.module_from_spec(spec)
        sys.modules[name] = other  # its dataclasses look their module up
        spec.loader.exec_module(other)
        planner = other.RoadmapPlanner(ctx, rm)
    else:
        planner = RoadmapPlanner(ctx, rm)
    named = scattered_targets()
    targets = [TargetRegion.sphere(c, TOLERANCE_MM) for _, c in named]
    args.out.mkdir(parents=True, exist_ok=True)
    rows = "\n".join(f"{c[0]},{c[1]},{c[2]},{TOLERANCE_MM}" for _, c in named)
    (args.out / "targets.csv").write_text("x,y,z,tolerance_mm\n" + rows + "\n")
    planner.answer(targets[0])  # first query warms caches the others share
    single = (be, ctx.exact, args.single_time_limit) if args.single_time_limit > 0 else None
    records = bench.run(planner, targets, backend_name=be.name, seed=0, single=single)
    region = {tuple(c.tolist()): name for name, c in named}
    for r in records:
        r["region"] = region[tuple(r["target_mm"])]
    summary = {"all": bench.summarize(records)}
    for name, *_ in REGIONS:
        summary[name] = bench.summarize([r for r in records if r["region"] == name])
    doc = {"roadmap": str(args.roadmap), "nodes": rm.n_nodes, "query_module": str(args.query_module or ""),
           "load_average": list(__import__("os").getloadavg()), "summary": summary, "runs": records}
    (args.out / "results.json").write_text(json.dumps(doc, indent=1))
    print(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
