"""A roadmap in anatomy that moves: when a structure shifts, repair the roadmap instead of building it
again (dynamic roadmaps: Leven & Hutchinson 2002; Kallmann & Mataric 2004), checking lazily what the
shift may have changed (Lazy PRM: Bohlin & Kavraki 2000).

`LiveRoadmap` keeps every node and edge of the built roadmap with a state -- ``OK`` (valid in the scene
as it is now), ``BLOCKED`` (touches a moved structure) or ``SUSPECT`` (not known since a structure
moved near it) -- and the shift of every structure that moved. Moving a structure S from its old place
to a new one marks, through the sweep index (`ctrplan.planning.roadmap.sweep`),

- the OK elements that sweep cells near S's new place (they may touch it now), and
- the BLOCKED elements that sweep cells near S's old place (they may be free now)

as SUSPECT; nothing else changes. An element is blocked only because it touches some moved structure
at its present place, so it sweeps cells near that place, which is the old place when that structure
moves next: an element not SUSPECT has the state it would have if checked now (the tests check this
against states computed from scratch). The shortest-path tree from the start is computed over the
elements not BLOCKED (SUSPECT ones optimistically usable). A query resolves the SUSPECT nodes and edges
on the path it is about to use (`resolve_path`: the roadmap build's checks -- planning backend, its
calibrated margin, the planner's resolution -- against the whole scene as it is, in one batched call);
when one is blocked the tree is computed again and the query tries again. An edge's state is about its
interior states; it is usable when it and both its nodes are.

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
from ctrplan.planning.roadmap._adapter import PlanningContext, edge_states, with_world
from ctrplan.planning.roadmap.store import Roadmap
from ctrplan.planning.roadmap.sweep import SweepIndex

#: Element states.
OK, BLOCKED, SUSPECT = 0, 1, 2
#: Distance band (mm) of a structure's own distance grid: it must exceed the sweep index's reach plus
#: half a cell diagonal.
STRUCTURE_BAND_MM = 8.0
#: States per batched check.
CHECK_STATES = 8192


@dataclass
class Repair:
    """What one move did: the structure and its shift from its place in the scene file (mm); the
    elements it made SUSPECT (near the new place, were OK; near the old place, were BLOCKED), of how
    many; and the seconds it took (index look-up, the shortest-path tree when it changed, total)."""

    structure: str
    shift_mm: list[float]
    suspect: dict[str, int] = field(default_factory=dict)
    reopened: dict[str, int] = field(default_factory=dict)
    total: dict[str, int] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)

    def to_json(self) -> dict:
        return {"structure": self.structure, "shift_mm": self.shift_mm, "suspect": self.suspect,
                "reopened": self.reopened, "total": self.total,
                "seconds": {k: round(v, 4) for k, v in self.seconds.items()}}


class LiveRoadmap:
    """A built roadmap, its sweep index and the states of its elements in a scene whose structures
    move (see the module docstring). ``ctx`` is the planning context of the scene as it is now (moved
    structures in place, collision world with them); ``roadmap`` the elements not BLOCKED, with the
    shortest-path tree from the start (node ids those of the built roadmap)."""

    def __init__(self, ctx: PlanningContext, built: Roadmap, index: SweepIndex):
        self.ctx, self.built, self.index = ctx, built, index
        self.original = {o.name: o for o in ctx.scene.obstacles}
        self.shifts: dict[str, np.ndarray] = {}
        self.node_state = np.zeros(built.n_nodes, dtype=np.int8)
        self.edge_state = np.zeros(len(built.edges), dtype=np.int8)
        self._grids: dict[str, DistanceGrid] = {}
        e = np.sort(built.edges.astype(np.int64), axis=1)
        self._keys = e[:, 0] * built.n_nodes + e[:, 1]
        self._order = np.argsort(self._keys, kind="stable")
        self.roadmap = built
        #: what lazy checks found so far: elements checked and blocked, and their seconds
        self.lazy = {"nodes_checked": 0, "edges_checked": 0, "blocked": 0, "trees": 0, "seconds": 0.0}

    def shift_of(self, name: str) -> np.ndarray:
        """The shift (3,) (mm) of structure ``name`` from its place in the scene file."""
        return self.shifts.get(name, np.zeros(3))

    def grid(self, name: str) -> DistanceGrid:
        """The distance grid of structure ``name`` alone at its place in the scene file (cached)."""
        if name not in self._grids:
            self._grids[name] = grid_for([self.original[name]], band_mm=STRUCTURE_BAND_MM)
        return self._grids[name]

    def move(self, name: str, shift_mm: np.ndarray) -> Repair:
        """Put structure ``name`` at its scene-file place moved by ``shift_mm`` (3,) (mm): mark what
        the move may have changed SUSPECT, change the collision world, recompute the tree if elements
        were reopened."""
        if name not in self.original:
            raise InputError(f"no structure named {name!r} (structures: {', '.join(self.original)})")
        t0 = time.perf_counter()
        new_shift = np.asarray(shift_mm, dtype=float)
        moved = self.original[name].translated(new_shift)
        near_new = self.index.near(self.original[name], self.grid(name), new_shift)
        near_old = self.index.near(self.original[name], self.grid(name), self.shift_of(name))
        rep = Repair(name, np.round(new_shift, 4).tolist(),
                     total={"nodes": self.built.n_nodes, "edges": len(self.built.edges)})
        for kind, state, look in (("nodes", self.node_state, self.index.nodes_in),
                                  ("edges", self.edge_state, self.index.edges_in)):
            near = look(near_new)
            near = near[state[near] == OK]
            back = look(near_old)
            back = back[state[back] == BLOCKED]
            state[near] = SUSPECT
            state[back] = SUSPECT
            rep.suspect[kind], rep.reopened[kind] = int(len(near)), int(len(back))
        t1 = time.perf_counter()
        rep.seconds["look_up_s"] = t1 - t0
        world = self.ctx.checker.world.moved(moved)
        scene = replace(self.ctx.scene, obstacles=tuple(moved if o.name == name else o
                                                         for o in self.ctx.scene.obstacles))
        self.ctx = with_world(self.ctx, scene, world)
        self.shifts[name] = new_shift
        t2 = time.perf_counter()
        rep.seconds["world_s"] = t2 - t1
        if rep.reopened["nodes"] or rep.reopened["edges"]:
            self.roadmap = self._tree()
        rep.seconds["tree_s"] = time.perf_counter() - t2
        rep.seconds["total_s"] = time.perf_counter() - t0
        return rep

    # ---- lazy checks --------------------------------------------------------------------------------
    def tree_nodes(self, node: int) -> np.ndarray:
        """Node ids of the tree path from the start to ``node``."""
        chain = [int(node)]
        while chain[-1] != 0:
            chain.append(int(self.roadmap.pred[chain[-1]]))
        return np.array(chain[::-1])

    def edge_ids(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Ids of the edges between nodes a[i] and b[i] (either way round)."""
        key = np.minimum(a, b).astype(np.int64) * self.built.n_nodes + np.maximum(a, b)
        return self._order[np.searchsorted(self._keys, key, sorter=self._order)]

    def resolve_path(self, node: int) -> bool:
        """Check the SUSPECT nodes and edges on the tree path to ``node`` (against the scene as it is
        now); True when all of them are OK (the path is usable), else the tree is computed again."""
        nodes = self.tree_nodes(node)
        edges = self.edge_ids(nodes[:-1], nodes[1:])
        return self.resolve(nodes, edges)

    def resolve(self, nodes: np.ndarray, edges: np.ndarray) -> bool:
        """Check the SUSPECT ones of ``nodes`` and ``edges``; True when none of them is BLOCKED after
        that (the tree is computed again when one is found blocked)."""
        t0 = time.perf_counter()
        nodes = np.unique(nodes[self.node_state[nodes] == SUSPECT])
        edges = np.unique(edges[self.edge_state[edges] == SUSPECT])
        blocked = 0
        if len(nodes):
            ok = self._check_nodes(nodes)
            self.node_state[nodes] = np.where(ok, OK, BLOCKED)
            blocked += int((~ok).sum())
        if len(edges):
            ok = self._check_edges(edges)
            self.edge_state[edges] = np.where(ok, OK, BLOCKED)
            blocked += int((~ok).sum())
        self.lazy["nodes_checked"] += len(nodes)
        self.lazy["edges_checked"] += len(edges)
        self.lazy["blocked"] += blocked
        if blocked:
            self.roadmap = self._tree()
            self.lazy["trees"] += 1
        self.lazy["seconds"] += time.perf_counter() - t0
        return blocked == 0

    def resolve_all(self) -> None:
        """Check every SUSPECT element (states then all exact for the scene as it is)."""
        self.resolve(np.flatnonzero(self.node_state == SUSPECT), np.flatnonzero(self.edge_state == SUSPECT))

    def _check_nodes(self, ids: np.ndarray) -> np.ndarray:
        out = np.ones(len(ids), dtype=bool)
        for a in range(0, len(ids), CHECK_STATES):
            out[a:a + CHECK_STATES] = self.ctx.checker.validate(self.built.q[ids[a:a + CHECK_STATES]])[0]
        return out

    def _check_edges(self, ids: np.ndarray) -> np.ndarray:
        """Validity of the interior states of edges ``ids`` (end states are their nodes)."""
        out = np.ones(len(ids), dtype=bool)
        e = self.built.edges[ids]
        states, edge = edge_states(self.ctx, self.built.q[e[:, 0]], self.built.q[e[:, 1]])
        for a in range(0, len(states), CHECK_STATES):
            valid = self.ctx.checker.validate(states[a:a + CHECK_STATES])[0]
            out[np.unique(edge[a:a + CHECK_STATES][~valid])] = False
        return out

    def usable_edges(self) -> np.ndarray:
        """Edges not BLOCKED between nodes not BLOCKED (SUSPECT ones count as usable)."""
        e, node_ok = self.built.edges, self.node_state != BLOCKED
        return (self.edge_state != BLOCKED) & node_ok[e[:, 0]] & node_ok[e[:, 1]]

    def _tree(self) -> Roadmap:
        """The elements not BLOCKED as a `Roadmap` with its shortest-path tree (node ids kept)."""
        rm, use = self.built, self.usable_edges()
        edges, lengths = rm.edges[use], rm.lengths[use]
        n = rm.n_nodes
        weights = np.maximum(lengths.astype(float), 1e-9)
        graph = coo_matrix((weights, (edges[:, 0], edges[:, 1])), shape=(n, n))
        dist, pred = dijkstra(graph.tocsr(), directed=False, indices=0, return_predecessors=True)
        if self.node_state[0] == BLOCKED:  # the start itself touches a moved structure
            dist[:] = np.inf
        pred = np.where(pred < 0, -1, pred).astype(np.int32)
        return Roadmap(rm.q, rm.tips, edges, lengths, dist, pred, rm.meta)
