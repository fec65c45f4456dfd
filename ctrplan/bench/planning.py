"""Planning benchmark: every backend x planner on a scene, N seeded runs each.

One run is `ctrplan.planning.plan` (search, exact re-validation, repair) on one (scene, backend,
planner, seed); `run_one` turns it into a flat record (times in s, lengths in mm) and `summarize`
aggregates the records per (scene, backend, planner). Every backend x planner pair gets the same seeds,
so their runs are paired. Runs are independent and deterministic for a seed (OMPL is re-seeded per run,
and every search is budgeted in work, `ctrplan.planning.budget`): `ctrplan.base.parallel` spreads them
over processes or a Ray cluster with the same content, whatever the load -- except a run whose
wall-clock guard fired (``cut_short``: counted in the summary).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass
from itertools import product
from pathlib import Path
from typing import Any

import numpy as np

#: Record fields that depend only on the seed, not on timing: equal for equal seeds on any executor.
CONTENT_FIELDS = ("scene", "backend", "planner", "seed", "solved", "status", "found", "repaired",
                  "path_states", "path_length_mm", "tip_travel_mm", "max_states", "states")


@dataclass(frozen=True)
class RunSpec:
    """One planning run: scene file, backend and planner names, seed, time budget (s) and work budget
    (states; None: what the time budget buys with the backend on the reference machine)."""

    scene: str
    backend: str
    planner: str
    seed: int
    time_limit_s: float
    max_states: int | None = None

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def make_specs(scenes: list[tuple[str, float]], backends: list[str], planners: list[str], runs: int,
               first_seed: int = 0, max_states: int | None = None) -> list[RunSpec]:
    """All runs: for each (scene file, time budget s), backend, planner, the seeds
    ``first_seed .. first_seed + runs - 1``; ordered so that early results cover every pair."""
    return [RunSpec(scene, backend, planner, first_seed + k, limit, max_states)
            for k, (scene, limit), backend, planner in product(range(runs), scenes, backends, planners)]


#: Most runs in one job of `batches` (a job loads its scenes and backends once).
BATCH_RUNS = 10
#: States, and states per call of the batched form, of `check_rates`.
RATE_STATES = 1000
RATE_BATCH = 64
#: Spread (mm, planning metric) of the states of `check_rates` around the scene's start.
RATE_SPREAD_MM = 10.0


class RunContext:
    """Scenes with their collision worlds, and planning backends with their exact companions
    (`ctrplan.kinematics.registry.exact_companion`, as `plan` pairs them), of a job's runs, each built
    once (a PINN warms up its compiled kernels, a scene builds its BVH and loads its distance grid):
    later runs of the job reuse them."""

    def __init__(self) -> None:
        self._scenes: dict[str, tuple[Any, Any]] = {}
        self._backends: dict[tuple[str, str], tuple[Any, Any]] = {}

    def get(self, scene_file: str, backend: str) -> tuple[Any, Any, Any, Any]:
        """Scene, planning backend, its exact companion and the collision world of ``scene_file`` and
        ``backend``."""
        from ctrplan.collision.world import CollisionWorld
        from ctrplan.kinematics import exact_companion, make_backend
        from ctrplan.scene.loader import load_scene

        if scene_file not in self._scenes:
            scene = load_scene(scene_file)
            self._scenes[scene_file] = (scene, CollisionWorld.from_scene(scene))
        scene, world = self._scenes[scene_file]
        key = (scene_file, backend)
        if key not in self._backends:
            planning = make_backend(backend, scene.robot)
            self._backends[key] = (planning, exact_companion(planning, scene.robot))
        return (scene, *self._backends[key], world)


def batches(specs: list[RunSpec], workers: int = 1) -> list[tuple[RunSpec, ...]]:
    """``specs`` as jobs for `run_batch`: runs of one scene and backend together (they share what
    `RunContext` loads), at most `BATCH_RUNS` and about an even share of ``workers`` per job."""
    groups: dict[tuple[str, str], list[RunSpec]] = {}
    for spec in specs:
        groups.setdefault((spec.scene, spec.backend), []).append(spec)
    out = []
    for group in groups.values():
        size = max(1, min(BATCH_RUNS, math.ceil(len(group) / max(1, workers))))
        out += [tuple(group[a:a + size]) for a in range(0, len(group), size)]
    return out


def run_batch(batch: tuple[RunSpec, ...]) -> dict[str, Any]:
    """`run_one` of every spec of ``batch`` with one `RunContext`: ``{"records": [...]}``."""
    context = RunContext()
    return {"records": [run_one(spec, context) for spec in batch]}


def run_all(specs: list[RunSpec], *, workers: int = 1, ray_address: str | None = None,
            tick: Callable[[int, int], None] | None = None, threads: int = 1) -> list[dict[str, Any]]:
    """The records of ``specs`` (in their order), run in `batches` on the executor of
    `ctrplan.base.parallel.run_jobs` (``threads``: cores of a run, one worker only); ``tick(runs done,
    runs)`` after every batch (runs done: about, where batches of different sizes finish out of
    order)."""
    from ctrplan.base.parallel import run_jobs

    jobs = batches(specs, workers)

    def jobs_done(done: int, _total: int) -> None:
        if tick is not None:
            tick(sum(map(len, jobs[:done])), len(specs))

    results = run_jobs(run_batch, jobs, workers=workers, ray_address=ray_address, tick=jobs_done,
                       threads=threads)
    by_spec = {spec: record for job, result in zip(jobs, results, strict=True)
               for spec, record in zip(job, result["records"], strict=True)}
    return [by_spec[spec] for spec in specs]


def run_one(spec: RunSpec, context: RunContext | None = None) -> dict[str, Any]:
    """Plan ``spec`` and return its record: outcome, exact validation, time split, work counters;
    scenes and backends from ``context`` (default: a new one)."""
    from ompl import util as ou

    from ctrplan.planning import plan

    scene, backend, exact, world = (context or RunContext()).get(spec.scene, spec.backend)
    ou.setLogLevel(ou.LOG_ERROR)
    result = plan(scene, backend, planner=spec.planner, time_limit_s=spec.time_limit_s,
                  max_states=spec.max_states, seed=spec.seed, exact=exact, world=world,
                  wall_limit=False)  # a benchmark's verdicts are decided by work, as documented
    counters = result.work.counters
    total = float(result.planning_time_s)
    kin, col = float(counters.kinematics_s), float(counters.collision_s)
    report = result.validated
    dense = result.dense
    tip_travel = (float(np.linalg.norm(np.diff(dense.exact.tip_mm, axis=0), axis=1).sum())
                  if dense is not None and len(dense.dense_q) > 1 else None)
    path_length = None
    if len(result.path) > 1:
        from ctrplan.planning.space import BoxSpace

        space = BoxSpace.for_scene(scene)
        path_length = float(space.distance(result.path[1:], result.path[:-1]).sum())
    calls = int(result.kinematics_calls)
    return {
        **spec.to_json(),
        "scene_name": scene.name,
        "max_states": int(result.max_states),
        "states": int(result.states),
        "cut_short": bool(result.cut_short),
        "solved": bool(result.solved),
        "status": result.status,
        "found": report is not None,
        "repaired": bool(report is not None and report.repaired),
        "exact_collision_free": None if report is None else bool(report.collision_free),
        "exact_tip_in_target": None if report is None else bool(report.tip_in_target),
        "min_clearance_mm": None if report is None else _round(report.min_clearance_mm),
        "max_position_error_mm": None if report is None else _round(report.max_position_error_mm),
        "planning_time_s": _round(total),
        "kinematics_s": _round(kin),
        "collision_s": _round(col),
        "planner_s": _round(max(total - kin - col, 0.0)),
        "validation_s": _round(result.work.validation_time_s or 0.0),
        "kinematics_calls": calls,
        "collision_checks": int(counters.collision_checks),
        "narrow_checks": int(counters.narrow_checks),
        "grid_contacts": int(counters.grid_contacts),
        "fcl_tests": int(counters.fcl_tests),
        "checks_per_s": _round(calls / total if total > 0 else 0.0, 1),
        "path_states": int(len(result.path)),
        "path_length_mm": None if path_length is None else round(path_length, 3),
        "tip_travel_mm": None if tip_travel is None else round(tip_travel, 3),
        "message": result.message,
    }


def check_rates(scene_file: str, backend: str, *, states: int = RATE_STATES, batch: int = RATE_BATCH,
                seed: int = 0, context: RunContext | None = None) -> dict[str, Any]:
    """Validity checks per second on one core, one state per call (`ConfigurationChecker.is_valid`,
    the planner's state path) against ``batch`` states per call (`ConfigurationChecker.check`: one
    backend call and one vectorised broadphase call per batch, FCL only on the capsules the broadphase
    cannot clear), on the same ``states`` seeded states scattered around the scene's start (normal,
    `RATE_SPREAD_MM` in the planning metric: where a search expands, valid and colliding ones), with
    the planning model `plan` builds (margins, stability decision). ``agree``: both give the same
    verdicts. Times depend on the machine and its load."""
    import time

    from ctrplan.base.machine import single_core
    from ctrplan.planning import ConfigurationChecker, PlanningModel, compile_kernels

    scene, be, exact, world = (context or RunContext()).get(scene_file, backend)
    model = PlanningModel.build(scene, be, exact, world)
    space = model.space
    y = space.to_coords(scene.start) + np.random.default_rng(seed).normal(
        scale=RATE_SPREAD_MM, size=(states, space.dimension))
    q = space.to_joints(space.clip(y))
    with single_core():
        compile_kernels(model)
        warm = ConfigurationChecker(model)  # compiled paths of both forms, before the clocks
        warm.check(q[-batch:])
        for x in q[-8:]:
            warm.is_valid(x)
        single, batched = ConfigurationChecker(model), ConfigurationChecker(model)
        t0 = time.perf_counter()
        one = np.array([single.is_valid(x) for x in q])
        t1 = time.perf_counter()
        many = np.concatenate([batched.check(q[a:a + batch]) for a in range(0, states, batch)])
        t2 = time.perf_counter()
    return {"scene": scene.name, "backend": backend, "states": states, "batch": batch,
            "valid_share": round(float(one.mean()), 4), "agree": bool(np.array_equal(one, many)),
            "single_checks_per_s": _round(states / (t1 - t0), 1),
            "batched_checks_per_s": _round(states / (t2 - t1), 1),
            "speedup": _round((t1 - t0) / (t2 - t1), 2)}


def describe_rates(rates: dict[str, Any]) -> str:
    """One line of `check_rates`: scene, backend, checks per second single and batched."""
    return (f"{rates['scene']} / {rates['backend']}: validity checks/s {rates['single_checks_per_s']:.0f} "
            f"one state per call, {rates['batched_checks_per_s']:.0f} {rates['batch']} per call "
            f"(x{rates['speedup']:.1f})")


def _round(x: float | None, digits: int = 5) -> float | None:
    return None if x is None or not math.isfinite(float(x)) else round(float(x), digits)


def _stats(values: list[float]) -> dict[str, float | None]:
    """min/median/p90/max/mean and coefficient of variation of ``values`` (None when empty)."""
    v = np.asarray([x for x in values if x is not None], dtype=float)
    if v.size == 0:
        return dict.fromkeys(("min", "median", "p90", "max", "mean", "cv"))
    mean = float(v.mean())
    return {"min": _round(v.min(), 4), "median": _round(np.median(v), 4),
            "p90": _round(np.percentile(v, 90), 4), "max": _round(v.max(), 4), "mean": _round(mean, 4),
            "cv": _round(float(v.std()) / mean if mean > 0 else 0.0, 3)}


def summarize(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per (scene, backend, planner): success, exact-validation outcome, planning-time distribution
    (all runs; an unsolved run counts with the time it used), mean time split, work rates, paths."""
    groups: dict[tuple[str, str, str], list[dict]] = {}
    for r in records:
        groups.setdefault((r["scene_name"], r["backend"], r["planner"]), []).append(r)
    out = []
    for (scene, backend, planner), rs in groups.items():
        solved = [r for r in rs if r["solved"]]
        mean = {k: float(np.mean([r[k] for r in rs])) for k in ("kinematics_s", "collision_s", "planner_s")}
        total = sum(mean.values()) or 1.0
        out.append({
            "scene": scene, "backend": backend, "planner": planner, "runs": len(rs),
            "time_limit_s": rs[0]["time_limit_s"],
            "max_states": rs[0].get("max_states"),
            "cut_short": sum(bool(r.get("cut_short")) for r in rs),
            "solved": len(solved), "success_rate": round(len(solved) / len(rs), 4),
            "found": sum(r["found"] for r in rs),
            "repaired": sum(r["repaired"] for r in rs),
            "unsafe": sum(r["found"] and not r["solved"] for r in rs),
            "planning_time_s": _stats([r["planning_time_s"] for r in rs]),
            "solved_time_s": _stats([r["planning_time_s"] for r in solved]),
            "time_split_s": {k.removesuffix("_s"): _round(v, 4) for k, v in mean.items()},
            "time_share": {k.removesuffix("_s"): round(v / total, 3) for k, v in mean.items()},
            "validation_s": _stats([r["validation_s"] for r in rs]),
            "checks_per_s": _stats([r["checks_per_s"] for r in rs]),
            "narrow_share": _stats([r["narrow_checks"] / r["collision_checks"] for r in rs
                                    if r.get("collision_checks") and "narrow_checks" in r]),
            "fcl_tests_per_check": _stats([r["fcl_tests"] / r["collision_checks"] for r in rs
                                           if r.get("collision_checks") and "fcl_tests" in r]),
            "kinematics_calls": _stats([r["kinematics_calls"] for r in rs]),
            "path_length_mm": _stats([r["path_length_mm"] for r in solved]),
            "tip_travel_mm": _stats([r["tip_travel_mm"] for r in solved]),
            "max_position_error_mm": _stats([r["max_position_error_mm"] for r in rs]),
            "min_clearance_mm": _stats([r["min_clearance_mm"] for r in solved]),
        })
    return out


def prepare(scene_files: list[Path], backends: list[str], time_limit_s: float | None
            ) -> list[tuple[str, float]]:
    """(scene file, time budget s) per scene: ``time_limit_s`` or the scene's own setting.

    Loads every scene and builds every backend for its robot once here, so that a bad scene file or
    a missing or mismatched model is reported before any run starts (not from inside a worker), and
    each scene's broadphase grid, so that workers load it from the disk cache."""
    from ctrplan.collision.broadphase import grid_for
    from ctrplan.kinematics import make_backend
    from ctrplan.scene.loader import load_scene

    out = []
    for f in scene_files:
        scene = load_scene(f)
        grid_for(scene.obstacles)
        for name in dict.fromkeys(backends):
            make_backend(name, scene.robot)
        out.append((str(Path(f).resolve()), float(time_limit_s or scene.settings.time_limit_s)))
    return out
