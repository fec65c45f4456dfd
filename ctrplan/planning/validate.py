"""Safety net: re-validate a planned path with the exact Cosserat model, and repair it if needed.

Whatever backend planned the path, `validate_path` densifies it at the planner's resolution, solves
every state with the exact model, adds states wherever a backbone point would move further than the
thinnest capsule's radius between two checked states (so an obstacle thinner than the resolution
cannot slip between them), and reports the position error between the planning backend and the
exact model along the whole backbone, whether the exact robot is collision-free (same capsules and
margin as in planning), its clearance, and whether its tip ends in the target. `repair_path` keeps the
exact-valid prefix of a path that fails and re-plans the rest with the exact model; a path that still
fails is never reported as solved.

The report is typed and complete, so that outputs only render it: the failing state and why
(`FailingState`), and, measured once on request (`measure_clearance`), the clearance along the path
per capsule and state and to every named structure (`PathClearance`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, fields, replace

import numpy as np

from ctrplan.collision.checker import RobotCollisionChecker, StructureClearance
from ctrplan.collision.world import CollisionWorld
from ctrplan.kinematics.backbone import Backbone
from ctrplan.kinematics.base import Backend
from ctrplan.kinematics.registry import EXACT_MODEL
from ctrplan.planning.goal import tip_tangents
from ctrplan.planning.model import PlanningModel
from ctrplan.planning.space import BoxSpace, split_segments
from ctrplan.scene.objects import Scene

#: Clearances along a path are measured up to this (mm; `measure_clearance`): larger ones are
#: reported as this.
CLEARANCE_CAP_MM = 50.0


@dataclass(frozen=True)
class FailingState:
    """The first checked state of a path that fails exact validation, and why: the exact model did
    not converge there, or the robot touches ``obstacles`` (with the margins), or its equilibrium is
    unstable (it would snap)."""

    state: int
    obstacles: tuple[str, ...]
    converged: bool = True
    stable: bool = True

    @property
    def labels(self) -> list[str]:
        """The obstacles it touches, with the reasons that are not a contact in parentheses (the
        ``obstacles`` of the JSON document)."""
        if not self.converged:
            return ["(exact model did not converge)"]
        return [*self.obstacles, *([] if self.stable else ["(unstable equilibrium: the robot snaps)"])]

    @property
    def why(self) -> str:
        """Why the state fails, in words."""
        reasons = [] if self.converged else ["the exact model did not converge"]
        if self.obstacles:
            reasons.append(f"the robot touches {', '.join(self.obstacles)}")
        if self.converged and not self.stable:
            reasons.append("its equilibrium is unstable (the robot would snap)")
        return "; ".join(reasons)

    def to_json(self) -> dict:
        return {"state": self.state, "obstacles": self.labels}


@dataclass
class Validation:
    """Exact-model check of a path. Lengths in mm, scene frame.

    ``min_clearance_mm`` is the smallest distance between the exact robot's surface (no margin) and
    any obstacle over the checked states (0 on contact); ``max_position_error_mm`` the largest
    distance between corresponding backbone points of the planning backend and the exact model;
    ``max_step_mm`` the largest displacement of any exact backbone point between two consecutive
    checked states, ``step_bound_mm`` the bound it was refined to (the thinnest capsule radius);
    ``tip_angle_deg`` the angle between the final tip tangent and the target's approach direction
    (0 without one), which ``tip_in_target`` requires within the target's tolerance;
    ``first_collision`` the first failing state and why; ``structures`` the clearance to every named
    structure along the path (`StructureClearance`, None until measured: `measure_clearance`).
    """

    backend: str = EXACT_MODEL
    collision_free: bool = False
    min_clearance_mm: float = 0.0
    max_position_error_mm: float = 0.0
    max_tip_error_mm: float = 0.0
    tip_in_target: bool = False
    tip_angle_deg: float = 0.0
    converged: bool = False
    stable: bool = True
    states: int = 0
    colliding_states: list[int] = field(default_factory=list)
    first_collision: FailingState | None = None
    nearest_obstacle: str = ""
    tip_mm: list[float] = field(default_factory=list)
    repaired: bool = False
    max_step_mm: float = 0.0
    step_bound_mm: float = 0.0
    time_s: float = 0.0
    structures: tuple[StructureClearance, ...] | None = None

    @property
    def ok(self) -> bool:
        return self.collision_free and self.tip_in_target and self.converged and self.stable

    def to_json(self) -> dict:
        d = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "structures"}
        d["colliding_states"] = len(self.colliding_states)
        d["first_collision"] = None if self.first_collision is None else self.first_collision.to_json()
        d["tip_mm"] = list(self.tip_mm)
        for k in ("min_clearance_mm", "max_position_error_mm", "max_tip_error_mm", "max_step_mm"):
            d[k] = _finite(d[k])
        if self.structures is not None:
            d["structures"] = [c.to_json() for c in self.structures]
        return d


def _finite(x: float):
    return float(x) if np.isfinite(x) else None


@dataclass
class ValidatedPath:
    """A dense path (K, 2N) with its exact and planning-backend backbones and the report;
    ``clearance_mm`` (K, P-1): the clearance of every capsule of every exact backbone (mm, surface to
    the nearest obstacle, 0 in contact, at most `CLEARANCE_CAP_MM`, NaN where the exact model did not
    converge), None until measured (`measure_clearance`)."""

    dense_q: np.ndarray
    exact: Backbone
    planned: Backbone | None
    report: Validation
    clearance_mm: np.ndarray | None = None


def validate_path(scene: Scene, path_q: np.ndarray, planning_backend: Backend | None = None, *,
                  exact: Backend | None = None, resolution: float | None = None,
                  points: int | None = None, margin_mm: float | None = None,
                  world: CollisionWorld | None = None, clearance_stride: int = 1,
                  measure: bool = False) -> ValidatedPath:
    """`validate_planned_path` on the planning model of ``scene`` with ``planning_backend`` (if given and not
    exact itself: evaluated on the same states for the position error), ``exact`` (default: the
    planning backend's exact companion, or the exact model; testing stability unless the robot is
    certified), ``points`` and a prebuilt ``world`` (`PlanningModel.of`)."""
    model = PlanningModel.of(scene, planning_backend, exact=exact, points=points, world=world)
    return validate_planned_path(model, path_q, resolution=resolution, margin_mm=margin_mm,
                                 clearance_stride=clearance_stride, measure=measure)


def validate_planned_path(model: PlanningModel, path_q: np.ndarray, *, resolution: float | None = None,
                          margin_mm: float | None = None, clearance_stride: int = 1,
                          measure: bool = False) -> ValidatedPath:
    """Re-validate ``path_q`` (K, 2N) with the model's exact backend at ``resolution`` (planning
    metric, mm; default: the scene's) and capsule margin ``margin_mm`` (default: the scene's, not the
    search's).

    The model's planning backend, unless it is the exact one, is evaluated on the same states for
    the position error. Collisions and clearance are found in one pass over the states; with
    ``clearance_stride`` k > 1 the clearance (an FCL distance, 1-2 ms) is measured only at every k-th
    and the last state, the others get the boolean collision check (one batched call). The exact
    backend computes elastic stability unless the robot is certified (`StabilityDecision`): an
    unstable state fails like a colliding one. On a certified robot the exact states are solved by
    continuation along the path (`Backend.forward_path`); on any other each starts cold
    (`StabilityDecision.continuation`). With ``measure``, the clearances of `measure_clearance` too.
    """
    t0 = time.perf_counter()
    scene = model.scene
    s = scene.settings
    resolution = float(resolution or s.resolution_mm)
    margin = s.margin_mm if margin_mm is None else float(margin_mm)
    exact = model.exact
    dense = model.space.densify(path_q, resolution)
    planned = model.backend is not exact
    warm = model.stability.continuation
    solve = exact.forward_path if warm else exact.forward
    ebb = solve(dense, points=model.points, check=False)
    bound = float(np.min(ebb.radius_mm)) + margin
    dense, ebb = refine_steps(model.space, exact, dense, ebb, bound, warm=warm)
    pbb = model.backend.forward(dense, points=model.points, check=False) if planned else None
    report = Validation(backend=exact.name, states=len(dense), step_bound_mm=bound,
                        max_step_mm=float(np.max(backbone_steps(ebb), initial=0.0)))
    report.converged = bool(ebb.converged.all())
    report.stable = bool(ebb.stable.all())
    if pbb is not None:
        _position_errors(report, pbb, ebb)
    _collisions_and_clearance(report, model.collision_checker(margin), ebb, clearance_stride)
    tip = scene.to_scene(ebb.tip_mm[-1])
    report.tip_mm = tip.tolist()
    angle = float(scene.target.angle_rad(tip_tangents(scene, ebb)[-1]))
    report.tip_angle_deg = float(np.degrees(angle))
    report.tip_in_target = bool(ebb.converged[-1] and scene.target.contains(tip)
                                and angle <= scene.target.angle_tolerance_rad + 1e-12)
    report.time_s = time.perf_counter() - t0
    validated = ValidatedPath(dense, ebb, pbb, report)
    return measure_clearance(model, validated) if measure else validated


def measure_clearance(model: PlanningModel, validated: ValidatedPath) -> ValidatedPath:
    """``validated`` with its clearances measured (`PathClearance` of the outputs): every capsule of
    every exact backbone against the nearest obstacle (``clearance_mm``, capped at `CLEARANCE_CAP_MM`),
    and every named structure's nearest approach along the path with where it happens
    (``report.structures``, against the scene's margin plus the structure's own). FCL distances, 1-2
    ms each: what a plan's outputs show, measured once, by the model's collision checker."""
    checker = model.collision_checker()
    ebb = validated.exact
    along = np.array([checker.clearances(p, r, CLEARANCE_CAP_MM)
                      for p, r in zip(ebb.positions_mm, ebb.radius_mm, strict=True)])
    structures = tuple(checker.structure_clearances(ebb.positions_mm, ebb.radius_mm, ebb.s_mm))
    return replace(validated, report=replace(validated.report, structures=structures), clearance_mm=along)


def _initial_states(bb: Backbone) -> np.ndarray:
    """Initial states (B, 2N + 9) of the exact backbones ``bb``, zero where a row did not converge:
    the two neighbours' of a refining state, interpolated, start its solve (`refine_steps`)."""
    return np.where(np.isfinite(bb.initial_state), bb.initial_state, 0.0)


def _position_errors(report: Validation, pbb: Backbone, ebb: Backbone) -> None:
    """The largest backbone point and tip distances (mm) between the planning backend and the exact
    model (inf where either did not converge)."""
    err = np.linalg.norm(pbb.positions_mm - ebb.positions_mm, axis=-1)
    tip_err = np.linalg.norm(pbb.tip_mm - ebb.tip_mm, axis=-1)
    report.max_position_error_mm = float(np.nanmax(err)) if np.isfinite(err).any() else np.inf
    report.max_tip_error_mm = float(np.nanmax(tip_err)) if np.isfinite(tip_err).any() else np.inf
    if not np.all(np.isfinite(err)):
        report.max_position_error_mm = np.inf


def _collisions_and_clearance(report: Validation, checker: RobotCollisionChecker, ebb: Backbone,
                              stride: int = 1) -> None:
    """One pass over the exact backbones: the clearance of every state (mm, surface to the nearest
    obstacle, 0 on contact), which decides its collision too -- a capsule grown by the margin touches
    an obstacle exactly when the capsule's clearance is at most the margin; where a structure's own
    margin could decide, the margin-aware boolean check does -- the failing states
    (colliding, not converged or unstable), the first one's obstacles, and the smallest clearance
    with its obstacle (over the states measured: every ``stride``-th and the last)."""
    bad: list[int] = []
    best, nearest = np.inf, ""
    own = max(checker.world.margins, default=0.0)  # the largest structure's own margin (mm)
    last = len(ebb.positions_mm) - 1
    measured = (np.arange(last + 1) % stride == 0) | (np.arange(last + 1) == last)
    free_rows = np.ones(last + 1, dtype=bool)
    if not measured.all():  # the others: the boolean check decides, in one batched call
        free_rows[~measured] = checker.free_batch(ebb.positions_mm[~measured], ebb.radius_mm[~measured])
    for i in range(last + 1):
        if not measured[i]:
            if not (ebb.stable[i] and free_rows[i]):
                bad.append(i)
            continue
        c = checker.clearance(ebb.positions_mm[i], ebb.radius_mm[i])
        free = c.distance_mm > checker.margin_mm
        if free and c.distance_mm <= checker.margin_mm + own:  # a structure's own margin may decide
            free = checker.is_free(ebb.positions_mm[i], ebb.radius_mm[i])
        if not (ebb.stable[i] and free):
            bad.append(i)  # unstable states fail too: the robot would snap there
        if c.distance_mm < best:
            best, nearest = c.distance_mm, c.obstacle
    report.colliding_states = bad
    report.collision_free = not bad and report.converged
    if bad:
        i = bad[0]
        converged = bool(ebb.converged[i])
        names = sorted({n for _, n in checker.contacts(ebb.positions_mm[i], ebb.radius_mm[i])}) \
            if converged else []
        report.first_collision = FailingState(i, tuple(names), converged, bool(ebb.stable[i]))
    report.min_clearance_mm = float(best) if np.isfinite(best) else float("inf")
    report.nearest_obstacle = nearest


def backbone_steps(bb: Backbone) -> np.ndarray:
    """Largest displacement (mm) of any backbone point between consecutive rows (B-1,); inf where
    a row did not converge."""
    d = np.linalg.norm(np.diff(bb.positions_mm, axis=0), axis=-1).max(axis=1, initial=0.0)
    return np.where(np.isfinite(d), d, np.inf)


def _stack(parts: list[Backbone], order: np.ndarray) -> Backbone:
    """Rows of several backbone batches (same points), concatenated and then taken in ``order``."""
    kw = {}
    for f in fields(Backbone):
        vals = [getattr(b, f.name) for b in parts]
        kw[f.name] = vals[0] if vals[0] is None or isinstance(vals[0], str) else np.concatenate(vals)[order]
    return Backbone(**kw)


def refine_steps(space: BoxSpace, exact: Backend, dense: np.ndarray, bb: Backbone, bound_mm: float,
                 max_split: int = 64, rounds: int = 4, warm: bool = False) -> tuple[np.ndarray, Backbone]:
    """Insert states between consecutive rows of ``dense`` (K, 2N) until no backbone point moves more
    than ``bound_mm`` between two of them.

    A point moving by at most d passes within d / 2 of one of its two checked positions, so with d
    no larger than the capsule radius an obstacle of any thickness that the robot sweeps through
    touches a checked capsule (twice the needed safety, for curved motion). Segments whose ends did
    not converge are left alone (they already fail); at most ``max_split`` pieces per segment and
    round. Returns the refined joints and their exact backbones (one batched call per round; with
    ``warm`` (`StabilityDecision.continuation`) each new state starts from its neighbours' solutions,
    interpolated)."""
    points = bb.s_mm.shape[1]
    for _ in range(rounds):
        step = backbone_steps(bb)
        pieces = np.where(np.isfinite(step), np.ceil(step / bound_mm), 1).astype(int)
        pieces = np.clip(pieces, 1, max_split)
        if pieces.max(initial=1) <= 1:
            break
        left, t = split_segments(pieces)
        extra_q = space.along(dense, left, t)
        guess = None
        if warm:   # between the neighbours' solutions, as the new state lies between their joints
            init, w = _initial_states(bb), t[:, None]
            guess = (1.0 - w) * init[left] + w * init[left + 1]
        solved = exact.forward(extra_q, points=points, check=False, guess=guess)
        order = np.argsort(np.concatenate([np.arange(len(dense), dtype=float), left + t]), kind="stable")
        dense = np.concatenate([dense, extra_q])[order]
        bb = _stack([bb, solved], order)
    return dense, bb


Replanner = Callable[[np.ndarray, "np.ndarray | None"], "np.ndarray | None"]


def repair_path(validated: ValidatedPath, replan: Replanner, pad: int = 2) -> np.ndarray | None:
    """Re-plan the stretches of a path that fail exact validation.

    Every run of failing dense states is replaced by a path between exact-valid states ``pad``
    states before and after it (``replan(start_q, goal_q)``, which keeps its own budget); a run that
    reaches the end -- or an end whose exact tip misses the target -- is re-planned to the target
    region (``goal_q=None``). Returns the repaired dense path, or None if a stretch cannot be re-planned.
    """
    rep = validated.report
    dense = validated.dense_q
    n = len(dense)
    bad = sorted(set(rep.colliding_states))
    runs: list[list[int]] = []
    for i in bad:
        if runs and i - runs[-1][1] <= 2 * pad + 1:
            runs[-1][1] = i
        else:
            runs.append([i, i])
    badset = set(bad)
    pieces = []
    cur = 0
    to_region_from = None
    for a, b in runs:
        pre = max(a - 1 - pad, cur)
        while pre > cur and pre in badset:
            pre -= 1
        if b >= n - 1 - pad:
            to_region_from = pre
            break
        post = min(b + 1 + pad, n - 1)
        while post < n - 1 and post in badset:
            post += 1
        seg = replan(dense[pre], dense[post])
        if seg is None:
            return None
        pieces += [dense[cur:pre + 1], np.atleast_2d(seg)[1:-1]]
        cur = post
    if to_region_from is None and not rep.tip_in_target:
        to_region_from = n - 1
    if to_region_from is not None:
        pieces.append(dense[cur:to_region_from + 1])
        seg = replan(dense[to_region_from], None)
        if seg is None:
            return None
        pieces.append(np.atleast_2d(seg)[1:])
    else:
        pieces.append(dense[cur:])
    return np.concatenate([p for p in pieces if len(p)])
