"""A roadmap in anatomy that moves: when a structure shifts, repair the roadmap instead of building it
again (dynamic roadmaps: Leven & Hutchinson 2002; Kallmann & Mataric 2004).

`LiveRoadmap` keeps every node and edge of the built roadmap with a flag -- usable in the scene as it is
now, or blocked -- and the shift of every structure that moved. Moving a structure S from its old
place to a new one re-checks, through the sweep index (`ctrplan.planning.roadmap.sweep`), only

- the usable elements that sweep cells near S's new place, against S there alone (they were valid
  against everything else already): those that touch it are blocked;
- the blocked elements that sweep cells near S's old place, against the whole scene as it is now:
  those that are free again are usable again.

An element is blocked only because it touches some moved structure at its present place, so it sweeps
cells near that place, which is the old place when that structure moves next: every flag stays exact
for the scene as it is (the test checks this against flags computed from scratch). An edge's flag is
about its interior states; it is usable when it and both its nodes are. The checks are those of
the roadmap build (planning backend, its calibrated margin, the planner's resolution), in batched
calls; then the shortest-path tree from the start is computed again over what is usable.

States that the build rejected because of S are not in the roadmap: a structure that moves away opens
no new roadmap states there (`ctrplan roadmap build` on the moved scene would add them).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from ctrplan.base.errors import InputError
from ctrplan.collision.broadphase import DistanceGrid, grid_for
from ctrplan.collision.world import CollisionWorld
from ctrplan.planning.roadmap._adapter import (
    PlanningContext,
    checker_with_world,
    edge_states,
    with_world,
)
from ctrplan.planning.roadmap.store import Roadmap
from ctrplan.planning.roadmap.sweep import SweepIndex

#: Distance band (mm) of a structure's own distance grid: it must exceed the sweep index's reach plus
#: half a cell diagonal.
STRUCTURE_BAND_MM = 8.0
#: States per batched check.
CHECK_STATES = 8192


@dataclass
class Repair:
    """What one move did: the structure and its shift from its place in the scene file (mm); elements
    that were checked (near the new place, usable; near the old place, blocked), how many of them
    it blocked and freed, of how many; and the seconds it took (index look-up, checks, tree)."""

    structure: str
    shift_mm: list[float]
    checked: dict[str, int] = field(default_factory=dict)
    blocked: dict[str, int] = field(default_factory=dict)
    freed: dict[str, int] = field(default_factory=dict)
    total: dict[str, int] = field(default_factory=dict)
    usable: dict[str, int] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)

    def to_json(self) -> dict:
        return {"structure": self.structure, "shift_mm": self.shift_mm, "checked": self.checked,
                "blocked": self.blocked, "freed": self.freed, "total": self.total, "usable": self.usable,
                "seconds": {k: round(v, 4) for k, v in self.seconds.items()}}


class LiveRoadmap:
    """A built roadmap, its sweep index and the flags of its elements in a scene whose structures move
    (see the module docstring). ``ctx`` is the planning context of the scene as it is now (moved
    structures in place, collision world with them); ``roadmap`` the usable part, with the
    shortest-path tree from the start (node ids those of the built roadmap)."""

    def __init__(self, ctx: PlanningContext, built: Roadmap, index: SweepIndex):
        self.ctx, self.built, self.index = ctx, built, index
        self.original = {o.name: o for o in ctx.scene.obstacles}
        self.shifts: dict[str, np.ndarray] = {}
        self.node_ok = np.ones(built.n_nodes, dtype=bool)
        self.edge_ok = np.ones(len(built.edges), dtype=bool)
        self._grids: dict[str, DistanceGrid] = {}
        self.roadmap = built

    def shift_of(self, name: str) -> np.ndarray:
        """The shift (3,) (mm) of structure ``name`` from its place in the scene file."""
        return self.shifts.get(name, np.zeros(3))

    def _grid(self, name: str) -> DistanceGrid:
        """The distance grid of structure ``name`` alone at its place in the scene file (cached)."""
        if name not in self._grids:
            self._grids[name] = grid_for([self.original[name]], band_mm=STRUCTURE_BAND_MM)
        return self._grids[name]

    def move(self, name: str, shift_mm: np.ndarray) -> Repair:
        """Put structure ``name`` at its scene-file place moved by ``shift_mm`` (3,) (mm) and repair."""
        if name not in self.original:
            raise InputError(f"no structure named {name!r} (structures: {', '.join(self.original)})")
        t0 = time.perf_counter()
        new_shift = np.asarray(shift_mm, dtype=float)
        old_shift = self.shift_of(name)
        moved = self.original[name].translated(new_shift)
        grid = self._grid(name)
        near_new = self.index.near(self.original[name], grid, new_shift)
        near_old = self.index.near(self.original[name], grid, old_shift)
        world = self.ctx.checker.world.moved(moved)
        scene = replace(self.ctx.scene, obstacles=tuple(moved if o.name == name else o
                                                         for o in self.ctx.scene.obstacles))
        self.ctx = with_world(self.ctx, scene, world)
        alone = checker_with_world(self.ctx, CollisionWorld([moved], grid=grid.translated(new_shift)))
        rep = Repair(name, np.round(new_shift, 4).tolist(),
                     total={"nodes": self.built.n_nodes, "edges": len(self.built.edges)})
        t1 = time.perf_counter()
        rep.seconds["look_up_s"] = t1 - t0
        for kind in ("nodes", "edges"):
            ok = self.node_ok if kind == "nodes" else self.edge_ok
            look = self.index.nodes_in if kind == "nodes" else self.index.edges_in
            near = look(near_new)
            near = near[ok[near]]
            back = look(near_old)
            back = back[~ok[back]]
            valid = self._check(kind, near, alone)
            ok[near[~valid]] = False
            freed = self._check(kind, back, self.ctx.checker)
            ok[back[freed]] = True
            rep.checked[kind] = int(len(near) + len(back))
            rep.blocked[kind] = int((~valid).sum())
            rep.freed[kind] = int(freed.sum())
        t2 = time.perf_counter()
        rep.seconds["check_s"] = t2 - t1
        self.shifts[name] = new_shift
        self.roadmap = self._usable()
        rep.usable = {"nodes": int(self.node_ok.sum()), "edges": int(self.usable_edges().sum())}
        rep.seconds["tree_s"] = time.perf_counter() - t2
        rep.seconds["total_s"] = time.perf_counter() - t0
        return rep

    def _check(self, kind: str, ids: np.ndarray, checker) -> np.ndarray:
        """Validity (M,) of nodes or edges (interior states) ``ids`` with ``checker``, in batches."""
        out = np.ones(len(ids), dtype=bool)
        if not len(ids):
            return out
        if kind == "nodes":
            for a in range(0, len(ids), CHECK_STATES):
                out[a:a + CHECK_STATES] = checker.validate(self.built.q[ids[a:a + CHECK_STATES]])[0]
            return out
        e = self.built.edges[ids]
        states, edge = edge_states(self.ctx, self.built.q[e[:, 0]], self.built.q[e[:, 1]])
        for a in range(0, len(states), CHECK_STATES):
            valid = checker.validate(states[a:a + CHECK_STATES])[0]
            out[np.unique(edge[a:a + CHECK_STATES][~valid])] = False
        return out

    def usable_edges(self) -> np.ndarray:
        e = self.built.edges
        return self.edge_ok & self.node_ok[e[:, 0]] & self.node_ok[e[:, 1]]

    def _usable(self) -> Roadmap:
        """The usable elements as a `Roadmap` with its shortest-path tree (node ids kept)."""
        rm, use = self.built, self.usable_edges()
        edges, lengths = rm.edges[use], rm.lengths[use]
        n = rm.n_nodes
        weights = np.maximum(lengths.astype(float), 1e-9)
        graph = coo_matrix((weights, (edges[:, 0], edges[:, 1])), shape=(n, n))
        dist, pred = dijkstra(graph.tocsr(), directed=False, indices=0, return_predecessors=True)
        if not self.node_ok[0]:  # the start itself touches a moved structure: nothing is reachable
            dist[:] = np.inf
        pred = np.where(pred < 0, -1, pred).astype(np.int32)
        return Roadmap(rm.q, rm.tips, edges, lengths, dist, pred, rm.meta)
