"""The planning model: what a plan knows before it searches, built once and shared.

As Pinocchio splits a robot into a frozen ``Model`` and a per-computation ``Data``, a plan splits into
a frozen `PlanningModel` -- the scene, the planning backend (with its capsule margins), the exact
backend, the collision world, the joint space and the stability decision -- built once in
`ctrplan.planning.planner.plan` and handed to search, validation, repair and the writers, and the
per-search data (`ctrplan.planning.validity.ConfigurationChecker`: caches, counters, hooks).

`StabilityDecision` is the one place that decides "this robot is certified snap-free over its domain,
else check elastic stability per state": every exact backend a plan, a validation, a scene check or a
design uses goes through it (`exact_backend`), so a caller cannot forget it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from ctrplan.collision.checker import RobotCollisionChecker
from ctrplan.collision.world import CollisionWorld
from ctrplan.kinematics.backbone import Backbone
from ctrplan.kinematics.base import DEFAULT_POINTS, Backend, Body, arc_fractions
from ctrplan.kinematics.error_bound import region_bounds_mm, region_margins_mm
from ctrplan.kinematics.pinn import ERROR_BOUND_KEY
from ctrplan.kinematics.registry import EXACT_MODEL, backend_kind, exact_companion
from ctrplan.kinematics.stability import is_certified
from ctrplan.model.robot import Robot
from ctrplan.planning.space import BoxSpace
from ctrplan.scene.objects import Scene

#: Surrogate margin (mm) for a model whose card has no calibrated error bound.
DEFAULT_SURROGATE_MARGIN_MM = 0.3


@dataclass(frozen=True)
class StabilityDecision:
    """Whether states need an elastic stability test: not when the robot is certified snap-free over
    its joint domain (`ctrplan.kinematics.stability.is_certified`), else every state an exact backend computes
    is tested (an unstable one is invalid: the robot would snap there). Made once per robot."""

    certified: bool

    @classmethod
    def for_robot(cls, robot: Robot) -> StabilityDecision:
        return cls(is_certified(robot))

    @property
    def continuation(self) -> bool:
        """Whether an exact solve may start from a neighbour's solution or a surrogate's guess: on a
        certified robot the equilibrium branch has no fold in the domain, so every start reaches the
        state a cold solve reaches. Otherwise checks start cold: continuation along a path could
        follow a branch on past where the cold solution is unstable, and call a snapping state
        safe."""
        return self.certified

    def apply(self, backend: Backend) -> Backend:
        """``backend`` as planning and validation must use it: testing stability per state unless the
        robot is certified (a surrogate, which cannot test it, is returned as it is)."""
        return backend if self.certified else backend.checking_stability()

    @property
    def invalid(self) -> str:
        """What makes a state invalid, for messages."""
        return "in collision" if self.certified else "in collision or elastically unstable"


def exact_backend(robot: Robot) -> Backend:
    """The exact model of ``robot`` (`ctrplan.kinematics.registry.EXACT_MODEL`) as planning uses it
    (`StabilityDecision.apply`)."""
    return StabilityDecision.for_robot(robot).apply(backend_kind(EXACT_MODEL).build(robot, None))


@dataclass(frozen=True, eq=False)
class PlanningModel:
    """What a plan knows before it searches; frozen, shared by the searches, validation, repair and the
    writers of one plan.

    Attributes:
        scene: the planning scene (base pose, obstacles, target, start, settings).
        backend: the backend the search evaluates (for a surrogate: with its capsule margins by
            arc-length region, `RegionMarginBackend`).
        exact: the exact backend of validation and repair.
        stability: the stability decision, applied to ``exact`` (and by `build` to ``backend``).
        world: the scene's collision world (FCL objects and broadphase grid), built once.
        margin_mm: capsule margin (mm) of the search (the scene's, plus a surrogate's flat margin).
        margin_source: where the search's margin comes from (`planning_backend`).
        points: backbone points per configuration.
        space: the joint space (box coordinates, planning metric).

    Its one collision checker of exact backbones (`collision_checker`) is built on first use.
    """

    scene: Scene
    backend: Backend
    exact: Backend
    stability: StabilityDecision
    world: CollisionWorld
    margin_mm: float
    points: int
    space: BoxSpace
    margin_source: dict = field(default_factory=dict)
    _checkers: dict[float, RobotCollisionChecker] = field(default_factory=dict, init=False, repr=False)

    @classmethod
    def build(cls, scene: Scene, backend: Backend, exact: Backend | None = None,
              world: CollisionWorld | None = None) -> PlanningModel:
        """The model of a plan: the stability decision made and applied to ``backend`` and ``exact``
        (default: the backend's exact companion, `ctrplan.kinematics.registry.exact_companion`), the
        planning margins, and the scene's collision world (``world`` if already built for these
        obstacles)."""
        decision = StabilityDecision.for_robot(scene.robot)
        exact = exact or exact_companion(backend, scene.robot)
        planning, margin, source = planning_backend(scene, decision.apply(backend))
        world = world or CollisionWorld.from_scene(scene)
        return cls(scene, planning, decision.apply(exact), decision, world,
                   margin, int(scene.settings.points), BoxSpace.for_scene(scene), source)

    @classmethod
    def of(cls, scene: Scene, backend: Backend | None = None, *, exact: Backend | None = None,
           margin_mm: float | None = None, points: int | None = None,
           world: CollisionWorld | None = None) -> PlanningModel:
        """A model that searches with ``backend`` as it is (no margins added; default: the exact
        backend), the stability decision applied to the exact backend (default: the backend's exact
        companion, or the exact model), with ``margin_mm`` and ``points`` (default: the scene's) and a
        prebuilt ``world``: for user code, tests, scene checks and design screens."""
        s = scene.settings
        decision = StabilityDecision.for_robot(scene.robot)
        if exact is None:
            exact = (exact_companion(backend, scene.robot) if backend is not None
                     else backend_kind(EXACT_MODEL).build(scene.robot, None))
        exact = decision.apply(exact)
        return cls(scene, backend or exact, exact, decision, world or CollisionWorld.from_scene(scene),
                   s.margin_mm if margin_mm is None else float(margin_mm),
                   int(points or s.points), BoxSpace.for_scene(scene))

    def collision_checker(self, margin_mm: float | None = None) -> RobotCollisionChecker:
        """The collision checker of the exact backbones of this model's paths (validation, clearance
        measurement), capsules grown by ``margin_mm`` (default: the scene's): one per model and
        margin, built on first use. A search keeps its own (`ConfigurationChecker`: its margin, its
        counters)."""
        margin = self.scene.settings.margin_mm if margin_mm is None else float(margin_mm)
        if margin not in self._checkers:
            self._checkers[margin] = RobotCollisionChecker(self.world, self.scene.base_pose, self.points,
                                                           margin)
        return self._checkers[margin]

    def exact_search(self) -> PlanningModel:
        """This model searching with the exact backend and the scene's margin (repair)."""
        return replace(self, backend=self.exact, margin_mm=self.scene.settings.margin_mm,
                       margin_source={"source": "exact backend"})

    def with_scene(self, scene: Scene) -> PlanningModel:
        """This model on ``scene``: the same robot, obstacles and joint box with another start or
        target (the collision world and space are kept)."""
        return replace(self, scene=scene)


class RegionMarginBackend(Backend):
    """A surrogate whose backbones carry extra radius (mm) by arc-length region: its calibrated
    error bound at ``coverage`` (`ctrplan.kinematics.error_bound`), so that planning keeps
    that much more clearance where the surrogate is less accurate. Positions, tips and all else are
    the wrapped backend's."""

    def __init__(self, inner: Backend, bound: dict, coverage: float):
        super().__init__(inner.robot)
        self.inner = inner
        self.bound = bound
        self.coverage = coverage
        self._margin_cache: dict[bytes, np.ndarray] = {}
        self.name = inner.name
        self.exact = inner.exact
        self.warm_startable = inner.warm_startable
        self.analytic_tip_jacobian = inner.analytic_tip_jacobian
        self.partial_backbones_cheap = inner.partial_backbones_cheap

    def forward(self, q: np.ndarray, points: int | np.ndarray = DEFAULT_POINTS, *,
                guess: np.ndarray | None = None, check: bool = True) -> Backbone:
        bb = self.inner.forward(q, points, guess=guess, check=check)
        return bb.with_radius(bb.radius_mm + self._margins(arc_fractions(points)))

    def body(self, q: np.ndarray, points: int | np.ndarray, *, guess: np.ndarray | None = None,
             check: bool = True) -> Body:
        pos, radius, usable, init = self.inner.body(q, points, guess=guess, check=check)
        return Body(pos, radius + self._margins(arc_fractions(points)), usable, init)

    def body_query(self, points: int | np.ndarray) -> Callable[[np.ndarray], Body]:
        inner = self.inner.body_query(points)
        margins = self._margins(arc_fractions(points))

        def query(q: np.ndarray) -> Body:
            pos, radius, usable, init = inner(q)
            return Body(pos, radius + margins, usable, init)

        return query

    def _margins(self, s_fraction: np.ndarray) -> np.ndarray:
        """`region_margins_mm` at arc fractions (P,) of l1, once per set of fractions (a planner asks
        for the same few again and again)."""
        key = s_fraction.tobytes()
        if key not in self._margin_cache:
            self._margin_cache[key] = region_margins_mm(self.bound, self.coverage, s_fraction)
        return self._margin_cache[key]

    def tip_jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.inner.tip_jacobian(q)

    def tip_and_tangent(self, q: np.ndarray, *, check: bool = True
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.inner.tip_and_tangent(q, check=check)

    def tips(self, q: np.ndarray, *, check: bool = True) -> np.ndarray:
        return self.inner.tips(q, check=check)

    def describe(self) -> dict:
        return {**self.inner.describe(), "coverage": self.coverage}


def planning_backend(scene: Scene, backend: Backend) -> tuple[Backend, float, dict]:
    """The backend and capsule margin (mm) to plan with, and where the margin comes from.

    An exact backend plans with the scene's ``margin_mm``. A surrogate adds the scene's
    ``surrogate_margin_mm`` everywhere if the scene sets one; otherwise the calibrated error bound
    of its model card at the scene's ``surrogate_coverage``, by arc-length region
    (`RegionMarginBackend`); a model without one gets `DEFAULT_SURROGATE_MARGIN_MM`."""
    s = scene.settings
    if backend.exact:
        return backend, s.margin_mm, {"source": "exact backend"}
    if s.surrogate_margin_mm is not None:
        return backend, s.margin_mm + s.surrogate_margin_mm, {
            "source": "scene surrogate_margin_mm", "surrogate_margin_mm": s.surrogate_margin_mm}
    bound = backend.error_bound
    if bound is None:
        return backend, s.margin_mm + DEFAULT_SURROGATE_MARGIN_MM, {
            "source": "default (the model card has no calibrated error bound)",
            "surrogate_margin_mm": DEFAULT_SURROGATE_MARGIN_MM}
    margins = region_bounds_mm(bound, s.surrogate_coverage)
    return RegionMarginBackend(backend, bound, s.surrogate_coverage), s.margin_mm, {
        "source": f"model card {ERROR_BOUND_KEY} at coverage {s.surrogate_coverage:g}",
        "regions": [{"s_fraction": r["s_fraction"], "margin_mm": m}
                    for r, m in zip(bound["regions"], margins, strict=True)]}
