"""`CollisionWorld`: the scene's obstacles as FCL objects, built once (meshes split into compact
BVH chunks, primitives as FCL shapes), with per-structure margins and the distance-grid broadphase.
"""

from __future__ import annotations

from collections.abc import Sequence

import fcl
import numpy as np

from ctrplan.collision.broadphase import (
    DistanceGrid,
    grid_for,
    obstacle_bounds,
    primitive_bounds,
)
from ctrplan.collision.capsules import _fcl_transform
from ctrplan.scene.objects import Obstacle, Scene


def _split_mesh(V: np.ndarray, F: np.ndarray, max_faces: int) -> list[np.ndarray]:
    """Face index sets of spatially compact chunks (recursive median split on the longest axis)."""
    cent = V[F].mean(axis=1)
    out = []
    stack = [np.arange(len(F))]
    while stack:
        idx = stack.pop()
        if len(idx) <= max_faces:
            out.append(idx)
            continue
        c = cent[idx]
        ext = np.ptp(V[F[idx]].reshape(-1, 3), axis=0)
        ax = int(np.argmax(ext))
        order = np.argsort(c[:, ax], kind="stable")
        half = len(idx) // 2
        stack += [idx[order[:half]], idx[order[half:]]]
    return out


#: `CollisionWorld.moved` keeps what the other obstacles give the cells within this much (mm) of a
#: moved structure's reach.
OTHERS_PAD_MM = 6.0


class CollisionWorld:
    """The scene's obstacles as FCL objects, built once, and their distance-grid broadphase.

    Meshes are split into spatially compact chunks (one BVH each) so that an axis-aligned
    bounding-box prefilter sends only nearby capsule/chunk pairs to FCL's narrow phase. ``max_faces``
    bounds the chunk size. With ``broadphase`` a `DistanceGrid` (from memory, the disk cache or built
    here, see `broadphase`; or ``grid``, already made for these obstacles) first clears the capsules
    certainly far from every obstacle; FCL judges the rest.
    """

    def __init__(self, obstacles: Sequence[Obstacle], max_faces: int = 256, broadphase: bool = True,
                 grid: DistanceGrid | None = None):
        self.obstacles = tuple(obstacles)
        self.broadphase = bool(broadphase)
        self._objects: list[fcl.CollisionObject] = []
        self._geoms: list = []  # keep FCL geometry alive
        self.names: list[str] = []
        #: per FCL object: the index of its obstacle in `obstacles`, and that obstacle's margin (mm)
        self.owner: list[int] = []
        self.margins: list[float] = []
        lo, hi = [], []
        for index, o in enumerate(self.obstacles):
            self._add_obstacle(index, o, max_faces, lo, hi)
        self._finish(lo, hi)
        #: the broadphase grid (None when disabled or without obstacles)
        self.grid: DistanceGrid | None = (grid or grid_for(self.obstacles)) if self.broadphase else None
        #: after `moved`: (its obstacle's name, a box, what the other obstacles give the box's cells)
        self._others: tuple | None = None

    def _add_obstacle(self, index: int, o: Obstacle, max_faces: int, lo: list, hi: list) -> None:
        """FCL objects of obstacle ``index`` (chunks of a mesh, or one primitive)."""
        if o.kind == "mesh":
            V = np.ascontiguousarray(o.vertices, dtype=float)
            F = np.ascontiguousarray(o.faces, dtype=np.int64)
            for idx in _split_mesh(V, F, max_faces):
                f = F[idx]
                used, inv = np.unique(f.ravel(), return_inverse=True)
                v = np.ascontiguousarray(V[used])
                f = np.ascontiguousarray(inv.reshape(-1, 3), dtype=np.int64)
                g = fcl.BVHModel()
                g.beginModel(len(v), len(f))
                g.addSubModel(v, f)
                g.endModel()
                self._add(g, fcl.Transform(), index, v.min(axis=0), v.max(axis=0), lo, hi)
            return
        if o.kind == "sphere":
            g = fcl.Sphere(o.radius)
        elif o.kind == "box":
            g = fcl.Box(*o.size)
        elif o.kind == "cylinder":
            g = fcl.Cylinder(o.radius, o.length)
        elif o.kind == "capsule":
            g = fcl.Capsule(o.radius, o.length)
        else:  # pragma: no cover - the loader only makes these kinds
            raise ValueError(f"unknown obstacle kind {o.kind!r}")
        b = primitive_bounds(o)
        self._add(g, _fcl_transform(o.pose), index, b[0], b[1], lo, hi)

    def _finish(self, lo: list, hi: list) -> None:
        """The objects' bounding boxes and the collision request, once every object is added."""
        #: the objects' bounding boxes (O, 3) (scene frame, mm) and, grown by each object's margin, the
        #: boxes a capsule must reach to collide (``aabb_lo``, ``aabb_hi``)
        self.box_lo = np.array(lo).reshape(-1, 3)
        self.box_hi = np.array(hi).reshape(-1, 3)
        grow = np.array(self.margins).reshape(-1, 1)
        self.aabb_lo = self.box_lo - grow
        self.aabb_hi = self.box_hi + grow
        self._request = fcl.CollisionRequest()

    def _add(self, geom, tf, index: int, lo_, hi_, lo, hi) -> None:
        self._geoms.append(geom)
        self._objects.append(fcl.CollisionObject(geom, tf))
        self.names.append(self.obstacles[index].name)
        self.owner.append(index)
        self.margins.append(float(self.obstacles[index].margin_mm))
        lo.append(lo_)
        hi.append(hi_)

    @classmethod
    def from_scene(cls, scene: Scene, broadphase: bool = True) -> CollisionWorld:
        return cls(scene.obstacles, broadphase=broadphase)

    def moved(self, obstacle: Obstacle, max_faces: int = 256) -> CollisionWorld:
        """This world with the obstacle of ``obstacle``'s name replaced by ``obstacle`` (a structure
        that moved): the other obstacles' FCL objects are shared, the grid is repainted around the
        old and the new place only (`DistanceGrid.repainted`; milliseconds where a new grid of the
        skull base takes seconds; grown first where the new place reaches beyond it)."""
        index = next(i for i, o in enumerate(self.obstacles) if o.name == obstacle.name)
        new = object.__new__(CollisionWorld)
        new.obstacles = self.obstacles[:index] + (obstacle,) + self.obstacles[index + 1:]
        new.broadphase = self.broadphase
        new._objects, new._geoms, new.names, new.owner, new.margins = [], [], [], [], []
        lo, hi = [], []
        for k, obj in enumerate(self._objects):
            if self.owner[k] != index:
                new._objects.append(obj)
                new._geoms.append(self._geoms[k])
                new.names.append(self.names[k])
                new.owner.append(self.owner[k])
                new.margins.append(self.margins[k])
                lo.append(self.box_lo[k])
                hi.append(self.box_hi[k])
        new._add_obstacle(index, obstacle, max_faces, lo, hi)
        new._finish(lo, hi)
        new.grid, new._others = None, None
        if self.grid is not None:
            new.grid, new._others = self._repainted(index, obstacle, new.obstacles)
        return new

    def _repainted(self, index: int, obstacle: Obstacle, obstacles: tuple[Obstacle, ...]
                   ) -> tuple[DistanceGrid, tuple | None]:
        """The grid with obstacle ``index`` moved to ``obstacle``: the cells around its old and new
        place painted again. What the other obstacles give the cells around it (grown by
        `OTHERS_PAD_MM`) is kept with the result and reused when the same obstacle moves next,
        within those cells (a structure dragged about then costs the painting of itself alone)."""
        old = self.obstacles[index]
        grid = self.grid.grown_to(obstacle)
        reach = grid.band_mm + max(old.margin_mm, obstacle.margin_mm) + 2 * grid.cell_mm
        both = np.stack([obstacle_bounds(old), obstacle_bounds(obstacle)])
        box = np.stack([both[:, 0].min(axis=0) - reach, both[:, 1].max(axis=0) + reach])
        kept = self._others
        if kept is None or kept[0] != obstacle.name or grid is not self.grid \
                or not (np.all(kept[1][0] <= box[0]) and np.all(box[1] <= kept[1][1])):
            wide = np.stack([box[0] - OTHERS_PAD_MM, box[1] + OTHERS_PAD_MM])
            others = [o for k, o in enumerate(obstacles) if k != index]
            kept = (obstacle.name, wide, grid.painted(others, grid.cells_of(wide)))
        cells = grid.cells_of(kept[1])
        return grid.with_cells(cells, np.minimum(kept[2], grid.painted([obstacle], cells))), kept

    def near(self, points: np.ndarray, radii: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Capsules the broadphase cannot clear, (B, M) bool, and a priority (B, M) to test them in
        (lowest first), for polylines (B, N, 3) (scene frame, mm) with capsule radii (B, M) (mm).

        With the grid: a capsule is near unless its clearance lower bound exceeds its radius;
        priority = that bound (likeliest contact first). Without: near = bounding box overlaps
        some object; priority = distal first."""
        p = np.asarray(points, dtype=float)
        if len(self) == 0:
            return np.zeros(radii.shape, dtype=bool), np.zeros(radii.shape)
        grid = self.grid
        if grid is not None:
            lower = grid.segment_lower_bounds(p, radii)
            return lower <= radii + 1e-9, lower
        lo = np.minimum(p[:, :-1], p[:, 1:]) - radii[..., None]
        hi = np.maximum(p[:, :-1], p[:, 1:]) + radii[..., None]
        m = radii.shape[-1]
        return self.overlaps(lo, hi).any(axis=-1), np.broadcast_to(-np.arange(m, dtype=float), radii.shape)

    def __len__(self) -> int:
        return len(self._objects)

    def overlaps(self, seg_lo: np.ndarray, seg_hi: np.ndarray, pad: float = 1e-6) -> np.ndarray:
        """Bounding-box overlap (..., M, O) of segment boxes (..., M, 3) with every object."""
        return np.all((seg_lo[..., :, None, :] <= self.aabb_hi + pad)
                      & (seg_hi[..., :, None, :] >= self.aabb_lo - pad), axis=-1)

    def candidates(self, seg_lo: np.ndarray, seg_hi: np.ndarray) -> np.ndarray:
        """(capsule, object) index pairs (P, 2) whose bounding boxes overlap, distal capsules first."""
        if len(self) == 0:
            return np.zeros((0, 2), dtype=np.int64)
        pairs = np.argwhere(self.overlaps(seg_lo, seg_hi)[::-1])
        pairs[:, 0] = len(seg_lo) - 1 - pairs[:, 0]
        return pairs
