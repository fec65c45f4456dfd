"""A backbone as a chain of capsules (mm): the capsule frames and bounding boxes of backbone
segments, the compiled kernels that place a batch of backbones in the scene and ask the distance
grid which capsules need FCL, and `CapsuleChain`, the FCL capsules updated in place.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import fcl
import numpy as np
from numba import njit

from ctrplan.collision.broadphase import (
    _capsule_lower_bounds,
    capsule_contact,
)

if TYPE_CHECKING:
    from ctrplan.collision.world import CollisionWorld


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


@dataclass(frozen=True)
class Clearance:
    """Result of a distance query: distance (mm, 0 on contact), capsule index, obstacle name and the
    nearest points (scene frame; NaN on contact)."""

    distance_mm: float
    segment: int
    obstacle: str
    robot_point: np.ndarray
    obstacle_point: np.ndarray


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
