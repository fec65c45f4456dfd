"""The frozen scene objects (mm, rad, scene frame): `Obstacle`, `TargetRegion`, `PlannerSettings`
and the `Scene` that holds them with the robot, its base pose and its start. Files are read by
`ctrplan.scene.loader`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from ctrplan.model.robot import Robot
from ctrplan.scene.geometry import transform_points


@dataclass(frozen=True)
class Obstacle:
    """One obstacle in the scene frame (mm).

    ``kind`` is ``mesh`` (``vertices`` (V, 3), ``faces`` (F, 3), already in the scene frame) or a
    primitive: ``sphere`` (radius), ``box`` (size (3,)), ``cylinder``/``capsule`` (radius, length along
    the local z axis), placed by ``pose`` (4x4, local -> scene). ``margin_mm``: the structure's own
    no-go margin, added to the collision distance for it in every check (`ctrplan.collision`).
    ``space``: the frame a mesh file declares (`ctrplan.scene.orientation.declared_space`; its
    vertices are converted to the scene's anatomy frame where that is declared), or None.
    """

    name: str
    kind: str
    pose: np.ndarray = field(default_factory=lambda: np.eye(4))
    radius: float = 0.0
    length: float = 0.0
    size: tuple[float, float, float] = (0.0, 0.0, 0.0)
    vertices: np.ndarray | None = None
    faces: np.ndarray | None = None
    source: str | None = None
    margin_mm: float = 0.0
    space: str | None = None

    def to_trimesh(self):
        """Triangle mesh of the obstacle in the scene frame (primitives tessellated)."""
        import trimesh

        if self.kind == "mesh":
            return trimesh.Trimesh(self.vertices, self.faces, process=False)
        if self.kind == "sphere":
            m = trimesh.creation.icosphere(subdivisions=3, radius=self.radius)
        elif self.kind == "box":
            m = trimesh.creation.box(extents=self.size)
        elif self.kind == "cylinder":
            m = trimesh.creation.cylinder(radius=self.radius, height=self.length, sections=32)
        elif self.kind == "capsule":
            m = trimesh.creation.capsule(height=self.length, radius=self.radius, count=[24, 12])
        else:  # pragma: no cover - guarded by the loader
            raise ValueError(self.kind)
        m.apply_transform(self.pose)
        return m

    def translated(self, shift_mm) -> Obstacle:
        """The obstacle moved by ``shift_mm`` (3,) (mm, scene frame): tissue that shifted."""
        shift = np.asarray(shift_mm, dtype=float)
        if self.kind == "mesh":
            return replace(self, vertices=np.asarray(self.vertices, dtype=float) + shift)
        pose = np.array(self.pose, dtype=float)
        pose[:3, 3] += shift
        return replace(self, pose=pose)

    @property
    def bounds(self) -> np.ndarray:
        """Axis-aligned bounds (2, 3) in the scene frame."""
        v = self.vertices if self.kind == "mesh" else np.asarray(self.to_trimesh().vertices)
        return np.stack([v.min(axis=0), v.max(axis=0)])


@dataclass(frozen=True)
class TargetRegion:
    """Where the tip must end: an ellipsoid (a sphere when all semi-axes are equal), scene frame;
    optionally with an approach ``direction`` (unit vector) that the tip's tangent must be within
    ``angle_tolerance_rad`` of."""

    center: np.ndarray
    semi_axes: np.ndarray
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    kind: str = "sphere"
    direction: np.ndarray | None = None
    angle_tolerance_rad: float = math.pi

    def angle_rad(self, tangent: np.ndarray) -> np.ndarray:
        """Angle (rad) between tip tangents (..., 3) (scene frame) and the approach direction
        (0 without one; pi for non-finite tangents)."""
        t = np.asarray(tangent, dtype=float)
        if self.direction is None:
            return np.zeros(t.shape[:-1])
        c = (t @ self.direction) / np.maximum(np.linalg.norm(t, axis=-1), 1e-300)
        return np.where(np.isfinite(c), np.arccos(np.clip(c, -1.0, 1.0)), math.pi)

    def direction_ok(self, tangent: np.ndarray) -> np.ndarray:
        """Whether tip tangents (..., 3) (scene frame) respect the approach direction."""
        return self.angle_rad(tangent) <= self.angle_tolerance_rad + 1e-12

    @classmethod
    def sphere(cls, center, radius: float) -> TargetRegion:
        return cls(np.asarray(center, dtype=float), np.full(3, float(radius)), np.eye(3), "sphere")

    @property
    def tolerance_mm(self) -> float:
        """Sphere radius; for an ellipsoid its smallest semi-axis."""
        return float(np.min(self.semi_axes))

    def _local(self, p: np.ndarray) -> np.ndarray:
        return (np.asarray(p, dtype=float) - self.center) @ self.rotation

    def normalized_radius(self, p: np.ndarray) -> np.ndarray:
        """1 on the surface, < 1 inside (..., )."""
        return np.linalg.norm(self._local(p) / self.semi_axes, axis=-1)

    def contains(self, p: np.ndarray, slack: float = 1e-9) -> np.ndarray:
        return self.normalized_radius(p) <= 1.0 + slack

    def distance(self, p: np.ndarray) -> np.ndarray:
        """Distance outside the region along the ray from the centre (exact for spheres), 0 inside."""
        rho = self.normalized_radius(p)
        r = np.linalg.norm(np.asarray(p, dtype=float) - self.center, axis=-1)
        with np.errstate(divide="ignore", invalid="ignore"):
            d = np.where(rho > 1.0, r * (1.0 - 1.0 / np.maximum(rho, 1e-300)), 0.0)
        return d

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` points uniformly inside the region (n, 3)."""
        u = rng.normal(size=(n, 3))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        r = rng.uniform(size=(n, 1)) ** (1.0 / 3.0)
        return (u * r * self.semi_axes) @ self.rotation.T + self.center

    def to_yaml(self) -> dict[str, Any]:
        """The region as a scene file's ``target`` mapping (see the module docstring)."""
        if self.kind == "sphere":
            d: dict[str, Any] = {"point": self.center.tolist(), "tolerance_mm": float(self.semi_axes[0])}
        else:
            d = {"ellipsoid": {"center": self.center.tolist(), "semi_axes_mm": self.semi_axes.tolist(),
                               "rotation": {"matrix": self.rotation.tolist()}}}
        if self.direction is not None:
            d["direction"] = self.direction.tolist()
            d["angle_tolerance_deg"] = math.degrees(self.angle_tolerance_rad)
        return d

    def to_dict(self) -> dict[str, Any]:
        d = {"kind": self.kind, "center_mm": self.center.tolist(),
             "semi_axes_mm": self.semi_axes.tolist(), "rotation": self.rotation.tolist()}
        if self.direction is not None:
            d["direction"] = self.direction.tolist()
            d["angle_tolerance_deg"] = math.degrees(self.angle_tolerance_rad)
        return d


@dataclass(frozen=True)
class PlannerSettings:
    """Planner defaults of a scene; the CLI overrides planner, time limit and seed.

    Attributes:
        planner: a planner name; `ctrplan.planning.planners` holds the table of them and checks it
            where the scene is planned (the model layer knows no planners).
        time_limit_s: the search's time budget (s): it sets the default work budget (what this many
            seconds buy on the reference machine, `ctrplan.planning.budget`) and the wall-clock guard
            (`GUARD_FACTOR` times it) that stops a search on a slow or overloaded machine.
        max_states: the search's work budget: configurations the kinematics backend evaluates for
            goal sampling plus search (None: from ``time_limit_s``). It decides the verdict, so a
            seeded search gives the same result under any load.
        seed: OMPL and numpy seed (None: random).
        margin_mm: added to every capsule radius in planning and validation.
        surrogate_margin_mm: extra margin everywhere while planning with an approximate backend
            (the PINN) so that its error rarely makes the exact robot touch; None: the model card's
            calibrated error bound by arc-length region. Validation uses ``margin_mm`` alone.
        surrogate_coverage: which of the model card's calibrated bounds to plan with: the
            probability that a configuration's error in a region is within its bound.
        points: backbone points (capsules + 1) per configuration.
        resolution_mm: edge checking resolution in the planning metric (mm; radians weighted by
            ``mm_per_rad``).
        mm_per_rad: metric weight of a tube rotation against a translation.
        range_mm: maximum edge length of tree planners (None: OMPL default, 20 % of the extent).
        simplify: shortcut the path after solving (`ctrplan.planning.shortcut`).
        goal_samples: goal configurations produced per inverse-kinematics batch.
        repair: try to repair a path that collides under the exact model.
    """

    planner: str = "corridor"
    time_limit_s: float = 10.0
    max_states: int | None = None
    seed: int | None = None
    margin_mm: float = 0.2
    surrogate_margin_mm: float | None = None
    surrogate_coverage: float = 0.8
    points: int = 40
    resolution_mm: float = 1.0
    mm_per_rad: float = 40.0
    range_mm: float | None = None
    simplify: bool = True
    goal_samples: int = 8
    repair: bool = True


@dataclass(frozen=True)
class Scene:
    """A validated planning problem. Lengths in mm, angles in rad, poses 4x4 (local -> scene)."""

    name: str
    robot: Robot
    base_pose: np.ndarray
    obstacles: tuple[Obstacle, ...]
    target: TargetRegion
    start: np.ndarray
    settings: PlannerSettings = field(default_factory=PlannerSettings)
    description: str = ""
    path: Path | None = None
    joint_limits: tuple[np.ndarray, np.ndarray] | None = None
    key_lines: dict = field(default_factory=dict)
    anatomy: dict[str, str] | None = None  # scene axis ("x", "y", "z") -> patient direction of +axis

    def where(self, key: str) -> str:
        """``file:line: key`` for messages about a key (dotted, e.g. ``planner.planner``), as the
        loader's errors."""
        loc = str(self.path) if self.path else self.name
        line = self.key_lines.get(key)
        return f"{loc}:{line}: {key}" if line else f"{loc}: {key}"

    @property
    def joint_box(self) -> tuple[np.ndarray, np.ndarray]:
        """Planning box (lower, upper) in box coordinates (mm, rad): the robot's snap-free domain,
        narrowed by the scene's ``joint_limits``."""
        if self.joint_limits is not None:
            return self.joint_limits
        return self.robot.domain.box_lower, self.robot.domain.box_upper

    def with_settings(self, **changes: Any) -> Scene:
        return replace(self, settings=replace(self.settings, **changes))

    @cached_property
    def base_inverse(self) -> np.ndarray:
        T = np.eye(4)
        R = self.base_pose[:3, :3]
        T[:3, :3] = R.T
        T[:3, 3] = -R.T @ self.base_pose[:3, 3]
        return T

    def to_scene(self, p_robot: np.ndarray) -> np.ndarray:
        """Robot-frame points (..., 3) -> scene frame."""
        return transform_points(self.base_pose, p_robot)

    def to_robot(self, p_scene: np.ndarray) -> np.ndarray:
        return transform_points(self.base_inverse, p_scene)

    def direction_to_scene(self, v_robot: np.ndarray) -> np.ndarray:
        """Robot-frame directions (..., 3) -> scene frame (rotation only)."""
        return np.asarray(v_robot, dtype=float) @ self.base_pose[:3, :3].T

    def merged_obstacles(self):
        """All obstacles as one trimesh (scene frame, mm)."""
        import trimesh

        meshes = [o.to_trimesh() for o in self.obstacles]
        if not meshes:
            return trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=int))
        return trimesh.util.concatenate(meshes)
