"""Roadmap benchmark: query times of a roadmap against single-query planning on random targets.

Targets are points drawn uniformly in a region (by default the scene's target, e.g. the sella of
``skullbase``), each a sphere of ``tolerance_mm``. Every target is answered from the roadmap
(`ctrplan.planning.roadmap.query`: query time, then exact validation timed separately) and, unless
skipped, planned from scratch by `ctrplan.planning.plan` (RRTConnect, seeded). Records have the keys
of `ctrplan.bench.planning` records, so they go into the same OMPL log and Planner Arena database
(planner ``roadmap``).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from ctrplan.planning.roadmap.query import QueryResult, RoadmapPlanner
from ctrplan.scene.objects import Scene, TargetRegion

#: Planner name of roadmap records in logs and databases.
ROADMAP_PLANNER = "roadmap"


def random_targets(region: TargetRegion, n: int, tolerance_mm: float, seed: int) -> list[TargetRegion]:
    """``n`` spheres of radius ``tolerance_mm`` (mm) centred uniformly in ``region`` (scene frame)."""
    rng = np.random.default_rng(seed)
    return [TargetRegion.sphere(p, tolerance_mm) for p in region.sample(n, rng)]


def _record(scene: Scene, target: TargetRegion, planner: str, backend: str, seed: int, time_limit_s: float,
            **fields: Any) -> dict[str, Any]:
    return {"scene": str(scene.path), "scene_name": scene.name, "planner": planner, "backend": backend,
            "seed": seed, "time_limit_s": time_limit_s, "target_mm": target.center.round(4).tolist(),
            "tolerance_mm": float(target.tolerance_mm), **fields}


def roadmap_record(scene: Scene, backend: str, seed: int, result: QueryResult) -> dict[str, Any]:
    """The record of one roadmap answer (``planning_time_s`` is its query time)."""
    v = result.validated
    found = result.path.size > 0
    return _record(scene, result.target, ROADMAP_PLANNER, backend, seed, 0.0,
                   planning_time_s=result.query_time_s, validation_s=result.validation_time_s,
                   solved=bool(result.solved), found=found,
                   status="Exact solution" if found else "Invalid goal", repaired=result.attempts > 1,
                   exact_collision_free=None if v is None else bool(v.collision_free),
                   exact_tip_in_target=None if v is None else bool(v.tip_in_target),
                   max_position_error_mm=None if v is None else _finite(v.max_position_error_mm),
                   path_states=int(len(result.path)), message=result.message,
                   steps={k: round(v, 6) if isinstance(v, float) else v
                          for k, v in getattr(result, "steps", {}).items()})  # (older answers had none)


def single_record(scene: Scene, backend, target: TargetRegion, seed: int, time_limit_s: float,
                  exact) -> dict[str, Any]:
    """Plan ``target`` from scratch (RRTConnect, ``seed``) and return its record."""
    from ompl import util as ou

    from ctrplan.planning import plan

    ou.setLogLevel(ou.LOG_ERROR)
    res = plan(replace(scene, target=target), backend, planner="rrtconnect", time_limit_s=time_limit_s,
               seed=seed, exact=exact)
    v = res.validated
    counters, validation_s = res.work.counters, res.work.validation_time_s
    return _record(scene, target, "rrtconnect", res.backend, seed, time_limit_s,
                   planning_time_s=float(res.planning_time_s),
                   validation_s=float(validation_s or 0.0), solved=bool(res.solved),
                   found=v is not None, status=res.status, repaired=bool(v is not None and v.repaired),
                   exact_collision_free=None if v is None else bool(v.collision_free),
                   exact_tip_in_target=None if v is None else bool(v.tip_in_target),
                   max_position_error_mm=None if v is None else _finite(v.max_position_error_mm),
                   kinematics_calls=int(res.kinematics_calls),
                   kinematics_s=float(counters.kinematics_s), collision_s=float(counters.collision_s),
                   path_states=int(len(res.path)), message=res.message)


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def run(planner: RoadmapPlanner, targets: list[TargetRegion], *, backend_name: str, seed: int,
        single: tuple[Any, Any, float] | None, tick=None) -> list[dict[str, Any]]:
    """Roadmap records for every target, then (``single`` = (backend, exact backend, time limit s))
    single-query records with seeds ``seed``, ``seed + 1``, ...; ``tick(done, total)`` after each."""
    scene = planner.ctx.scene
    total = len(targets) * (2 if single else 1)
    records = []
    for i, target in enumerate(targets):
        records.append(roadmap_record(scene, backend_name, seed + i, planner.answer(target)))
        if tick:
            tick(len(records), total)
    if single:
        backend, exact, limit = single
        for i, target in enumerate(targets):
            records.append(single_record(scene, backend, target, seed + i, limit, exact))
            if tick:
                tick(len(records), total)
    return records


def _ms(values: list[float]) -> dict[str, float | None]:
    v = np.asarray(values, dtype=float) * 1e3
    if not v.size:
        return {"median_ms": None, "p95_ms": None, "max_ms": None}
    return {"median_ms": round(float(np.median(v)), 3), "p95_ms": round(float(np.percentile(v, 95)), 3),
            "max_ms": round(float(v.max()), 3)}


def summarize(records: list[dict[str, Any]]) -> dict[str, Any]:
    """Per planner: solved, unsafe (a path found whose exact validation failed), query (planning) and
    validation time distributions; and the roadmap's solve rate on the targets RRTConnect solves."""
    out: dict[str, Any] = {}
    for name in dict.fromkeys(r["planner"] for r in records):
        rs = [r for r in records if r["planner"] == name]
        solved = [r for r in rs if r["solved"]]
        out[name] = {"targets": len(rs), "solved": len(solved),
                     "unsafe": sum(r["found"] and not r["solved"] and r["exact_collision_free"] is False
                                   for r in rs),
                     "time": _ms([r["planning_time_s"] for r in rs]),
                     "validation": _ms([r["validation_s"] for r in solved])}
        cpu = [r["steps"]["cpu_s"] for r in rs if "cpu_s" in r.get("steps", {})]
        if cpu:
            out[name]["cpu_time"] = _ms(cpu)  # the roadmap query's own CPU seconds
    road = {tuple(r["target_mm"]): r["solved"] for r in records if r["planner"] == ROADMAP_PLANNER}
    single = [tuple(r["target_mm"]) for r in records if r["planner"] == "rrtconnect" and r["solved"]]
    if single:
        hit = sum(road.get(t, False) for t in single)
        out["roadmap_on_single_solved"] = {"single_solved": len(single), "roadmap_solved": hit,
                                           "rate": round(hit / len(single), 4)}
    return out
