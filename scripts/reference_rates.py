#!/usr/bin/env python3
"""Measure the reference rates of the planning backends: states a search evaluates per second.

A planning time limit of S seconds buys ``S x reference_states_per_s`` states of work
(`ctrplan.kinematics.registry`, `ctrplan.planning.budget`); this script measures that rate on the
machine it runs on, the way `plan` searches: the skull-base scene, RRT (it uses its whole budget
there: no solution within it), one core (numba and BLAS as `plan` sets them), each backend's work
budget from its registered rate x ``--seconds``, ``--seeds`` seeded runs; the rate of a run is its
states over its search time (goal sampling included), and over the CPU time the process used for
it (on a machine shared with other work, the rate an idle core would give). Prints a table, the
machine (CPU, cores, load average before and after) and the registered rates beside the measured
ones; ``--json`` prints the record. Run it on an otherwise idle machine, under the lock of shared
machines:

    flock /work/heavy.lock python scripts/reference_rates.py --seconds 10 --seeds 3
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

from ctrplan.base.machine import machine_info
from ctrplan.kinematics.registry import BACKEND_KINDS
from ctrplan.planning import ConfigurationChecker, PlanningModel, resolve_backend
from ctrplan.planning.budget import states_for
from ctrplan.planning.planner import compile_kernels, search
from ctrplan.scene.loader import load_scene

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "skullbase.yaml"


def measure(backend_name: str, seconds: float, seeds: int, planner: str) -> dict:
    """One backend's runs: states, search seconds and rate per seed, and their median rate."""
    scene = load_scene(SCENE)
    model = PlanningModel.build(scene, resolve_backend(backend_name, scene.robot))
    compile_kernels(model)
    runs = []
    for seed in range(seeds):
        checker = ConfigurationChecker(model)
        t, cpu = time.perf_counter(), time.process_time()
        out = search(checker, planner=planner, max_states=states_for(backend_name, seconds), seed=seed,
                     simplify=False, time_limit_s=seconds)
        wall, cpu = time.perf_counter() - t, time.process_time() - cpu
        states = out.budget["states"]
        runs.append({"seed": seed, "states": states, "search_s": round(wall, 3), "cpu_s": round(cpu, 3),
                     "states_per_s": round(states / wall, 1), "states_per_cpu_s": round(states / cpu, 1),
                     "solved": out.path_q is not None})
    used = [r for r in runs if not r["solved"]] or runs  # searches that used their whole budget
    return {"backend": backend_name, "planner": planner, "runs": runs,
            "median_states_per_s": round(statistics.median(r["states_per_s"] for r in used), 1),
            "median_states_per_cpu_s": round(statistics.median(r["states_per_cpu_s"] for r in used), 1),
            "registered_states_per_s": BACKEND_KINDS[backend_name].reference_states_per_s}


def main() -> None:
    from ompl import util as ou

    ou.setLogLevel(ou.LOG_WARN)
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--backends", default=",".join(BACKEND_KINDS))
    parser.add_argument("--seconds", type=float, default=10.0, help="work budget: what this many seconds buy")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--planner", default="rrt")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    load_before = os.getloadavg()
    results = [measure(name, args.seconds, args.seeds, args.planner) for name in args.backends.split(",")]
    record = {"machine": machine_info() | {"load_before": [round(v, 2) for v in load_before],
                                           "load_after": [round(v, 2) for v in os.getloadavg()]},
              "scene": str(SCENE.name), "seconds": args.seconds, "results": results}
    if args.json:
        print(json.dumps(record, indent=2))
        return
    m = record["machine"]
    print(f"{m['cpu']}, {m['cores']} cores; load average before {m['load_before']}, after {m['load_after']}")
    print(f"{'backend':<10} {'planner':<8} {'states/s (wall)':>16} {'states/CPU-s':>13} {'registered':>11}  "
          f"runs (states/s wall)")
    for r in results:
        runs = ", ".join(f"{x['states_per_s']:,.0f}" + (" solved" if x["solved"] else "") for x in r["runs"])
        print(f"{r['backend']:<10} {r['planner']:<8} {r['median_states_per_s']:>16,.0f} "
              f"{r['median_states_per_cpu_s']:>13,.0f} {r['registered_states_per_s']:>11,.0f}  {runs}")


if __name__ == "__main__":
    main()
