"""Collision checking of a CTR backbone against the scene with FCL.

The robot is a chain of capsules between consecutive backbone points; each capsule's radius is the
outer radius of the outermost tube present on that segment plus a configurable margin. Each obstacle
may carry its own margin (`Obstacle.margin_mm`): every boolean check against that obstacle tests the
capsule grown by it as well (the broadphase grid and the bounding boxes account for it too), so
planning, exact validation, repair and design keep that much more clearance from it without code of
their own. Distances are the raw ones (robot surface to obstacle, no margin);
`RobotCollisionChecker.structure_clearances` compares them with each structure's margin. The scene is
built once (meshes as BVHs of compact chunks, primitives as FCL shapes); the capsules are FCL objects
whose radius, length and pose are updated in place for every configuration (docs/design.md §4: building from
Python is slow, boolean checks are cheap, distances are for final paths only).

Boolean checks first ask the scene's conservative distance grid (`ctrplan.broadphase`) which capsules
are certainly clear of every obstacle -- for a whole batch of backbones in one compiled call -- and
send only the others to FCL, likeliest contact first: FCL judges every contact, so the answers are
those of FCL alone.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import fcl
import numpy as np
from numba import njit

from ctrplan.broadphase import (
    DistanceGrid,
    _capsule_lower_bounds,
    capsule_contact,
    grid_for,
    primitive_bounds,
)
from ctrplan.scene import Obstacle, Scene, transform_points


def _fcl_transform(pose: np.ndarray) -> fcl.Transform:
    return fcl.Transform(np.ascontiguousarray(pose[:3, :3]), np.ascontiguousarray(pose[:3, 3]))


def capsule_frames(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centres (..., 3), rotations (..., 3, 3) taking z onto each segment, and lengths (...) (mm) of
    the segments from ``a`` to ``b`` (..., 3)."""
    a = np.asarray(a, dtype=float)
    d = np.asarray(b, dtype=float) - a
    length = np.linalg.norm(d, axis=-1)
    safe = np.where(length > 1e-12, length, 1.0)
    u = d / safe[..., None]
    u = np.where((length > 1e-12)[..., None], u, np.array([0.0, 0.0, 1.0]))
    x, y, z = u[..., 0], u[..., 1], u[..., 2]
    flip = z < -1.0 + 1e-9
    k = 1.0 / np.where(flip, 1.0, 1.0 + z)
    R = np.empty(u.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1 - x * x * k
    R[..., 0, 1] = -x * y * k
    R[..., 0, 2] = x
    R[..., 1, 0] = -x * y * k
    R[..., 1, 1] = 1 - y * y * k
    R[..., 1, 2] = y
    R[..., 2, 0] = -x
    R[..., 2, 1] = -y
    R[..., 2, 2] = z
    if np.any(flip):
        R[flip] = np.diag([1.0, -1.0, -1.0])
    return a + 0.5 * d, R, length


@njit(cache=True)
def _frames_and_boxes(a, b, radii, aabb_lo, aabb_hi):
    """Compiled hot path of `CapsuleChain.capsules_collide`: `capsule_frames` of K segments a -> b
    (K, 3), their bounding boxes grown by ``radii`` (K,), and the (capsule, object) pairs (P, 2) whose
    boxes overlap the objects' boxes ``aabb_lo/hi`` (O, 3), capsule-major, for each capsule the
    objects whose box is nearest its centre first."""
    k = a.shape[0]
    centres = np.empty((k, 3))
    R = np.empty((k, 3, 3))
    length = np.empty(k)
    lo = np.empty((k, 3))
    hi = np.empty((k, 3))
    pairs = np.empty((k * aabb_lo.shape[0], 2), dtype=np.int64)
    dist = np.empty(k * aabb_lo.shape[0])
    n = 0
    for i in range(k):
        d = b[i] - a[i]
        ln = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        length[i] = ln
        if ln > 1e-12:
            x, y, z = d[0] / ln, d[1] / ln, d[2] / ln
        else:
            x, y, z = 0.0, 0.0, 1.0
        if z < -1.0 + 1e-9:
            R[i] = 0.0
            R[i, 0, 0], R[i, 1, 1], R[i, 2, 2] = 1.0, -1.0, -1.0
        else:
            c = 1.0 / (1.0 + z)
            R[i, 0, 0], R[i, 0, 1], R[i, 0, 2] = 1 - x * x * c, -x * y * c, x
            R[i, 1, 0], R[i, 1, 1], R[i, 1, 2] = -x * y * c, 1 - y * y * c, y
            R[i, 2, 0], R[i, 2, 1], R[i, 2, 2] = -x, -y, z
        for j in range(3):
            centres[i, j] = a[i, j] + 0.5 * d[j]
            lo[i, j] = min(a[i, j], b[i, j]) - radii[i]
            hi[i, j] = max(a[i, j], b[i, j]) + radii[i]
        first = n
        for o in range(aabb_lo.shape[0]):
            if (lo[i, 0] <= aabb_hi[o, 0] + 1e-6 and hi[i, 0] >= aabb_lo[o, 0] - 1e-6
                    and lo[i, 1] <= aabb_hi[o, 1] + 1e-6 and hi[i, 1] >= aabb_lo[o, 1] - 1e-6
                    and lo[i, 2] <= aabb_hi[o, 2] + 1e-6 and hi[i, 2] >= aabb_lo[o, 2] - 1e-6):
                # objects nearest the capsule centre first (insertion): the likeliest contact
                d = 0.0
                for j in range(3):
                    d += max(aabb_lo[o, j] - centres[i, j], 0.0, centres[i, j] - aabb_hi[o, j]) ** 2
                dist[n] = d
                m = n
                while m > first and dist[m - 1] > d:
                    pairs[m] = pairs[m - 1]
                    dist[m] = dist[m - 1]
                    m -= 1
                pairs[m, 0] = i
                pairs[m, 1] = o
                dist[m] = d
                n += 1
    return centres, R, length, lo, hi, pairs[:n]


@njit(cache=True)
def _to_world(positions, radius, T, margin):
    """Backbones (B, N, 3) robot frame -> points (B, N, 3) in T's frame (non-finite rows -> 0), capsule
    radii (B, N-1) = larger end radius + margin (non-finite -> 0), and which rows are finite (B,)."""
    nb, n = positions.shape[0], positions.shape[1]
    p = np.zeros((nb, n, 3))
    radii = np.zeros((nb, n - 1))
    finite = np.ones(nb, dtype=np.bool_)
    for b in range(nb):
        for i in range(n):
            x, y, z = positions[b, i, 0], positions[b, i, 1], positions[b, i, 2]
            if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
                finite[b] = False
        if finite[b]:
            for i in range(n):
                x, y, z = positions[b, i, 0], positions[b, i, 1], positions[b, i, 2]
                for k in range(3):
                    p[b, i, k] = T[k, 0] * x + T[k, 1] * y + T[k, 2] * z + T[k, 3]
        for i in range(n - 1):
            r = max(radius[b, i], radius[b, i + 1]) + margin
            radii[b, i] = r if math.isfinite(r) else 0.0
    return p, radii, finite


@njit(cache=True)
def _near_in_order(p, radii, finite, lo, cell, step, band, values, spacing):
    """Per row of world polylines ``p`` (B, N, 3) with capsule radii (B, N-1): the capsules the
    distance grid cannot clear, likeliest contact (smallest lower bound) first, as ``order`` (B, N-1)
    with ``count`` (B,) valid entries per row (rows that are not finite: none), and whether the grid
    shows one of them certainly in contact (B,) (`capsule_contact`; FCL need not test that row)."""
    nb, m = radii.shape
    lower = np.empty((nb, m))
    _capsule_lower_bounds(p, radii, lo, cell, step, band, values, spacing, lower)
    order = np.empty((nb, m), dtype=np.int64)
    count = np.zeros(nb, dtype=np.int64)
    hit = np.zeros(nb, dtype=np.bool_)
    for b in range(nb):
        if not finite[b]:
            continue
        k = 0
        for i in range(m):
            if lower[b, i] <= radii[b, i] + 1e-9:
                j = k  # insertion by lower bound; stable for ties
                while j > 0 and lower[b, order[b, j - 1]] > lower[b, i]:
                    order[b, j] = order[b, j - 1]
                    j -= 1
                order[b, j] = i
                k += 1
        count[b] = k
        for j in range(k):
            i = order[b, j]
            if capsule_contact(p[b, i], p[b, i + 1], radii[b, i], lo, cell, step, values, spacing):
                hit[b] = True
                break
    return order, count, hit


@njit(cache=True)
def _world_and_near(positions, radius, T, margin, lo, cell, step, band, values, spacing):
    """`_to_world` then `_near_in_order`, in one compiled call (the planner's hot path)."""
    p, radii, finite = _to_world(positions, radius, T, margin)
    order, count, hit = _near_in_order(p, radii, finite, lo, cell, step, band, values, spacing)
    return p, radii, finite, order, count, hit


@njit(cache=True)
def _candidate_frames(points, radii, caps, aabb_lo, aabb_hi):
    """The capsules ``caps`` (K,) of one polyline ``points`` (N, 3) with capsule radii (N-1,) as FCL
    needs them, ``frames`` (K, 14) = centre (3), rotation (9, row-major), length, radius, and their
    (capsule row, object) pairs (P, 2) whose boxes overlap (see `_frames_and_boxes`)."""
    k = caps.shape[0]
    a = np.empty((k, 3))
    b = np.empty((k, 3))
    r = np.empty(k)
    for j in range(k):
        a[j] = points[caps[j]]
        b[j] = points[caps[j] + 1]
        r[j] = radii[caps[j]]
    centres, R, length, _, _, pairs = _frames_and_boxes(a, b, r, aabb_lo, aabb_hi)
    return _pack_frames(centres, R, length, r), pairs


@njit(cache=True)
def _pack_frames(centres, R, length, radii):
    """Rows of centre (3), rotation (9), length and radius (K, 14) of K capsules."""
    k = length.shape[0]
    frames = np.empty((k, 14))
    for j in range(k):
        frames[j, 0:3] = centres[j]
        frames[j, 3:12] = R[j].ravel()
        frames[j, 12] = length[j]
        frames[j, 13] = radii[j]
    return frames


@njit(cache=True)
def _one_backbone(positions, radius, T, margin, lo, cell, step, band, values, spacing, aabb_lo, aabb_hi):
    """`_world_and_near` then `_candidate_frames` for a single backbone (N, 3) with radii (N,) in
    one compiled call (the planner's single-state hot path): whether it is finite, whether the grid
    shows a contact, and the frames and pairs of the capsules the broadphase cannot clear (none: the
    backbone is free, or certainly not)."""
    n = positions.shape[0]
    p, radii, finite, order, count, hit = _world_and_near(
        positions.reshape((1, n, 3)), radius.reshape((1, n)), T, margin, lo, cell, step, band, values,
        spacing)
    k = 0 if hit[0] else count[0]
    frames, pairs = _candidate_frames(p[0], radii[0], order[0, :k], aabb_lo, aabb_hi)
    return finite[0], hit[0], frames, pairs


def segment_frames(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centres (..., M, 3), rotations (..., M, 3, 3) taking z onto each segment, and lengths (..., M)
    for the M = N - 1 segments of polylines (..., N, 3)."""
    p = np.asarray(points, dtype=float)
    return capsule_frames(p[..., :-1, :], p[..., 1:, :])


def segment_radii(radius_mm: np.ndarray, margin_mm: float = 0.0) -> np.ndarray:
    """Capsule radius per segment (..., N-1): the larger tube radius of its two ends plus margin."""
    r = np.asarray(radius_mm, dtype=float)
    return np.maximum(r[..., 1:], r[..., :-1]) + margin_mm


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


class CollisionWorld:
    """The scene's obstacles as FCL objects, built once, and their distance-grid broadphase.

    Meshes are split into spatially compact chunks (one BVH each) so that an axis-aligned
    bounding-box prefilter sends only nearby capsule/chunk pairs to FCL's narrow phase. ``max_faces``
    bounds the chunk size. With ``broadphase`` a `DistanceGrid` (from memory, the disk cache or built
    here, see `ctrplan.broadphase`) first clears the capsules certainly far from every obstacle; FCL judges
    the rest.
    """

    def __init__(self, obstacles: Sequence[Obstacle], max_faces: int = 256, broadphase: bool = True):
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
                continue
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
        #: the objects' bounding boxes (O, 3) (scene frame, mm) and, grown by each object's margin, the
        #: boxes a capsule must reach to collide (``aabb_lo``, ``aabb_hi``)
        self.box_lo = np.array(lo).reshape(-1, 3)
        self.box_hi = np.array(hi).reshape(-1, 3)
        grow = np.array(self.margins).reshape(-1, 1)
        self.aabb_lo = self.box_lo - grow
        self.aabb_hi = self.box_hi + grow
        self._request = fcl.CollisionRequest()
        #: the broadphase grid (None when disabled or without obstacles)
        self.grid: DistanceGrid | None = grid_for(self.obstacles) if self.broadphase else None

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


class CapsuleChain:
    """A chain of ``n_segments`` FCL capsules, placed lazily and updated in place.

    `set` (or `load_frames`) stores the capsule frames of a new configuration (vectorised); a
    capsule's FCL object is only updated when a query needs it (capsules far from every obstacle
    never are).
    """

    def __init__(self, n_segments: int):
        self.n_segments = int(n_segments)
        self._geoms = [fcl.Capsule(0.5, 1.0) for _ in range(self.n_segments)]
        self._objects = [fcl.CollisionObject(g, fcl.Transform()) for g in self._geoms]
        self._placed = np.zeros(self.n_segments, dtype=bool)
        self._grown = np.zeros(self.n_segments)  # the obstacle margin each capsule's radius has now
        self._frames = np.zeros((0, 14))
        self.seg_lo = self.seg_hi = np.zeros((0, 3))
        self._result = fcl.CollisionResult()
        #: FCL narrow-phase tests (capsule, object pairs) run by `collides`
        self.tests = 0

    def set(self, points: np.ndarray, radii: np.ndarray) -> None:
        """New configuration: points (N, 3) with per-segment radii (N-1,) (the world's frame)."""
        p = np.asarray(points, dtype=float)
        if p.shape[0] - 1 > self.n_segments:
            raise ValueError(f"chain has {self.n_segments} capsules, got {p.shape[0] - 1} segments")
        centres, R, length = segment_frames(p)
        radii = np.asarray(radii, dtype=float)
        self.load_frames(_pack_frames(centres, R, length, radii))
        r = radii[:, None]
        self.seg_lo, self.seg_hi = np.minimum(p[:-1], p[1:]) - r, np.maximum(p[:-1], p[1:]) + r

    def load_frames(self, frames: np.ndarray) -> None:
        """New configuration from capsule frames (K, 14) (see `_pack_frames`): for `collides` with
        its candidate pairs; `contacts`, `distance` and `collides` without pairs need `set`."""
        self._frames = frames
        self._placed[:] = False

    def _object(self, i: int, grow_mm: float = 0.0) -> fcl.CollisionObject:
        """Capsule i's FCL object, placed, with its radius grown by ``grow_mm`` (an obstacle's margin)."""
        o = self._objects[i]
        if not self._placed[i]:
            f = self._frames[i]
            g = self._geoms[i]
            g.radius = float(f[13]) + grow_mm
            g.lz = float(f[12])
            o.setRotation(f[3:12].reshape(3, 3))
            o.setTranslation(f[0:3])
            self._placed[i] = True
            self._grown[i] = grow_mm
        elif self._grown[i] != grow_mm:
            self._geoms[i].radius = float(self._frames[i, 13]) + grow_mm
            self._grown[i] = grow_mm
        return o

    def collides(self, world: CollisionWorld, pairs: np.ndarray | None = None) -> bool:
        """True if any capsule touches any obstacle, each grown by that obstacle's margin (distal
        capsules are tested first). ``pairs``: precomputed candidate (capsule, object) pairs."""
        req, res = world._request, self._result
        objs, margins = world._objects, world.margins
        if pairs is None:
            pairs = world.candidates(self.seg_lo, self.seg_hi)
        for i, j in pairs:
            self.tests += 1
            if fcl.collide(self._object(i, margins[j]), objs[j], req, res):  # this test's contact count
                res.contacts.clear()  # a result only grows on contact: reused, not rebuilt
                return True
        return False

    def capsules_collide(self, world: CollisionWorld, points: np.ndarray, radii: np.ndarray,
                         caps: np.ndarray) -> bool:
        """Whether any of the capsules ``caps`` (K,) of one polyline ``points`` (N, 3) (world frame,
        mm) with capsule radii (N-1,) touches an obstacle, tested in the given order (replaces the
        chain's configuration)."""
        frames, pairs = _candidate_frames(points, radii, caps, world.aabb_lo, world.aabb_hi)
        self.load_frames(frames)
        return self.collides(world, pairs)

    def contacts(self, world: CollisionWorld) -> list[tuple[int, str]]:
        """Every (capsule index, obstacle name) pair in contact (with the obstacle's margin)."""
        out = set()
        for i, j in world.candidates(self.seg_lo, self.seg_hi):
            if fcl.collide(self._object(i, world.margins[j]), world._objects[j], world._request,
                           fcl.CollisionResult()):
                out.add((int(i), world.names[j]))
        return sorted(out)

    def distances(self, world: CollisionWorld, cap_mm: float) -> np.ndarray:
        """Distance (mm) from each capsule (M,) to the nearest obstacle (0 in contact), capped at
        ``cap_mm``: an obstacle whose bounding box is farther than the best so far is not queried."""
        out = np.full(len(self._frames), float(cap_mm))
        if len(world) == 0:
            return out
        lower = self._box_gaps(world)
        req = fcl.DistanceRequest()
        for i in range(len(out)):
            for j in np.argsort(lower[i]):
                if lower[i, j] >= out[i]:
                    break
                d = fcl.distance(self._object(i), world._objects[j], req, fcl.DistanceResult())
                out[i] = min(out[i], max(float(d), 0.0))
                if out[i] == 0.0:
                    break
        return out

    def _box_gaps(self, world: CollisionWorld, objects: np.ndarray | None = None) -> np.ndarray:
        """Gaps (M, O) between the capsules' bounding boxes and the objects' (all, or ``objects``):
        lower bounds of their distances (mm)."""
        lo, hi = (world.box_lo, world.box_hi) if objects is None else (world.box_lo[objects],
                                                                        world.box_hi[objects])
        gap = np.maximum(0.0, np.maximum(lo[None] - self.seg_hi[:, None], self.seg_lo[:, None] - hi[None]))
        return np.linalg.norm(gap, axis=-1)

    def distance(self, world: CollisionWorld, objects: np.ndarray | None = None,
                 below: float = np.inf) -> Clearance:
        """Smallest distance between the chain and the obstacles (0 when in contact): all objects
        of ``world`` or the object indices ``objects``; a distance of ``below`` or more is not
        searched for (the result is then the no-hit `Clearance` with distance inf).

        Pairs are visited by increasing bounding-box gap; the search stops when that gap (a lower
        bound of the distance) reaches the best distance found, so the result is exact.
        """
        best = Clearance(np.inf, -1, "", np.full(3, np.nan), np.full(3, np.nan))
        if len(world) == 0 or len(self._frames) == 0:
            return best
        ids = np.arange(len(world)) if objects is None else np.asarray(objects)
        lower = self._box_gaps(world, ids)  # (M, O)
        req = fcl.DistanceRequest(enable_nearest_points=True)
        for flat in np.argsort(lower, axis=None):
            i, k = divmod(int(flat), lower.shape[1])
            j = int(ids[k])
            if lower[i, k] >= min(best.distance_mm, below):
                break
            res = fcl.DistanceResult()
            d = fcl.distance(self._object(i), world._objects[j], req, res)
            if d < 0 or (d == 0 and fcl.collide(self._object(i), world._objects[j], world._request,
                                                 fcl.CollisionResult())):
                return Clearance(0.0, i, world.names[j], np.full(3, np.nan), np.full(3, np.nan))
            if d < best.distance_mm:
                best = Clearance(float(d), i, world.names[j], *self._robot_first(i, res.nearest_points))
        return best

    def _robot_first(self, i: int, points) -> tuple[np.ndarray, np.ndarray]:
        """FCL's two nearest points of capsule i and an obstacle as (robot point, obstacle point):
        FCL gives them in either order (primitive against mesh: the mesh's first), so the robot's
        is the one nearer the capsule's axis."""
        f = self._frames[i]
        axis = f[3:12].reshape(3, 3)[:, 2]
        p = np.array(points, dtype=float)
        t = np.clip((p - f[0:3]) @ axis, -0.5 * f[12], 0.5 * f[12])
        off_axis = np.linalg.norm(p - f[0:3] - t[:, None] * axis, axis=1)
        return (p[0], p[1]) if off_axis[0] <= off_axis[1] else (p[1], p[0])


@dataclass(frozen=True)
class Clearance:
    """Result of a distance query: distance (mm, 0 on contact), capsule index, obstacle name and the
    nearest points (scene frame; NaN on contact)."""

    distance_mm: float
    segment: int
    obstacle: str
    robot_point: np.ndarray
    obstacle_point: np.ndarray


@dataclass(frozen=True)
class StructureClearance:
    """The smallest distance (mm; robot surface to the structure, 0 on contact) between the robot
    along a path and one obstacle, and where: the path state (row of the backbones), the arc length
    (mm from the front plate) and the robot's and the structure's nearest points (scene frame, mm).
    ``margin_mm`` is the structure's own margin, ``required_mm`` the clearance the collision checks
    demand from it (the robot's margin plus the structure's)."""

    name: str
    margin_mm: float
    required_mm: float
    distance_mm: float
    state: int
    arc_length_mm: float
    robot_point: np.ndarray
    obstacle_point: np.ndarray

    @property
    def below_margin(self) -> bool:
        """In contact, or closer than the checks allow (`MARGIN_TOLERANCE_MM` of rounding aside)."""
        return self.distance_mm <= 0.0 or self.distance_mm < self.required_mm - MARGIN_TOLERANCE_MM

    def to_json(self) -> dict:
        """The record as ``plan --json`` lists it (non-finite numbers as null)."""
        def num(x: float) -> float | None:
            return round(float(x), 4) if np.isfinite(x) else None

        return {"name": self.name, "clearance_mm": num(self.distance_mm), "margin_mm": self.margin_mm,
                "required_mm": self.required_mm, "below_margin": self.below_margin,
                "state": self.state, "arc_length_mm": num(self.arc_length_mm),
                "robot_point_mm": [num(x) for x in self.robot_point],
                "structure_point_mm": [num(x) for x in self.obstacle_point]}


#: Distances within this (mm) of a required clearance are not flagged (FCL's distance and collision
#: tests round differently).
MARGIN_TOLERANCE_MM = 1e-6

_WARM = False


def warm_kernels() -> None:
    """Compile (or load from numba's cache) the boolean-check kernels once per process, so that no
    timed planning run pays for it."""
    global _WARM
    if _WARM:
        return
    a = np.zeros((1, 2, 3))
    a[0, 1, 2] = 1.0
    _to_world(a, np.ones((1, 2)), np.eye(4), 0.0)
    _candidate_frames(a[0], np.ones(1), np.zeros(1, dtype=np.int64), np.zeros((1, 3)), np.ones((1, 3)))
    grid = DistanceGrid(np.zeros(3), 1.0, 1.0, np.zeros((1, 1, 1), dtype=np.uint8))
    grid.segment_lower_bounds(a)
    args = (a, np.ones((1, 2)), np.eye(4), 0.0, grid.lo, grid.cell_mm, grid.step_mm, grid.band_mm,
            grid.values, grid.spacing_mm)
    _world_and_near(*args)
    _one_backbone(a[0], np.ones(2), *args[2:], np.zeros((1, 3)), np.ones((1, 3)))
    _WARM = True


class RobotCollisionChecker:
    """Backbones (robot frame) against a scene: boolean checks for planning, distances for paths.

    Args:
        world: the scene's `CollisionWorld` (built once, shareable).
        base_pose: robot base in the scene frame (4x4).
        points: backbone points per configuration (capsules = points - 1).
        margin_mm: added to every capsule radius in the boolean checks.
    """

    def __init__(self, world: CollisionWorld, base_pose: np.ndarray, points: int,
                 margin_mm: float = 0.0):
        self.world = world
        self.base_pose = np.ascontiguousarray(base_pose, dtype=float)
        self.points = int(points)
        self.margin_mm = float(margin_mm)
        self.chain = CapsuleChain(self.points - 1)
        grid = world.grid
        #: the grid's arguments of the compiled broadphase, bound once (None without a grid)
        self._grid_args = None if grid is None or not len(world) else (
            self.base_pose, self.margin_mm, grid.lo, grid.cell_mm, grid.step_mm, grid.band_mm, grid.values,
            grid.spacing_mm)
        warm_kernels()
        #: backbones checked, how many of them the broadphase could not clear alone (went to FCL), and
        #: how many the grid showed certainly in contact (no FCL)
        self.checks = 0
        self.narrow_checks = 0
        self.grid_contacts = 0

    @classmethod
    def for_scene(cls, scene: Scene, points: int | None = None, margin_mm: float | None = None,
                  world: CollisionWorld | None = None) -> RobotCollisionChecker:
        s = scene.settings
        return cls(world or CollisionWorld.from_scene(scene), scene.base_pose,
                   s.points if points is None else points, s.margin_mm if margin_mm is None else margin_mm)

    def _place(self, positions: np.ndarray, radius: np.ndarray, margin: float) -> None:
        self.chain.set(transform_points(self.base_pose, positions), segment_radii(radius, margin))

    def is_free(self, positions: np.ndarray, radius: np.ndarray) -> bool:
        """Boolean check of one backbone: positions (N, 3) robot frame, tube radius (N,) mm; NaN
        positions are not free. With the broadphase grid: one compiled call, then FCL on the capsules
        it cannot clear (the planner's single-state hot path)."""
        if self._grid_args is None:
            return bool(self.free_batch(positions[None], radius[None])[0])
        self.checks += 1
        finite, hit, frames, pairs = _one_backbone(
            np.ascontiguousarray(positions, dtype=float), np.ascontiguousarray(radius, dtype=float),
            *self._grid_args, self.world.aabb_lo, self.world.aabb_hi)
        if not finite:
            return False
        if hit:
            self.grid_contacts += 1
            return False
        if len(frames):
            self.narrow_checks += 1
            self.chain.load_frames(frames)
            return not self.chain.collides(self.world, pairs)
        return True

    def free_batch(self, positions: np.ndarray, radius: np.ndarray,
                   stop_at_first: bool = False) -> np.ndarray:
        """Boolean checks of B backbones (B, N, 3) robot frame / radii (B, N) mm; NaN rows are not free.
        The broadphase runs on the whole batch at once; FCL then tests each row's remaining capsules,
        likeliest contact first, rows in order. With ``stop_at_first``, rows after the first collision
        are left not free."""
        p, radii, finite, caps, count, hit = self._world_and_near(
            np.ascontiguousarray(positions, dtype=float), np.ascontiguousarray(radius, dtype=float))
        cleared = finite & (count == 0)
        if cleared.all():
            self.checks += len(cleared)
            return cleared
        free = np.zeros(len(finite), dtype=bool)
        for i in range(len(finite)):
            self.checks += 1
            if cleared[i] or not finite[i] or hit[i]:
                ok = bool(cleared[i])
                self.grid_contacts += int(hit[i])
            else:
                self.narrow_checks += 1
                ok = not self.chain.capsules_collide(self.world, p[i], radii[i], caps[i, :count[i]])
            free[i] = ok
            if stop_at_first and not ok:
                break
        return free

    def _world_and_near(self, positions: np.ndarray, radius: np.ndarray) -> tuple[np.ndarray, ...]:
        """Backbones (B, N, 3) robot frame with tube radii (B, N) -> world points (B, N, 3), capsule
        radii with the margin (B, N-1), finite rows (B,), the capsules the broadphase cannot
        clear, likeliest contact first (B, N-1), with their count (B,) (see `CollisionWorld.near`),
        and the rows the grid shows certainly in contact (B,) (none without a grid)."""
        if self._grid_args is not None:
            return _world_and_near(positions, radius, *self._grid_args)
        p, radii, finite = _to_world(positions, radius, self.base_pose, self.margin_mm)
        near, priority = self.world.near(p, radii)
        near &= finite[:, None]
        order = np.argsort(np.where(near, priority, np.inf), axis=1, kind="stable")
        return p, radii, finite, order, near.sum(axis=1), np.zeros(len(finite), dtype=bool)

    def contacts(self, positions: np.ndarray, radius: np.ndarray) -> list[tuple[int, str]]:
        """(segment, obstacle) pairs in contact for one backbone (with the margin)."""
        self._place(positions, radius, self.margin_mm)
        return self.chain.contacts(self.world)

    def clearances(self, positions: np.ndarray, radius: np.ndarray, cap_mm: float) -> np.ndarray:
        """Distance (mm) from the surface of each capsule (N-1,) (no margin) to the nearest
        obstacle, 0 on contact, capped at ``cap_mm``; NaN where the backbone is not finite."""
        if not np.all(np.isfinite(positions)):
            return np.full(len(positions) - 1, np.nan)
        self._place(positions, radius, 0.0)
        return self.chain.distances(self.world, cap_mm)

    def clearance(self, positions: np.ndarray, radius: np.ndarray) -> Clearance:
        """Distance from the robot's surface (no margin) to the nearest obstacle; 0 on contact."""
        if not np.all(np.isfinite(positions)):
            return Clearance(0.0, -1, "", np.full(3, np.nan), np.full(3, np.nan))
        if len(self.world) == 0:
            return Clearance(np.inf, -1, "", np.full(3, np.nan), np.full(3, np.nan))
        self._place(positions, radius, 0.0)
        return self.chain.distance(self.world)

    def structure_clearances(self, positions: np.ndarray, radius: np.ndarray,
                             s_mm: np.ndarray) -> list[StructureClearance]:
        """For every obstacle of the world, its `StructureClearance` over the backbones (K, N, 3)
        (robot frame, mm) with tube radii (K, N) and arc lengths (K, N) (mm): the exact smallest
        distance (no margins; states whose backbone is not finite are skipped). States are searched
        by increasing bounding-box gap to the structure and the search stops when the gap reaches the
        best distance found, so the few states near a structure are the ones measured."""
        pts = transform_points(self.base_pose, positions)
        radii = segment_radii(radius)
        r = radii[..., None]
        seg_lo, seg_hi = np.minimum(pts[:, :-1], pts[:, 1:]) - r, np.maximum(pts[:, :-1], pts[:, 1:]) + r
        finite = np.all(np.isfinite(seg_lo) & np.isfinite(seg_hi), axis=(1, 2))
        owner = np.asarray(self.world.owner)
        out = []
        for index, obstacle in enumerate(self.world.obstacles):
            ids = np.flatnonzero(owner == index)
            gap = np.maximum(0.0, np.maximum(self.world.box_lo[ids] - seg_hi[:, :, None],
                                             seg_lo[:, :, None] - self.world.box_hi[ids]))
            lower = np.where(finite, np.linalg.norm(gap, axis=-1).min(axis=(1, 2)), np.inf)  # (K,)
            best, state = Clearance(np.inf, -1, "", np.full(3, np.nan), np.full(3, np.nan)), -1
            for k in np.argsort(lower, kind="stable"):
                if lower[k] >= best.distance_mm:
                    break
                self.chain.set(pts[k], radii[k])
                c = self.chain.distance(self.world, ids, below=best.distance_mm)
                if c.distance_mm < best.distance_mm:
                    best, state = c, int(k)
                if best.distance_mm == 0.0:
                    break
            out.append(self._where(obstacle, best, state, pts, s_mm))
        return out

    def _where(self, obstacle: Obstacle, c: Clearance, state: int, pts: np.ndarray,
               s_mm: np.ndarray) -> StructureClearance:
        """`StructureClearance` of the nearest hit ``c`` at row ``state`` of the scene-frame
        backbones ``pts`` (K, N, 3) with arc lengths ``s_mm`` (K, N); in contact, the robot point is
        the middle of the touching capsule's axis."""
        arc, robot = np.nan, c.robot_point
        if state >= 0:
            a, b = pts[state, c.segment], pts[state, c.segment + 1]
            if not np.all(np.isfinite(robot)):
                robot = 0.5 * (a + b)
            d = b - a
            t = float(np.clip((robot - a) @ d / max(float(d @ d), 1e-300), 0.0, 1.0))
            s0, s1 = s_mm[state, c.segment], s_mm[state, c.segment + 1]
            arc = float(s0 + t * (s1 - s0))
        return StructureClearance(obstacle.name, float(obstacle.margin_mm),
                                  self.margin_mm + float(obstacle.margin_mm), c.distance_mm, state, arc,
                                  robot, c.obstacle_point)
