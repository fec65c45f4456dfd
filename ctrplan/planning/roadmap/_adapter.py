"""The roadmap's one point of contact with the single-query planning code.

Everything the roadmap needs from `ctrplan.planning` -- the planning backend with its calibrated
margin and stability check, batched state validity, edge checks at the planner's resolution, inverse
kinematics, exact validation, the exact goal correction -- goes through this module, so that the
roadmap checks states exactly as ``ctrplan plan`` does and follows it when the planning internals
change (re-point the functions here; nothing else in `ctrplan.planning.roadmap` imports them).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from ctrplan.kinematics.base import Backend
from ctrplan.planning.ik import IKResult, backend_tip_jacobian, solve_ik
from ctrplan.planning.model import PlanningModel
from ctrplan.planning.planner import compile_kernels, exact_goal
from ctrplan.planning.search import search
from ctrplan.planning.space import BoxSpace
from ctrplan.planning.validate import ValidatedPath, validate_path
from ctrplan.planning.validity import ConfigurationChecker
from ctrplan.scene.objects import Scene, TargetRegion


@dataclass
class PlanningContext:
    """What checks states for one scene and backend: the planning checker (backend with the
    calibrated margin; stability checked where the robot has no snap-free certificate), the exact
    model, the state space and the tip Jacobian for IK."""

    scene: Scene
    loaded: Backend           # as loaded (what the model fingerprint names)
    backend: Backend          # with the stability check where needed (position error in validation)
    exact: Backend
    checker: ConfigurationChecker
    margin_mm: float
    margin_source: dict
    jacobian: Callable | None = None
    exact_checker: ConfigurationChecker | None = None  # the exact model with the scene's margin

    @property
    def space(self) -> BoxSpace:
        return self.checker.space

    @property
    def resolution_mm(self) -> float:
        return float(self.scene.settings.resolution_mm)


def planning_context(scene: Scene, backend: Backend, compile_now: bool = True) -> PlanningContext:
    """The `PlanningContext` of ``scene`` with ``backend``, as `ctrplan.planning.plan` sets it up: the
    same planning model (margins, stability decision) and the same exact companion
    (`ctrplan.kinematics.registry.exact_companion`); kernels compiled first when ``compile_now``."""
    model = PlanningModel.build(scene, backend)  # stability decided once, margins as in plan
    if compile_now:
        compile_kernels(model)
    checker = ConfigurationChecker(model)
    return PlanningContext(scene, backend, model.stability.apply(backend), model.exact, checker,
                           model.margin_mm, model.margin_source,
                           backend_tip_jacobian(model.backend, model.space),
                           ConfigurationChecker(model.exact_search()))


def check_states(ctx: PlanningContext, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Validity (B,) of joints q (B, 2N) under the planning backend and margin (one batched call, no
    cache) and their tips (B, 3), scene frame, mm (NaN where the backend did not converge)."""
    q = np.atleast_2d(q)
    if not len(q):
        return np.zeros(0, dtype=bool), np.zeros((0, 3))
    valid, body = ctx.checker.validate(q)
    tips = np.full((len(q), 3), np.nan)
    usable = np.asarray(body.usable, dtype=bool)
    tips[usable] = ctx.scene.to_scene(body.positions_mm[usable, -1])  # the first stage ends at the tip
    return valid, tips


def edge_states(ctx: PlanningContext, qa: np.ndarray, qb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Interior states of the straight edges qa[i] -> qb[i] (E, 2N) at the planner's resolution, as
    `ConfigurationChecker.check_motion` checks them: (K, 2N) and the edge of each (K,)."""
    space = ctx.space
    ya, yb = space.to_coords(qa), space.to_coords(qb)
    n = np.maximum(1, np.ceil(np.linalg.norm(yb - ya, axis=1) / ctx.resolution_mm)).astype(int)
    edge = np.repeat(np.arange(len(n)), n - 1)
    start = np.concatenate([[0], np.cumsum(n - 1)[:-1]]) if len(n) else np.zeros(0, dtype=int)
    k = np.arange(len(edge)) - np.repeat(start, n - 1) + 1
    t = (k / n[edge])[:, None]
    return space.to_joints(ya[edge] + t * (yb[edge] - ya[edge])), edge


def check_edges(ctx: PlanningContext, qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
    """Validity (E,) of the straight edges qa[i] -> qb[i] whose end states are valid: every interior
    state at the planner's resolution valid (all edges' states in one batched call)."""
    qa, qb = np.atleast_2d(qa), np.atleast_2d(qb)
    ok = np.ones(len(qa), dtype=bool)
    states, edge = edge_states(ctx, qa, qb)
    if len(states):
        valid, _ = check_states(ctx, states)
        bad = np.unique(edge[~valid])
        ok[bad] = False
    return ok


def exact_end_check(ctx: PlanningContext, target: TargetRegion, path_q: np.ndarray) -> tuple[bool, bool]:
    """A quick look at the end of a path with the exact model (the scene's margin): whether its
    waypoints and the states between them at the planner's resolution are all valid (one batched
    call), and whether the exact tip of its last state lies in ``target``. A filter before the full
    validation (`validate`), which also refines where the backbone moves fast."""
    states = np.vstack([path_q, edge_states(ctx, path_q[:-1], path_q[1:])[0]])
    valid, body = ctx.exact_checker.validate(states)
    tip = ctx.scene.to_scene(body.positions_mm[len(path_q) - 1, -1])
    return bool(valid.all()), bool(np.isfinite(tip).all() and target.contains(tip))


def inverse_kinematics(ctx: PlanningContext, seeds: np.ndarray, targets_scene: np.ndarray, tol_mm: float,
                       max_iterations: int) -> IKResult:
    """Damped-least-squares IK of the planning backend from ``seeds`` (B, 2N) towards tip targets
    (B, 3) in the scene frame (mm), as goal sampling runs it."""
    return solve_ik(ctx.jacobian, ctx.space, seeds, ctx.scene.to_robot(targets_scene), tol_mm=tol_mm,
                    max_iterations=max_iterations, rotation_weight=8.0)


def tip_directions(ctx: PlanningContext, q: np.ndarray) -> np.ndarray:
    """Unit tip tangents (B, 3), scene frame, of the planning backend."""
    _, tangent, _ = ctx.checker.backend.tip_and_tangent(np.atleast_2d(q), check=False)
    return ctx.scene.direction_to_scene(tangent)


def validate(ctx: PlanningContext, scene: Scene, path_q: np.ndarray) -> ValidatedPath:
    """Exact re-validation of ``path_q`` in ``scene`` (the context's scene with the query's target),
    as ``plan`` does it: every state at the planner's resolution, refined where the backbone moves
    more than a capsule radius, solved by the exact model and checked for collision with the scene's
    margin, convergence and stability, the last tip for the target; the clearance is computed at the
    first and last state. The planning backend's error against the exact model is left to
    `add_model_error`."""
    return validate_path(scene, path_q, None, exact=ctx.exact, world=ctx.checker.world,
                         clearance_stride=CLEARANCE_STRIDE)


def add_model_error(ctx: PlanningContext, vp: ValidatedPath) -> None:
    """Fill in the validation report's ``max_position_error_mm`` and ``max_tip_error_mm``: the largest
    distance between the planning backend's and the exact backbones (points, tips) along the
    validated states (inf where the backend gives none)."""
    pbb = ctx.backend.forward(vp.dense_q, points=vp.exact.positions_mm.shape[1], check=False)
    vp.planned = pbb
    err = np.linalg.norm(pbb.positions_mm - vp.exact.positions_mm, axis=-1)
    tip = np.linalg.norm(pbb.tip_mm - vp.exact.tip_mm, axis=-1)
    vp.report.max_position_error_mm = float(np.max(err)) if np.isfinite(err).all() else float("inf")
    vp.report.max_tip_error_mm = float(np.max(tip)) if np.isfinite(tip).all() else float("inf")


#: `validate_path`'s clearance stride: distances (1-2 ms each) at the first and last state only.
CLEARANCE_STRIDE = 10**9


def exact_goal_state(ctx: PlanningContext, scene: Scene, path_q: np.ndarray) -> np.ndarray:
    """The path with a last state whose exact tip lies where the planning backend put its tip in
    ``scene``'s target (see `ctrplan.planning.planner.exact_goal`), or unchanged."""
    return exact_goal(path_q, ConfigurationChecker(ctx.checker.model.with_scene(scene)))


def single_query_path(ctx: PlanningContext, region: TargetRegion, seed: int, max_states: int
                      ) -> np.ndarray | None:
    """A path (K, 2N) from the start into ``region`` by the single-query planner (RRTConnect, work
    budget ``max_states``, simplified), checked like every planner edge; None if none was found.
    OMPL's own messages are silenced (a worker's stderr is the build's progress display)."""
    from ompl import util as ou

    ou.setLogLevel(ou.LOG_NONE)
    checker = ConfigurationChecker(ctx.checker.model.with_scene(replace(ctx.scene, target=region)))
    outcome = search(checker, planner="rrtconnect", time_limit_s=max(1.0, max_states / 20_000),
                     max_states=max_states, seed=seed)
    return outcome.path_q


def densify(ctx: PlanningContext, path_q: np.ndarray, step_mm: float) -> np.ndarray:
    """The path with states added so consecutive ones are at most ``step_mm`` apart (planning metric)."""
    return ctx.space.densify(path_q, step_mm)


def with_world(ctx: PlanningContext, scene: Scene, world) -> PlanningContext:
    """``ctx`` on ``scene`` -- the same robot, start and joint box with obstacles that moved -- whose
    collision world is ``world`` (`ctrplan.collision.world.CollisionWorld.moved`): planning and exact
    checkers made again, backends, margins and kernels kept."""
    model = replace(ctx.checker.model, scene=scene, world=world)
    return replace(ctx, scene=scene, checker=ConfigurationChecker(model),
                   exact_checker=ConfigurationChecker(model.exact_search()))


def checker_with_world(ctx: PlanningContext, world) -> ConfigurationChecker:
    """A planning checker of ``ctx`` (backend and margins) against ``world`` alone (e.g. one structure
    that moved)."""
    return ConfigurationChecker(replace(ctx.checker.model, world=world))
