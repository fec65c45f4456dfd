"""Answer targets from a roadmap: connect the target, read the path off the shortest-path tree.

A query (`RoadmapPlanner.query`) takes the connected nodes whose tips lie nearest the target
(KD-tree on the stored tips), moves copies of them into the target by a few batched IK iterations,
checks the short connecting edges of the cheapest candidates (start-to-node distance along the tree
plus the edge) in one batched call, checks the end of the best valid one (its last waypoints) with the
exact model -- where a roadmap path fails exactly, it fails near the anatomy it ends in -- and returns
the tree path to it plus its IK state; a path whose exact tip misses the target gets the exact goal
correction of the single-query planner. ``query_time_s`` covers all that; the exact re-validation of
the whole path (`RoadmapPlanner.answer`) is timed separately (the planning backend's error against
the exact model along the path is added to its report afterwards, untimed: a report, not a check).
When it rejects a path, the next candidate is tried (local repair: that time counts as query time).
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.spatial import cKDTree

from ctrplan.base.machine import numba_threads_at_most
from ctrplan.kinematics.blas import single_threaded_blas
from ctrplan.planning.roadmap._adapter import (
    PlanningContext,
    add_model_error,
    check_edges,
    check_states,
    exact_end_check,
    exact_goal_state,
    inverse_kinematics,
    tip_directions,
    validate,
)
from ctrplan.planning.roadmap.store import Roadmap
from ctrplan.scene.objects import TargetRegion

if TYPE_CHECKING:
    from ctrplan.planning.roadmap.repair import LiveRoadmap

#: Connected nodes whose tips are nearest the target that IK starts from.
NEAREST = 24
#: IK iterations per query (the nearest tips lie within a few mm).
IK_ITERATIONS = 8
#: Candidate connections checked per batched call.
CHECK_BATCH = 2
#: Candidates whose exact validation may fail before the query gives up.
MAX_ATTEMPTS = 3
#: Waypoints at the end of a candidate path checked with the exact model before it is chosen (the
#: last state: its exact tip decides the goal correction; the rest is left to the exact validation).
EXACT_TAIL = 1
#: Tree paths to one node tried on a live roadmap (each found blocked changes the tree), and paths
#: found blocked in one query before it gives up (each costs a new shortest-path tree).
LAZY_TRIES = 8
LAZY_TREES = 12
#: A node ends a path itself when its tip lies this far (mm) inside the target (the planning
#: backend's tip error leaves the exact tip inside too, no exact goal correction needed).
DIRECT_INSET_MM = 0.2


@dataclass
class QueryResult:
    """One target's answer: ``path`` (K, 2N) from the start (empty when not solved), the times, the
    exact validation report (None when no path) and a message."""

    target: TargetRegion
    solved: bool = False
    path: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    query_time_s: float = 0.0
    validation_time_s: float = 0.0
    validated: Any = None
    dense: Any = None
    attempts: int = 0
    message: str = ""
    #: seconds of the query's steps and counts of its work (`Steps`)
    steps: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return {"target_mm": self.target.center.tolist(), "tolerance_mm": float(self.target.tolerance_mm),
                "solved": bool(self.solved), "query_time_s": round(self.query_time_s, 6),
                "validation_time_s": round(self.validation_time_s, 6),
                "path": np.asarray(self.path, dtype=float).tolist(),
                "validated": None if self.validated is None else self.validated.to_json(),
                "attempts": self.attempts, "message": self.message,
                "steps": {k: round(v, 6) if isinstance(v, float) else v for k, v in self.steps.items()}}


class RoadmapPlanner:
    """Queries on one roadmap in one planning context (KD-tree of the connected nodes' tips built
    once here). With ``live`` (a `ctrplan.planning.roadmap.repair.LiveRoadmap` whose tree ``roadmap``
    is) the SUSPECT elements of a path are checked before it is used (lazy repair)."""

    def __init__(self, ctx: PlanningContext, roadmap: Roadmap, live: LiveRoadmap | None = None):
        self.ctx, self.roadmap, self.live = ctx, roadmap, live
        self.nodes = np.flatnonzero(roadmap.connected)
        self.tree = cKDTree(roadmap.tips[self.nodes])

    def candidates(self, target: TargetRegion, steps: Steps) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Where paths into the target can end, sorted by path cost: (node ids (C,), the last joints
        (C, 2N), whether each is a node itself (C,) bool). The connected nodes whose tips are nearest
        the target are looked up; those whose tips lie in the target end there (no new state, no new
        edge). Only when none does are copies of them moved into the target by IK."""
        rm, sp = self.roadmap, self.ctx.space
        with steps.timed("nearest"):
            k = min(NEAREST, len(self.nodes))
            _, idx = self.tree.query(target.center, k=k)
            nodes = self.nodes[np.atleast_1d(idx)]
            inside = _within(target, rm.tips[nodes], DIRECT_INSET_MM)
        if inside.any() and target.direction is not None:
            with steps.timed("direction"):
                inside[inside] = target.direction_ok(tip_directions(self.ctx, rm.q[nodes[inside]]))
        if inside.any():
            nodes = nodes[inside]
            order = np.argsort(rm.dist[nodes])
            steps.count("direct", len(nodes))
            return nodes[order], rm.q[nodes[order]], np.ones(len(nodes), dtype=bool)
        with steps.timed("ik"):
            tol = min(0.3, 0.25 * target.tolerance_mm)
            ik = inverse_kinematics(self.ctx, rm.q[nodes], np.repeat(target.center[None], len(nodes), 0),
                                    tol_mm=tol, max_iterations=IK_ITERATIONS)
            tips = self.ctx.scene.to_scene(ik.tip)
            ok = ik.success & target.contains(tips)
            if target.direction is not None and ok.any():
                ok[ok] = target.direction_ok(tip_directions(self.ctx, ik.q[ok]))
        nodes, q = nodes[ok], ik.q[ok]
        order = np.argsort(rm.dist[nodes] + sp.distance(rm.q[nodes], q))
        return nodes[order], q[order], np.zeros(len(nodes), dtype=bool)

    def connect(self, target: TargetRegion, scene, found: tuple, skip: int, steps: Steps
                ) -> tuple[np.ndarray | None, int]:
        """The path to the first candidate of ``found`` (`candidates`; from the ``skip``-th on) whose
        connecting edge is valid for the planning backend (none for a node itself) and whose last
        `EXACT_TAIL` waypoints pass the exact model (a short exact check: where a roadmap path fails
        exactly it fails near the anatomy it ends in); a path whose exact tip misses the target gets
        the exact goal correction. Returns the path and the index of its candidate (None and -1 if
        none)."""
        nodes, q, direct = found
        for a in range(skip, len(nodes), CHECK_BATCH):
            b = min(a + CHECK_BATCH, len(nodes))
            edges = direct[a:b].copy()
            new = np.flatnonzero(~edges)
            if len(new):
                with steps.timed("check"):
                    steps.count("checked", len(new))
                    valid, _ = check_states(self.ctx, q[a + new])
                    if valid.any():
                        keep = a + new[valid]
                        edges[new[valid]] = check_edges(self.ctx, self.roadmap.q[nodes[keep]], q[keep])
            for i in a + np.flatnonzero(edges):
                if not self._usable(int(nodes[i]), steps):
                    continue
                tree = self.roadmap.path_to(int(nodes[i]))
                path = tree if direct[i] else np.vstack([tree, q[i]])
                with steps.timed("exact_end"):
                    free, tip_in = exact_end_check(self.ctx, target, path[-EXACT_TAIL:])
                if not free:
                    steps.count("exact_end_rejected")
                    continue
                if tip_in:
                    return path, int(i)
                with steps.timed("exact_goal"):
                    return exact_goal_state(self.ctx, scene, path), int(i)
        return None, -1

    def _usable(self, node: int, steps: Steps) -> bool:
        """Whether the tree path to ``node`` can be used: connected to the start and, on a live
        roadmap, every SUSPECT element on it checked and found OK; when one is BLOCKED the live
        roadmap's tree is computed again and the new path to the node tried (`LAZY_TRIES` times)."""
        for _ in range(LAZY_TRIES):
            if not np.isfinite(self.roadmap.dist[node]):
                return False
            if self.live is None:
                return True
            if steps.get("lazy_blocked", 0) >= LAZY_TREES:
                return False  # moved tissue blocks path after path here: the caller says so
            with steps.timed("lazy"):
                ok = self.live.resolve_path(node)
                self.roadmap = self.live.roadmap
            if ok:
                return True
            steps.count("lazy_blocked")  # the tree changed: its new path to the node is tried
        return False

    def answer(self, target: TargetRegion) -> QueryResult:
        """Query, validate exactly, repair locally (see the module docstring)."""
        res = QueryResult(target)
        steps = Steps()
        scene = replace(self.ctx.scene, target=target)
        t0 = time.perf_counter()
        with _one_thread(), steps.cpu():
            found = self.candidates(target, steps)
        skip = 0  # rejected attempts and their validations count as query time (local repair)
        while res.attempts < MAX_ATTEMPTS:
            with _one_thread(), steps.cpu():
                path, used = self.connect(target, scene, found, skip, steps)
            if path is None:
                nearest = float(self.tree.query(target.center)[0])
                res.message = (f"no roadmap state connects to the target (the nearest roadmap tip is "
                               f"{nearest:.1f} mm from its centre)" if res.attempts == 0 else
                               f"not solved: {res.attempts} roadmap paths failed exact validation")
                if steps.get("lazy_blocked", 0) >= LAZY_TREES:
                    res.message = (f"not solved: {steps['lazy_blocked']} roadmap paths to the target "
                                   "touch moved tissue")
                break
            res.attempts += 1
            tv = time.perf_counter()
            vp = validate(self.ctx, scene, path)
            if vp.report.ok:
                res.query_time_s = tv - t0
                res.validation_time_s = time.perf_counter() - tv
                add_model_error(self.ctx, vp)  # a report, not a check: after the clock
                res.solved, res.path, res.validated, res.dense = True, path, vp.report, vp
                res.message = "solved" + ("" if res.attempts == 1 else f" (attempt {res.attempts})")
                res.steps = dict(steps)
                return res
            add_model_error(self.ctx, vp)  # a rejected path is reported too
            res.validated, res.dense = vp.report, vp
            skip = used + 1
        res.query_time_s = time.perf_counter() - t0
        res.steps = dict(steps)
        return res


@contextmanager
def _one_thread() -> Iterator[None]:
    """A query's kinematics calls (a few dozen rows each) on one thread: on a busy machine a parallel
    region waits for its other thread to be scheduled (a 24-row IK took 80-200 ms on two threads
    beside other jobs, 2-12 ms on one)."""
    with numba_threads_at_most(1), single_threaded_blas():
        yield


def _within(target: TargetRegion, points: np.ndarray, inset_mm: float) -> np.ndarray:
    """Whether points (M, 3) lie in ``target`` shrunk by ``inset_mm`` (mm; at most to half its size)."""
    shrunk = replace(target, semi_axes=np.maximum(target.semi_axes - inset_mm, 0.5 * target.semi_axes))
    return shrunk.contains(points)


class Steps(dict):
    """Seconds spent in a query's steps (``<step>_s``) and counts of its work, by name."""

    @contextmanager
    def timed(self, name: str) -> Iterator[None]:
        t = time.perf_counter()
        try:
            yield
        finally:
            self[f"{name}_s"] = self.get(f"{name}_s", 0.0) + time.perf_counter() - t

    def count(self, name: str, n: int = 1) -> None:
        self[name] = self.get(name, 0) + int(n)

    @contextmanager
    def cpu(self) -> Iterator[None]:
        """The CPU seconds of this thread inside (``cpu_s``): the query's work without the time the
        operating system gave other processes (on a busy machine a 10-20 ms slice now and then)."""
        t = time.thread_time()
        try:
            yield
        finally:
            self["cpu_s"] = self.get("cpu_s", 0.0) + time.thread_time() - t
