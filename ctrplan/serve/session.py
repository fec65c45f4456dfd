"""One planning session of `ctrplan serve`: a scene whose structures may move, its planner (a roadmap
repaired as tissue moves, else the single-query planner -- also where the roadmap has no path, e.g.
when moved tissue blocks its routes), the target and the last answer.

Every request -- from the page or the JSON API -- goes through `PlanSession`, one at a time (a lock):
`plan` answers a target with a document shaped like one entry of ``plan --roadmap --targets --json``,
`move` shifts a structure (the roadmap is repaired, the collision world changed around it), `save`
writes what ``plan --out`` writes for the last answer. Results are computed here and rendered by the
page (`ctrplan.serve.page`) and the API (`ctrplan.serve.api`).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ctrplan.base.errors import InputError
from ctrplan.base.machine import numba_threads_at_most
from ctrplan.kinematics.base import Backend
from ctrplan.kinematics.blas import single_threaded_blas
from ctrplan.planning import plan
from ctrplan.planning.execution import DEFAULT_RATE_HZ, trajectory_table
from ctrplan.planning.result import PlanResult
from ctrplan.planning.roadmap._adapter import PlanningContext, planning_context, with_world
from ctrplan.planning.roadmap.query import QueryResult, RoadmapPlanner
from ctrplan.planning.roadmap.repair import BLOCKED, SUSPECT, LiveRoadmap, Repair
from ctrplan.planning.roadmap.store import fingerprints, load_roadmap
from ctrplan.planning.roadmap.sweep import SweepIndex, build_sweep
from ctrplan.planning.validate import measure_clearance
from ctrplan.scene.objects import Scene, TargetRegion
from ctrplan.serve.render import state_clearances
from ctrplan.viz.plan_outputs import plan_document, write_plan_outputs

#: Largest shift (mm) of a structure from its place in the scene file that `move` accepts.
MAX_SHIFT_MM = 30.0


@dataclass
class Answer:
    """A planned target: the result (`QueryResult`: also what the single-query planner found), the
    `PlanResult` the ``plan --out`` writers take, the clearance to every structure along the path
    (nearest first; empty until measured, and without a path), the scene it was planned in, a
    running number, and the distance grid's lower bound of every capsule's clearance along the path
    ((K, P-1) mm, `ctrplan.serve.render.state_clearances`; None without a path): what the page
    colours the path by at once, before the exact clearances are measured."""

    result: QueryResult
    plan_result: PlanResult
    structures: list[dict]
    scene: Scene
    number: int
    capsule_clearance_mm: np.ndarray | None = None

    def to_json(self) -> dict:
        """One entry of ``plan --roadmap --targets --json`` plus ``structures`` and ``number``."""
        return {**self.result.to_json(), "planner": self.plan_result.planner, "structures": self.structures,
                "number": self.number}


class PlanSession:
    """The state behind `ctrplan serve` (see the module docstring). ``roadmap_dir``: answer from the
    roadmap there (its sweep index is built and saved beside it when missing, `progress` told), else
    plan each target from scratch."""

    def __init__(self, scene: Scene, backend: Backend, model: str | None = None,
                 roadmap_dir: Path | None = None, progress=lambda text: None):
        self.lock = threading.RLock()
        self.model, self.roadmap_dir = model, roadmap_dir
        progress("compiling kernels (first run only)")
        ctx = planning_context(scene, backend)
        self.live: LiveRoadmap | None = None
        self.planner: RoadmapPlanner | None = None
        if roadmap_dir is not None:
            rm = load_roadmap(roadmap_dir, fingerprints(scene, backend))
            index = SweepIndex.load(roadmap_dir, rm)
            if index is None:
                progress(f"indexing the roadmap's sweep of the workspace ({rm.n_nodes:,} nodes, "
                         f"{len(rm.edges):,} edges; once)")
                index = build_sweep(ctx, rm, lambda done, total: progress(
                    f"indexing the roadmap's sweep: {done:,}/{total:,} elements"))
                index.save(roadmap_dir)
            self.live = LiveRoadmap(ctx, rm, index)
            self.planner = RoadmapPlanner(ctx, rm, self.live)
        self._ctx = ctx
        #: the start's exact backbone, what the outputs show without a path
        self.start = ctx.exact.forward(scene.start, points=scene.settings.points, check=False)
        self._shifts: dict[str, np.ndarray] = {}  # without a roadmap (the roadmap keeps its own)
        self.target = scene.target
        self.last: Answer | None = None
        self.repairs: list[Repair] = []
        self.count = 0

    @property
    def ctx(self) -> PlanningContext:
        """The planning context of the scene as it is now (moved structures in place)."""
        return self.live.ctx if self.live is not None else self._ctx

    @property
    def scene(self) -> Scene:
        return self.ctx.scene

    def shift_of(self, name: str) -> np.ndarray:
        """The shift (3,) (mm) of structure ``name`` from its place in the scene file."""
        return self.live.shift_of(name) if self.live is not None else self._shifts.get(name, np.zeros(3))

    # ---- requests ---------------------------------------------------------------------------------
    def plan(self, center_mm, tolerance_mm: float, use: str = "any", clearances: bool = True) -> Answer:
        """Answer the sphere of ``tolerance_mm`` around ``center_mm`` (scene frame, mm): from the
        roadmap, and where it has no path (or there is none) by the single-query planner; ``use``
        ``roadmap``: the roadmap's answer only (when there is one), ``single``: the single-query
        planner only. With ``clearances`` the exact clearance to every structure along the path
        (`measure`) too."""
        region = TargetRegion.sphere(np.asarray(center_mm, dtype=float), float(tolerance_mm))
        with self.lock, numba_threads_at_most(1), single_threaded_blas():
            # one core: the browser showing the page draws on the other (and on a busy machine a
            # two-thread region waits for its second thread: a validation took 54-77 ms on two,
            # 34-55 ms on one, beside other jobs)
            scene = replace(self.scene, target=region)
            result = None if self.planner is None or use == "single" else self.planner.answer(region)
            if result is not None and (result.solved or use == "roadmap"):
                planned = _as_plan_result(result, scene, self.ctx.backend.name, self.start)
            else:  # no roadmap, or it has no path (tissue moved across its routes): plan from scratch
                planned = plan(scene, self.ctx.loaded, exact=self.ctx.exact, world=self.ctx.checker.world)
                if result is not None:
                    planned = replace(planned, message=f"{planned.message} (single-query planner: the "
                                                       f"roadmap had no path, {result.message})")
                result = _as_query_result(planned, region)
            self.count += 1
            self.target = region
            dense = result.dense
            bound = None if dense is None else state_clearances(
                self.ctx.checker.world, scene.to_scene(dense.exact.positions_mm), dense.exact.radius_mm)[1]
            self.last = Answer(result, planned, [], scene, self.count, bound)
            if clearances:
                self.measure(self.last)
            return self.last

    def measure(self, answer: Answer) -> Answer:
        """Measure the clearances of ``answer``'s path once (`measure_clearance`: every capsule, and
        every structure's nearest approach, nearest first in ``answer.structures``; FCL distances, a
        few hundred ms on the skull base; nothing without a path)."""
        dense = answer.plan_result.dense
        if dense is not None and dense.clearance_mm is None:
            dense = measure_clearance(replace(self.ctx.checker.model, scene=answer.scene), dense)
            answer.plan_result = replace(answer.plan_result, dense=dense)
            answer.structures = sorted((c.to_json() for c in dense.report.structures), key=_nearest_first)
        return answer

    def move(self, name: str, translation_mm) -> dict:
        """Move structure ``name`` by ``translation_mm`` (3,) (mm, scene frame) from where it is now;
        the roadmap is repaired. Returns the structure's shift from its scene-file place and the
        repair record (None without a roadmap)."""
        with self.lock:
            names = [o.name for o in self.scene.obstacles]
            if name not in names:
                raise InputError(f"no structure named {name!r} (structures: {', '.join(names)})")
            shift = self.shift_of(name) + np.asarray(translation_mm, dtype=float)
            if np.linalg.norm(shift) > MAX_SHIFT_MM:
                raise InputError(f"translation_mm: {name} would be {np.linalg.norm(shift):.1f} mm from its "
                                 f"place in the scene file; at most {MAX_SHIFT_MM:g} mm")
            t0 = time.perf_counter()
            if self.live is not None:
                rep = self.live.move(name, shift)
                self.repairs.append(rep)
                self.planner = RoadmapPlanner(self.live.ctx, self.live.roadmap, self.live)
                record = rep.to_json()
            else:
                original = next(o for o in self._ctx.scene.obstacles if o.name == name)
                moved = original.translated(shift)
                scene = replace(self.scene, obstacles=tuple(moved if o.name == name else o
                                                             for o in self.scene.obstacles))
                self._ctx = with_world(self._ctx, scene, self._ctx.checker.world.moved(moved))
                self._shifts[name] = shift
                record = None
            return {"structure": name, "shift_mm": np.round(shift, 4).tolist(), "repair": record,
                    "seconds": round(time.perf_counter() - t0, 4)}

    def save(self, out: Path, scene_file: Path) -> list[Path]:
        """Write ``plan --out``'s files for the last answer into ``out``; the paths written."""
        with self.lock:
            if self.last is None:
                raise InputError("nothing planned yet: no plan to write")
            a = self.measure(self.last)
            doc = plan_document(a.plan_result, a.scene, scene_file, self.model)
            trajectory = trajectory_table(a.scene, a.plan_result.path, DEFAULT_RATE_HZ,
                                          self.ctx.checker.world) if a.plan_result.solved else None
            write_plan_outputs(out, a.scene, a.plan_result, doc, trajectory)
            names = ["path.json", "trajectory.csv", "obstacles.ply", "plan.png", "plan.html"]
            return [out / n for n in names if (out / n).exists()]

    def describe(self) -> dict:
        """``GET /api/scene``: structures (name, margin, shift), base pose, target, roadmap summary."""
        with self.lock:
            sc, t = self.scene, self.target
            roadmap = None
            if self.live is not None:
                rm = self.live.built
                live = self.live
                roadmap = {"folder": str(self.roadmap_dir), "nodes": rm.n_nodes, "edges": len(rm.edges),
                           "blocked_nodes": int((live.node_state == BLOCKED).sum()),
                           "blocked_edges": int((live.edge_state == BLOCKED).sum()),
                           "suspect_nodes": int((live.node_state == SUSPECT).sum()),
                           "suspect_edges": int((live.edge_state == SUSPECT).sum()),
                           "connected_nodes": int(live.roadmap.connected.sum()),
                           "build_s": rm.meta.get("build_s"), "backend": rm.meta.get("backend"),
                           "reach": rm.meta.get("reach"), "repairs": len(self.repairs),
                           "lazy_checks": {k: round(v, 4) if isinstance(v, float) else v
                                           for k, v in live.lazy.items()}}
            return {"scene": sc.name,
                    "structures": [{"name": o.name, "margin_mm": float(o.margin_mm),
                                    "shift_mm": np.round(self.shift_of(o.name), 4).tolist()}
                                   for o in sc.obstacles],
                    "base_pose": np.asarray(sc.base_pose).tolist(),
                    "target": {"center_mm": t.center.tolist(), "tolerance_mm": t.tolerance_mm,
                               "region": t.to_dict()},
                    "planner": "roadmap" if self.live is not None else "single-query",
                    "roadmap": roadmap}


def _nearest_first(c: dict) -> float:
    return np.inf if c["clearance_mm"] is None else c["clearance_mm"]


def _as_plan_result(result: QueryResult, scene: Scene, backend: str, start) -> PlanResult:
    """A roadmap answer as the `PlanResult` the ``plan --out`` writers take (planner ``roadmap``;
    ``start``: the start's exact backbone)."""
    return PlanResult(result.solved, "roadmap", backend, scene.name, scene.target.center,
                      scene.target.tolerance_mm, scene.base_pose, np.asarray(result.path),
                      status="Exact solution" if result.solved else "", message=result.message,
                      planning_time_s=result.query_time_s, dense=result.dense, start=start)


def _as_query_result(planned: PlanResult, region: TargetRegion) -> QueryResult:
    """A single-query plan as a roadmap answer (its planning time as the query time)."""
    return QueryResult(region, planned.solved, np.asarray(planned.path), planned.planning_time_s,
                       float(planned.work.validation_time_s or 0.0), planned.validated, planned.dense,
                       1, planned.message)
