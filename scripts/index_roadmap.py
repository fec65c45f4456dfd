"""Index the workspace sweep of an existing roadmap (`ctrplan.planning.roadmap.sweep`), as `ctrplan
roadmap build` does at its end, on local workers; prints the time, the index's entries and size.

    python scripts/index_roadmap.py SCENE.yaml ROADMAP_DIR [--workers 2]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", type=Path)
    ap.add_argument("roadmap", type=Path)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()

    from ctrplan.base.parallel import open_pool
    from ctrplan.kinematics import make_backend
    from ctrplan.planning.roadmap.build import Source
    from ctrplan.planning.roadmap.store import fingerprints, load_roadmap
    from ctrplan.planning.roadmap.sweep import SWEEP_FILE, build_sweep
    from ctrplan.scene.loader import load_scene

    sc = load_scene(args.scene)
    be = make_backend("pinn", sc.robot)
    rm = load_roadmap(args.roadmap, fingerprints(sc, be))
    source = Source(str(args.scene.resolve()), "pinn")
    ctx = source()
    with open_pool(args.workers, None, context=source) as pool:
        t0 = time.perf_counter()
        index = build_sweep(ctx, rm, pool=pool, in_flight=2 * args.workers)
        seconds = time.perf_counter() - t0
    index.save(args.roadmap)
    print(json.dumps({"nodes": rm.n_nodes, "edges": len(rm.edges), "seconds": round(seconds, 1),
                      "workers": args.workers, "node_entries": int(len(index.node_ids)),
                      "edge_entries": int(len(index.edge_ids)), "cells": index.grid.size,
                      "reach_mm": round(index.reach_mm, 3),
                      "file_mb": round((args.roadmap / SWEEP_FILE).stat().st_size / 1e6, 1)}))


if __name__ == "__main__":
    main()
