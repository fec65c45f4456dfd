"""Build a roadmap: a graph of valid states and edges grown from the scene's start, sharded over
worker processes or Ray tasks (Torres, Baykal & Alterovitz, ICRA 2014: build offline, query online).

The main process decides where to grow: each job is a batch of candidate states, each a random step
(at most the scene's ``range_mm`` in the planning metric) from a node connected to the start -- half
of the parents drawn with weight 1 / (1 + degree) (expansive-space style, so sparse parts grow), half
among the nodes whose tips lie nearest a focus region (the scene's target: the anatomy the roadmap
serves) -- with, for each candidate, its nearest nodes within 1.5 ranges. A worker checks the
candidates and, for the valid ones, the edges to those nodes in batched calls (`check_job`, through
the planning code's validity checking: `ctrplan.planning.roadmap._adapter`), and the main process
adds what was valid. The build saves itself every `CHECKPOINT_S` seconds and at the end, with the
shortest-path tree from the start; run again on the same folder it continues where it stopped.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from ctrplan.base.errors import InputError
from ctrplan.planning.roadmap._adapter import (
    PlanningContext,
    check_edges,
    check_states,
    densify,
    inverse_kinematics,
    planning_context,
    single_query_path,
)
from ctrplan.planning.roadmap.store import Roadmap, fingerprints, load_roadmap, read_meta
from ctrplan.planning.roadmap.sweep import build_sweep
from ctrplan.scene.objects import TargetRegion

#: Seconds between checkpoints of a running build.
CHECKPOINT_S = 60.0
#: Candidate states per job.
JOB_STATES = 256
#: Nearest nodes each candidate is connected to (within `NEIGHBOUR_RANGES` x range_mm).
NEIGHBOURS = 6
NEIGHBOUR_RANGES = 1.5
#: A candidate closer than this (planning metric, mm) to a node is not added.
MIN_SEPARATION_MM = 1.0
#: Share of parents drawn near the focus region, and how many nearest nodes that draw picks from.
FOCUS_SHARE = 0.5
FOCUS_POOL = 400
#: IK iterations of a focus step.
FOCUS_IK_ITERATIONS = 3
#: Every this many jobs, one seed job: a single-query path to a point of the focus region (a sphere
#: of `SEED_TOLERANCE_MM`), searched with a work budget of `SEED_STATES` states.
SEED_EVERY = 6
SEED_TOLERANCE_MM = 1.0
SEED_STATES = 20_000


class Pool(Protocol):
    """What the builder needs of an executor (`ctrplan.base.parallel.Pool`, opened with a `Source` or
    another factory of the `PlanningContext` as its ``context``: jobs are called ``fn(ctx, spec)``)."""

    def submit(self, fn: Callable[[PlanningContext, Any], dict], spec: Any) -> int: ...

    def next_done(self) -> tuple[int, dict]: ...


@dataclass(frozen=True)
class Source:
    """How a worker builds its planning context: scene file, backend name, PINN model (or None).
    Called, it builds the context (`ctrplan.base.parallel.open_pool`'s ``context``: once per worker)."""

    scene_file: str
    backend: str
    model: str | None = None

    def __call__(self) -> PlanningContext:
        from ctrplan.kinematics import make_backend
        from ctrplan.scene.loader import load_scene

        scene = load_scene(self.scene_file)
        return planning_context(scene, make_backend(self.backend, scene.robot, self.model))


def check_job(ctx: PlanningContext, job: dict) -> dict:
    """A worker's job (``job["kind"]``): ``grow`` (`_grow_job`), ``seed`` (`_seed_job`) or ``warm``
    (build the context and check one edge from the start, which compiles or loads every kernel a grow
    job uses, then hold the worker a moment so that the next warm job goes to another)."""
    if job["kind"] == "warm":
        start = ctx.scene.start[None]
        _grow_job(ctx, {"cand": np.vstack([start, start]), "edge_cand": np.zeros(1, dtype=int),
                        "edge_q": start + 1e-3})
        time.sleep(0.5)
        return {}
    t0, c0 = time.perf_counter(), time.process_time()
    out = _grow_job(ctx, job) if job["kind"] == "grow" else _seed_job(ctx, job)
    return {**out, "seconds": time.perf_counter() - t0, "cpu_s": time.process_time() - c0}


def _grow_job(ctx: PlanningContext, job: dict) -> dict:
    """Validity and tips of the candidate states ``cand`` (M, 2N) and validity of the edges
    ``cand[edge_cand[i]] -> edge_q[i]`` of the valid candidates (edges of invalid ones: False)."""
    cand, edge_cand, edge_q = job["cand"], job["edge_cand"], job["edge_q"]
    valid, tips = check_states(ctx, cand)
    edge_ok = np.zeros(len(edge_cand), dtype=bool)
    keep = np.flatnonzero(valid[edge_cand])
    if keep.size:
        edge_ok[keep] = check_edges(ctx, cand[edge_cand[keep]], edge_q[keep])
    return {"valid": valid, "tips": tips, "edge_ok": edge_ok}


def _seed_job(ctx: PlanningContext, job: dict) -> dict:
    """A single-query path from the start to a sphere around ``aim`` (scene frame, mm), cut into
    states at most ``step_mm`` apart and checked again as roadmap states and edges: the valid prefix
    (``path`` (K, 2N) from the start, ``tips`` (K, 3)); empty when the search failed."""
    region = TargetRegion.sphere(job["aim"], job["tolerance_mm"])
    path = single_query_path(ctx, region, job["seed"], job["max_states"])
    if path is None:
        return {"path": np.zeros((0, len(ctx.scene.start))), "tips": np.zeros((0, 3))}
    dense = densify(ctx, path, job["step_mm"])
    valid, tips = check_states(ctx, dense)
    ok = valid & np.concatenate([[True], check_edges(ctx, dense[:-1], dense[1:])])
    k = int(np.argmin(ok)) if not ok.all() else len(ok)
    return {"path": dense[:k], "tips": tips[:k]}


class _Graph:
    """The growing roadmap in the main process: nodes (joints, box coordinates, tips), edges, degrees,
    which nodes are connected to the start, and a nearest-neighbour index in box coordinates (a
    KD-tree rebuilt when the nodes added since its build exceed a tenth of it; newer nodes searched
    directly)."""

    def __init__(self, ctx: PlanningContext, roadmap: Roadmap):
        self.space = ctx.space
        n = roadmap.n_nodes
        cap = max(1024, 2 * n)
        self.q = np.zeros((cap, roadmap.q.shape[1]))
        self.y = np.zeros((cap, self.space.dimension))
        self.tips = np.zeros((cap, 3))
        self.deg = np.zeros(cap, dtype=np.int64)
        self.conn = np.zeros(cap, dtype=bool)
        self.n = 0
        self.edges: list[np.ndarray] = [roadmap.edges.reshape(-1, 2).astype(np.int64)]
        self.lengths: list[np.ndarray] = [roadmap.lengths.astype(float)]
        self._append(roadmap.q, roadmap.tips)
        np.add.at(self.deg, self.edges[0].ravel(), 1)
        self.conn[:n] = roadmap.connected if len(roadmap.dist) == n else False
        self.conn[0] = True
        self.tree: cKDTree | None = None
        self.indexed = 0

    def _append(self, q: np.ndarray, tips: np.ndarray) -> np.ndarray:
        m = len(q)
        if self.n + m > len(self.q):
            cap = 2 * (self.n + m)
            for name in ("q", "y", "tips", "deg", "conn"):
                old = getattr(self, name)
                new = np.zeros((cap, *old.shape[1:]), dtype=old.dtype)
                new[:self.n] = old[:self.n]
                setattr(self, name, new)
        ids = np.arange(self.n, self.n + m)
        self.q[ids], self.tips[ids] = q, tips
        self.y[ids] = self.space.to_coords(q)
        self.n += m
        return ids

    def nearest(self, y: np.ndarray, k: int, radius: float) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` nearest nodes of points y (M, D) within ``radius``: distances and ids (M, k),
        inf / -1 where fewer."""
        if self.tree is None or self.n - self.indexed > max(256, self.indexed // 10):
            self.tree, self.indexed = cKDTree(self.y[:self.n]), self.n
        d, i = self.tree.query(y, k=k, distance_upper_bound=radius)
        i = np.where(np.isfinite(d), i, -1)
        if self.n > self.indexed:  # nodes newer than the tree
            dn = np.linalg.norm(y[:, None, :] - self.y[None, self.indexed:self.n], axis=-1)
            dn = np.where(dn <= radius, dn, np.inf)
            d = np.concatenate([d, dn], axis=1)
            i = np.concatenate([i, np.broadcast_to(np.arange(self.indexed, self.n), dn.shape)], axis=1)
            order = np.argsort(d, axis=1)[:, :k]
            d, i = np.take_along_axis(d, order, 1), np.take_along_axis(i, order, 1)
        return d, np.where(np.isfinite(d), i, -1)

    def add(self, q: np.ndarray, tips: np.ndarray, edges: np.ndarray, lengths: np.ndarray) -> None:
        """Nodes q (M, 2N) with tips, then edges (E, 2) between any nodes (ids after the addition)."""
        self._append(q, tips)
        if len(edges):
            self.edges.append(edges)
            self.lengths.append(lengths)
            np.add.at(self.deg, edges.ravel(), 1)
            for _ in range(2):  # a node joins the start's component through a connected neighbour
                a, b = edges[:, 0], edges[:, 1]
                self.conn[a[self.conn[b]]] = True
                self.conn[b[self.conn[a]]] = True

    def refresh_connected(self) -> None:
        """Which nodes are connected to the start, exactly (components of the whole graph)."""
        edges = np.concatenate(self.edges)
        graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(self.n, self.n))
        _, label = connected_components(graph, directed=False)
        self.conn[:self.n] = label == label[0]

    def roadmap(self, meta: dict) -> Roadmap:
        """The graph as a `Roadmap`, with the shortest-path tree from the start."""
        edges = np.concatenate(self.edges).astype(np.int64)
        lengths = np.concatenate(self.lengths).astype(float)
        graph = coo_matrix((np.maximum(lengths, 1e-9), (edges[:, 0], edges[:, 1])), shape=(self.n, self.n))
        dist, pred = dijkstra(graph.tocsr(), directed=False, indices=0, return_predecessors=True)
        pred = np.where(pred < 0, -1, pred)
        return Roadmap(self.q[:self.n].copy(), self.tips[:self.n].copy(), edges.astype(np.int32),
                       lengths.astype(np.float32), dist, pred.astype(np.int32), meta)


@dataclass
class BuildStats:
    """Work of this run of a build: jobs (seed jobs among them, and the nodes their paths gave),
    candidate states and the valid ones, edges checked and the valid ones, seconds the workers spent
    in jobs (wall clock and CPU)."""

    jobs: int = 0
    seeds: int = 0
    seed_nodes: int = 0
    candidates: int = 0
    valid: int = 0
    edges_checked: int = 0
    edges_valid: int = 0
    worker_s: float = 0.0
    worker_cpu_s: float = 0.0
    #: per focus region: the distance (mm) from it of the nearest tip of a node connected to the start
    #: (0: inside) and how many such tips lie inside (`reach`)
    reach: dict = field(default_factory=dict)


class Grower:
    """Makes jobs from the graph and adds their results (see the module docstring)."""

    def __init__(self, ctx: PlanningContext, graph: _Graph, source: Source, rng: np.random.Generator,
                 regions: list[tuple[str, TargetRegion]]):
        self.ctx, self.graph, self.source, self.rng, self.regions = ctx, graph, source, rng, regions
        self.range_mm = float(ctx.scene.settings.range_mm or 10.0)
        self.stats = BuildStats()
        self.made = 0
        self.turns = {"grow": 0, "seed": 0}  # jobs of each kind made: the regions take turns in each
        self.region = 0  # the focus region of the job being made

    @property
    def focus(self) -> TargetRegion:
        return self.regions[self.region][1]

    def _turn(self, kind: str) -> None:
        self.region = self.turns[kind] % len(self.regions)
        self.turns[kind] += 1

    def _parents(self, m: int) -> tuple[np.ndarray, np.ndarray]:
        """Parents of ``m`` candidates: spread ones (weight 1 / (1 + degree)) and focus ones (among
        the connected nodes whose tips lie nearest the focus region)."""
        g = self.graph
        conn = np.flatnonzero(g.conn[:g.n])
        w = 1.0 / (1.0 + g.deg[conn])
        k = int(round(FOCUS_SHARE * m))
        spread = self.rng.choice(conn, size=m - k, p=w / w.sum())
        d = np.where(np.isfinite(d := self.focus.distance(g.tips[conn])), d, np.inf)
        self.stats.reach[self.regions[self.region][0]] = _reach(d)
        near = conn[np.argsort(d)[:FOCUS_POOL]]
        return spread, self.rng.choice(near, size=k)

    def _steps(self, spread: np.ndarray, focus: np.ndarray) -> np.ndarray:
        """Box coordinates of the candidates: a random step from each spread parent; from each focus
        parent a few IK iterations towards a random point of the focus region (grown by a quarter),
        plus a little noise; every step at most range_mm long."""
        g, sp = self.graph, self.ctx.space
        step = self.rng.normal(size=(len(spread), sp.dimension))
        step *= (self.range_mm * self.rng.uniform(0.2, 1.0, size=(len(spread), 1))
                 / np.linalg.norm(step, axis=1, keepdims=True))
        aims = self.focus.center + 1.25 * (self.focus.sample(len(focus), self.rng) - self.focus.center)
        ik = inverse_kinematics(self.ctx, g.q[focus], aims, tol_mm=0.1, max_iterations=FOCUS_IK_ITERATIONS)
        toward = sp.to_coords(ik.q) - g.y[focus] + self.rng.normal(scale=0.5, size=(len(focus), sp.dimension))
        toward *= np.minimum(1.0, self.range_mm / np.maximum(np.linalg.norm(toward, axis=1, keepdims=True),
                                                             1e-12))
        return sp.clip(np.concatenate([g.y[spread] + step, g.y[focus] + toward]))

    def make_job(self, m: int = JOB_STATES) -> tuple[dict, dict]:
        """A job for `check_job` and what `integrate` needs to add its result."""
        g, sp = self.graph, self.ctx.space
        y = self._steps(*self._parents(m))
        d, nbr = g.nearest(y, NEIGHBOURS, NEIGHBOUR_RANGES * self.range_mm)
        keep = d[:, 0] >= MIN_SEPARATION_MM
        y, nbr = y[keep], nbr[keep]
        cand_i, slot = np.nonzero(nbr >= 0)
        nodes = nbr[cand_i, slot]
        cand = sp.to_joints(y)
        job = {"kind": "grow", "source": self.source, "cand": cand, "edge_cand": cand_i, "edge_q": g.q[nodes]}
        return job, {"kind": "grow", "cand": cand, "edge_cand": cand_i, "edge_nodes": nodes}

    def next_job(self) -> tuple[dict, dict]:
        """Every `SEED_EVERY`-th job (the first ones included) a seed job, else a grow job."""
        self.made += 1
        if self.made % SEED_EVERY != 1:
            self._turn("grow")
            return self.make_job()
        self._turn("seed")
        aim = self.focus.center + 1.25 * (self.focus.sample(1, self.rng)[0] - self.focus.center)
        job = {"kind": "seed", "source": self.source, "aim": aim, "tolerance_mm": SEED_TOLERANCE_MM,
               "seed": int(self.rng.integers(2**31)), "max_states": SEED_STATES,
               "step_mm": 0.5 * self.range_mm}
        return job, {"kind": "seed"}

    def integrate(self, book: dict, result: dict) -> None:
        if book["kind"] == "seed":
            self._integrate_seed(result)
        else:
            self._integrate_grow(book, result)
        self.stats.jobs += 1
        self.stats.worker_s += float(result["seconds"])
        self.stats.worker_cpu_s += float(result["cpu_s"])

    def _integrate_seed(self, result: dict) -> None:
        """A seed path's states after the start become nodes chained by edges (node 0 first)."""
        g, path = self.graph, result["path"]
        self.stats.seeds += 1
        if len(path) < 2:
            return
        ids = np.arange(g.n, g.n + len(path) - 1)
        chain = np.stack([np.concatenate([[0], ids[:-1]]), ids], axis=1)
        g.add(path[1:], result["tips"][1:], chain, self.ctx.space.distance(path[:-1], path[1:]))
        self.stats.seed_nodes += len(ids)

    def _integrate_grow(self, book: dict, result: dict) -> None:
        g, st = self.graph, self.stats
        valid = result["valid"]
        new_id = np.full(len(valid), -1)
        new_id[valid] = np.arange(g.n, g.n + int(valid.sum()))
        ok = result["edge_ok"]
        a, b = new_id[book["edge_cand"][ok]], book["edge_nodes"][ok]
        lengths = self.ctx.space.distance(book["cand"][book["edge_cand"][ok]], g.q[b])
        g.add(book["cand"][valid], result["tips"][valid], np.stack([a, b], axis=1), lengths)
        st.candidates += len(valid)
        st.valid += int(valid.sum())
        st.edges_checked += int(valid[book["edge_cand"]].sum())
        st.edges_valid += int(ok.sum())


def _reach(d: np.ndarray) -> dict:
    """How close tips at distances ``d`` (mm, 0 inside) came to a region."""
    return {"closest_mm": round(float(d.min(initial=np.inf)), 3), "inside": int((d <= 0).sum())}


def reach(roadmap: Roadmap, regions: list[tuple[str, TargetRegion]]) -> dict:
    """Per region (name -> ``closest_mm``, ``inside``): how close the tips of the nodes connected to
    the start came to it."""
    tips = roadmap.tips[roadmap.connected]
    return {name: _reach(np.nan_to_num(region.distance(tips), nan=np.inf)) for name, region in regions}


Progress = Callable[[dict], None]


def _quiet(_info: dict) -> None:
    return None


def start_roadmap(ctx: PlanningContext, meta: dict) -> Roadmap:
    """A roadmap of the start alone (refused with an `InputError` if the start is not valid)."""
    valid, tips = check_states(ctx, ctx.scene.start[None])
    if not valid[0]:
        raise InputError(f"{ctx.scene.where('start')}: the start collides under the {ctx.backend.name} "
                         f"backend with its planning margin ({ctx.margin_source['source']}): no roadmap "
                         f"can grow from it (`ctrplan scene check`)")
    return Roadmap(ctx.scene.start[None].copy(), tips, np.zeros((0, 2), np.int32), np.zeros(0, np.float32),
                   np.zeros(1), np.full(1, -1, np.int32), meta)


def open_build(ctx: PlanningContext, folder: Path, meta: dict) -> Roadmap:
    """The roadmap to continue in ``folder`` (fingerprints checked), or a new one from the start."""
    old = read_meta(folder)
    if old is None:
        return start_roadmap(ctx, meta)
    return load_roadmap(folder, meta["fingerprints"])


def build(ctx: PlanningContext, source: Source, folder: Path, pool: Pool, *, time_limit_s: float,
          seed: int, workers: int, executor: str, progress: Progress = _quiet,
          max_nodes: int | None = None, focus: list[tuple[str, TargetRegion]] | None = None,
          index: bool = True) -> Roadmap:
    """Grow the roadmap in ``folder`` (new, or continued) until its total build time reaches
    ``time_limit_s`` (or it has ``max_nodes`` nodes: a budget in work), with ``workers`` jobs in flight
    on ``pool``, towards the ``focus`` regions in turn (name, region; default: the scene's target);
    saved every `CHECKPOINT_S` s, at the end and when interrupted, with how close it came to each
    region (``meta["reach"]``, also in every ``progress`` report's stats). Then, with ``index``, the
    sweep index of the finished roadmap (`ctrplan.planning.roadmap.sweep`) on the same pool, saved
    beside it (``progress({"indexing": (done, total)})``). Returns the saved roadmap."""
    focus = focus or [("target", ctx.scene.target)]
    meta = {"scene_name": ctx.scene.name, "scene_file": source.scene_file, "robot": ctx.scene.robot.name,
            "backend": source.backend, "model": source.model,
            "fingerprints": fingerprints(ctx.scene, ctx.loaded),
            "settings": {"range_mm": ctx.scene.settings.range_mm or 10.0, "neighbours": NEIGHBOURS,
                         "min_separation_mm": MIN_SEPARATION_MM,
                         "focus": {name: region.to_dict() for name, region in focus},
                         "planning_margin_mm": ctx.margin_mm, "margin_source": ctx.margin_source}}
    roadmap = open_build(ctx, folder, meta)
    runs = list(roadmap.meta.get("runs", []))
    before = float(sum(r["seconds"] for r in runs))
    graph = _Graph(ctx, roadmap)
    grower = Grower(ctx, graph, source, np.random.default_rng([seed, len(runs)]), focus)
    run = {"seed": seed, "workers": workers, "executor": executor, "seconds": 0.0, "nodes_before": graph.n}
    progress({"starting": workers})
    for _ in range(workers):  # every worker loads its model and scene before the clock starts
        pool.submit(check_job, {"kind": "warm", "source": source})
    for _ in range(workers):
        pool.next_done()
    t0 = last_save = last_conn = time.perf_counter()

    def save() -> Roadmap:
        run["seconds"] = round(time.perf_counter() - t0, 2)
        run.update(nodes_after=graph.n, **vars(grower.stats))
        done = graph.roadmap({**meta, "runs": [*runs, run], "build_s": round(before + run["seconds"], 2)})
        done.meta["reach"] = reach(done, focus)
        done.save(folder)
        return done

    in_flight: dict[int, dict] = {}
    try:
        while (before + time.perf_counter() - t0 < time_limit_s
               and (max_nodes is None or graph.n < max_nodes)):
            while len(in_flight) < max(2, 2 * workers):
                job, book = grower.next_job()
                in_flight[pool.submit(check_job, job)] = book
            number, result = pool.next_done()
            grower.integrate(in_flight.pop(number), result)
            now = time.perf_counter()
            if now - last_conn > 5.0:
                graph.refresh_connected()
                last_conn = now
            if now - last_save > CHECKPOINT_S:
                save()
                last_save = now
            progress({"elapsed_s": before + now - t0, "limit_s": time_limit_s, "nodes": graph.n,
                      "connected": int(graph.conn[:graph.n].sum()), "stats": grower.stats})
        while in_flight:  # finish the jobs in flight: their work is done or nearly
            number, result = pool.next_done()
            grower.integrate(in_flight.pop(number), result)
    finally:
        done = save()
    if index:
        sweep = build_sweep(ctx, done, lambda k, n: progress({"indexing": (k, n)}), pool,
                            in_flight=max(2, 2 * workers))
        sweep.save(folder)
    return done
