"""Where a roadmap's states and edges sweep the workspace: an index from workspace cells to the roadmap
elements whose backbones pass through them (dynamic roadmaps: Leven & Hutchinson 2002; Kallmann &
Mataric 2004), so that when a structure moves only the elements near its old or new place are checked
again (`ctrplan.planning.roadmap.repair`).

The workspace is cut into cubic cells of `CELL_MM` over the obstacles' bounds grown by `PAD_MM` (one
more bucket holds every sample outside). Each element's backbones -- the planning backend's, with its
capsule radii -- are sampled along every capsule axis at most `SAMPLE_MM` apart: a node's one state,
an edge's interior states at the planner's resolution (its end states are its nodes). An element
*sweeps* the cells its samples lie in. Every point of a capsule surface lies within ``reach_mm`` =
(largest capsule radius, the planning margin included) + `SAMPLE_MM` / 2 of a sample, so an element
can touch a structure only if some cell it sweeps comes within ``reach_mm`` (plus the structure's own
margin) of it: `SweepIndex.near` lists the cells whose centre lies within ``reach_mm`` + half a cell
diagonal of the structure, from the structure's distance grid.

On disk (``sweep.npz`` beside the roadmap, no pickles): the grid, ``reach_mm`` and two compressed
sparse rows over the cells, cell -> nodes and cell -> edges (element ids int32, sorted per cell).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ctrplan.base.dataio import atomic_write
from ctrplan.base.errors import InputError
from ctrplan.collision.broadphase import DistanceGrid, obstacle_bounds
from ctrplan.planning.roadmap._adapter import PlanningContext, edge_states
from ctrplan.planning.roadmap.store import Roadmap
from ctrplan.scene.objects import Obstacle, Scene

SWEEP_FILE = "sweep.npz"
#: Edge of a workspace cell (mm).
CELL_MM = 2.0
#: Largest spacing of the samples along a capsule axis (mm).
SAMPLE_MM = 1.0
#: The cells cover the obstacles' bounds grown by this (mm); samples beyond share one bucket.
PAD_MM = 30.0
#: States per backend call while indexing.
CHUNK_STATES = 4096


@dataclass(frozen=True)
class CellGrid:
    """Cubic cells of ``cell_mm`` from the lower corner ``lo`` (3,) (scene frame, mm), ``shape``
    (3,) of them; id ``size`` is the bucket of everything outside."""

    lo: np.ndarray
    cell_mm: float
    shape: tuple[int, int, int]

    @classmethod
    def for_scene(cls, scene: Scene, cell_mm: float = CELL_MM, pad_mm: float = PAD_MM) -> CellGrid:
        bounds = np.stack([obstacle_bounds(o) for o in scene.obstacles])
        lo = bounds[:, 0].min(axis=0) - pad_mm
        hi = bounds[:, 1].max(axis=0) + pad_mm
        return cls(lo, float(cell_mm), tuple(int(n) for n in np.ceil((hi - lo) / cell_mm)))

    @property
    def size(self) -> int:
        return int(np.prod(self.shape))

    def ids(self, points: np.ndarray) -> np.ndarray:
        """Cell ids (...) of points (..., 3) (scene frame, mm); `size` outside (or not finite)."""
        f = np.floor((np.asarray(points, dtype=float) - self.lo) / self.cell_mm)
        inside = np.all((f >= 0) & (f < np.array(self.shape)), axis=-1)
        f = np.where(inside[..., None], f, 0).astype(np.int64)
        ids = (f[..., 0] * self.shape[1] + f[..., 1]) * self.shape[2] + f[..., 2]
        return np.where(inside, ids, self.size)

    def box(self, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
        """Ids (M,) and centres (M, 3) of the cells overlapping the box [lo, hi] (mm), and whether
        the box reaches beyond the grid."""
        i0 = np.floor((lo - self.lo) / self.cell_mm).astype(int)
        i1 = np.floor((hi - self.lo) / self.cell_mm).astype(int) + 1
        beyond = bool(np.any(i0 < 0) or np.any(i1 > np.array(self.shape)))
        i0, i1 = np.maximum(i0, 0), np.minimum(i1, self.shape)
        axes = [np.arange(a, b) for a, b in zip(i0, i1, strict=True)]
        idx = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        ids = (idx[:, 0] * self.shape[1] + idx[:, 1]) * self.shape[2] + idx[:, 2]
        return ids, self.lo + (idx + 0.5) * self.cell_mm, beyond


def _samples(positions: np.ndarray, spacing_mm: float) -> np.ndarray:
    """Points (B, S, 3) along the polylines (B, P, 3), at most ``spacing_mm`` apart on every segment."""
    seg = np.linalg.norm(np.diff(positions, axis=1), axis=-1)
    longest = float(np.nanmax(seg)) if np.isfinite(seg).any() else 0.0
    k = max(1, math.ceil(longest / spacing_mm))
    t = (np.arange(k) / k)[None, None, :, None]
    a, b = positions[:, :-1, None, :], positions[:, 1:, None, :]
    pts = (a + t * (b - a)).reshape(len(positions), -1, 3)
    return np.concatenate([pts, positions[:, -1:]], axis=1)


def sweep_pairs(ctx: PlanningContext, grid: CellGrid, q: np.ndarray, owner: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, float]:
    """The (cell, element) pairs (each (K,) int64, unique) swept by the planning backend's backbones
    of states q (B, 2N), state i belonging to element ``owner[i]``, and the largest capsule radius
    (mm, the planning margin included) among them."""
    bb = ctx.checker.forward(q)
    pos = ctx.scene.to_scene(bb.positions_mm)
    ok = np.isfinite(pos).all(axis=(1, 2))
    cells = grid.ids(_samples(pos[ok], SAMPLE_MM))
    key = np.unique(cells.astype(np.int64) * (int(owner.max()) + 1) + owner[ok, None])
    radius = float(np.max(bb.radius_mm[ok], initial=0.0)) + ctx.margin_mm
    return key // (int(owner.max()) + 1), key % (int(owner.max()) + 1), radius


@dataclass
class SweepIndex:
    """Cell -> nodes and cell -> edges of one roadmap (see the module docstring)."""

    grid: CellGrid
    reach_mm: float
    node_ptr: np.ndarray
    node_ids: np.ndarray
    edge_ptr: np.ndarray
    edge_ids: np.ndarray
    nodes: int  # the roadmap's nodes and edges when it was indexed
    edges: int

    def near(self, structure: Obstacle, distance: DistanceGrid, shift_mm: np.ndarray) -> np.ndarray:
        """Ids of the cells an element must sweep to come within reach of ``structure`` moved by
        ``shift_mm`` (3,) (mm): those whose centre lies within ``reach_mm`` + half a cell diagonal of
        it by ``distance``, the structure's own distance grid where it has not moved (its band must
        exceed that reach); the outside bucket too when the structure's reach leaves the grid."""
        shift_mm = np.asarray(shift_mm, dtype=float)
        slack = self.reach_mm + 0.5 * math.sqrt(3.0) * self.grid.cell_mm
        b = obstacle_bounds(structure) + shift_mm
        pad = slack + structure.margin_mm
        ids, centres, beyond = self.grid.box(b[0] - pad, b[1] + pad)
        unmoved = (centres - shift_mm)[:, None, :]
        lower = distance.segment_lower_bounds(np.concatenate([unmoved, unmoved], axis=1))[:, 0]
        picked = ids[lower <= slack]
        return np.append(picked, self.grid.size) if beyond else picked

    def nodes_in(self, cells: np.ndarray) -> np.ndarray:
        """The nodes (ids, ascending) that sweep any of ``cells``."""
        return _gather(self.node_ptr, self.node_ids, cells, self.nodes)

    def edges_in(self, cells: np.ndarray) -> np.ndarray:
        """The edges (ids, ascending) that sweep any of ``cells``."""
        return _gather(self.edge_ptr, self.edge_ids, cells, self.edges)

    @property
    def entries(self) -> int:
        return int(len(self.node_ids) + len(self.edge_ids))

    def save(self, folder: Path) -> None:
        with atomic_write(Path(folder) / SWEEP_FILE, "wb") as fh:
            np.savez_compressed(fh, lo=self.grid.lo, cell_mm=self.grid.cell_mm,
                                shape=np.array(self.grid.shape),
                                reach_mm=self.reach_mm, node_ptr=self.node_ptr, node_ids=self.node_ids,
                                edge_ptr=self.edge_ptr, edge_ids=self.edge_ids,
                                counts=np.array([self.nodes, self.edges]))

    @classmethod
    def load(cls, folder: Path, roadmap: Roadmap) -> SweepIndex | None:
        """The index in ``folder`` if there is one for ``roadmap`` (as many nodes and edges), else
        None; `InputError` for one that cannot be read."""
        path = Path(folder) / SWEEP_FILE
        if not path.is_file():
            return None
        try:
            with np.load(path, allow_pickle=False) as z:
                d = {k: z[k] for k in z.files}
            index = cls(CellGrid(d["lo"], float(d["cell_mm"]), tuple(int(n) for n in d["shape"])),
                        float(d["reach_mm"]), d["node_ptr"], d["node_ids"], d["edge_ptr"], d["edge_ids"],
                        int(d["counts"][0]), int(d["counts"][1]))
        except (OSError, ValueError, KeyError, IndexError) as exc:
            raise InputError(f"{path}: cannot read the roadmap's sweep index ({exc})") from None
        fits = len(index.node_ptr) == index.grid.size + 2 and len(index.edge_ptr) == index.grid.size + 2
        return index if fits and (index.nodes, index.edges) == (roadmap.n_nodes, len(roadmap.edges)) else None


def _gather(ptr: np.ndarray, ids: np.ndarray, cells: np.ndarray, count: int) -> np.ndarray:
    """The element ids (of ``count``) listed under ``cells`` of a cell -> elements CSR, each once."""
    cells = np.asarray(cells, dtype=np.int64)
    start, stop = ptr[cells], ptr[cells + 1]
    n = stop - start
    if not len(cells) or not n.sum():
        return np.zeros(0, dtype=np.int64)
    offsets = np.repeat(start - np.concatenate([[0], np.cumsum(n)[:-1]]), n)
    seen = np.zeros(count, dtype=bool)
    seen[ids[np.arange(int(n.sum())) + offsets]] = True
    return np.flatnonzero(seen)


def _state_chunks(ctx: PlanningContext, roadmap: Roadmap) -> Iterator[dict]:
    """Jobs of about `CHUNK_STATES` states each: the nodes, then the edges' interior states (an
    edge shorter than the resolution has none), with the owner of each state and the elements the
    job covers."""
    for a in range(0, roadmap.n_nodes, CHUNK_STATES):
        b = min(a + CHUNK_STATES, roadmap.n_nodes)
        yield {"kind": "node", "q": roadmap.q[a:b], "owner": np.arange(a, b), "covered": b - a}
    e = roadmap.edges
    per = max(1, CHUNK_STATES // 8)
    for a in range(0, len(e), per):
        b = min(a + per, len(e))
        states, edge = edge_states(ctx, roadmap.q[e[a:b, 0]], roadmap.q[e[a:b, 1]])
        yield {"kind": "edge", "q": states, "owner": edge + a, "covered": b - a}


def sweep_job(ctx: PlanningContext, job: dict) -> dict:
    """A worker's part of `build_sweep`: the (cell, element) pairs of the job's states."""
    if not len(job["q"]):
        return {"kind": job["kind"], "cells": np.zeros(0, np.int64), "owners": np.zeros(0, np.int64),
                "radius": 0.0, "covered": job["covered"]}
    cells, owners, radius = sweep_pairs(ctx, job["grid"], job["q"], job["owner"])
    return {"kind": job["kind"], "cells": cells.astype(np.int32), "owners": owners.astype(np.int32),
            "radius": radius, "covered": job["covered"]}


def build_sweep(ctx: PlanningContext, roadmap: Roadmap, progress: Callable[[int, int], None] | None = None,
                pool=None, in_flight: int = 4) -> SweepIndex:
    """The sweep index of ``roadmap`` in context ``ctx`` (every node and edge), its jobs run on
    ``pool`` (`ctrplan.planning.roadmap.build.Pool`: jobs are called ``fn(ctx, spec)``; None: here),
    ``in_flight`` at a time; ``progress(done, total)`` in elements."""
    grid = CellGrid.for_scene(ctx.scene)
    pairs: dict[str, list] = {"node": [], "edge": []}
    radius, done, total = 0.0, 0, roadmap.n_nodes + len(roadmap.edges)

    def add(out: dict) -> None:
        nonlocal radius, done
        pairs[out["kind"]].append((out["cells"], out["owners"]))
        radius = max(radius, out["radius"])
        done += out["covered"]
        if progress:
            progress(done, total)

    jobs = ({**job, "grid": grid} for job in _state_chunks(ctx, roadmap))
    if pool is None:
        for job in jobs:
            add(sweep_job(ctx, job))
    else:
        waiting = 0
        for job in jobs:
            pool.submit(sweep_job, job)
            waiting += 1
            if waiting >= in_flight:
                add(pool.next_done()[1])
                waiting -= 1
        for _ in range(waiting):
            add(pool.next_done()[1])
    rows = [_csr(pairs[kind], grid.size) for kind in ("node", "edge")]
    return SweepIndex(grid, radius + 0.5 * SAMPLE_MM, *rows[0], *rows[1], roadmap.n_nodes, len(roadmap.edges))


def _csr(parts: list[tuple[np.ndarray, np.ndarray]], size: int) -> tuple[np.ndarray, np.ndarray]:
    """Cell -> owners rows (ptr (size + 2,) int64, owner ids int32 sorted per cell) from (cell,
    owner) pairs."""
    cells = np.concatenate([c for c, _ in parts]) if parts else np.zeros(0, np.int32)
    owners = np.concatenate([o for _, o in parts]) if parts else np.zeros(0, np.int32)
    order = np.lexsort((owners, cells))
    counts = np.bincount(cells, minlength=size + 1)
    return np.concatenate([[0], np.cumsum(counts)]).astype(np.int64), owners[order].astype(np.int32)
