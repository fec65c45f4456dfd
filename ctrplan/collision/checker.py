"""`RobotCollisionChecker`: backbones (robot frame, mm) against a `CollisionWorld` -- boolean checks
for planning (distance grid first, FCL for the rest), distances and per-structure clearances for
final paths.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ctrplan.collision.broadphase import (
    DistanceGrid,
)
from ctrplan.collision.capsules import (
    CapsuleChain,
    Clearance,
    _candidate_frames,
    _one_backbone,
    _to_world,
    _world_and_near,
    segment_radii,
)
from ctrplan.collision.world import CollisionWorld
from ctrplan.scene.geometry import transform_points
from ctrplan.scene.objects import Obstacle, Scene


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

    def blockers(self, positions: np.ndarray, radius: np.ndarray) -> dict[str, float]:
        """The obstacles one backbone (positions (N, 3) robot frame, tube radii (N,) mm) touches with
        the margins (the robot's and each obstacle's own), each with the distance (mm) from the robot's
        surface to it without margins (0 on contact): how much margin it would take to free it."""
        self._place(positions, radius, self.margin_mm)
        names = sorted({name for _, name in self.chain.contacts(self.world)})
        if not names:
            return {}
        self._place(positions, radius, 0.0)
        owner = np.asarray(self.world.owner)
        index = {o.name: i for i, o in enumerate(self.world.obstacles)}
        return {n: float(self.chain.distance(self.world, np.flatnonzero(owner == index[n])).distance_mm)
                for n in names}

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

    def structure_clearances(self, positions: np.ndarray, radius: np.ndarray, s_mm: np.ndarray,
                             stop: Callable[[], bool] | None = None) -> list[StructureClearance] | None:
        """For every obstacle of the world, its `StructureClearance` over the backbones (K, N, 3)
        (robot frame, mm) with tube radii (K, N) and arc lengths (K, N) (mm): the exact smallest
        distance (no margins; states whose backbone is not finite are skipped). States are searched
        by increasing bounding-box gap to the structure and the search stops when the gap reaches the
        best distance found, so the few states near a structure are the ones measured. ``stop``,
        asked before each obstacle: when it says so, None (the measurement abandoned)."""
        pts = transform_points(self.base_pose, positions)
        radii = segment_radii(radius)
        r = radii[..., None]
        seg_lo, seg_hi = np.minimum(pts[:, :-1], pts[:, 1:]) - r, np.maximum(pts[:, :-1], pts[:, 1:]) + r
        finite = np.all(np.isfinite(seg_lo) & np.isfinite(seg_hi), axis=(1, 2))
        owner = np.asarray(self.world.owner)
        out = []
        for index, obstacle in enumerate(self.world.obstacles):
            if stop is not None and stop():
                return None
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
