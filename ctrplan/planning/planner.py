"""Planning pipeline: scene + backend -> planning model -> OMPL problem -> path -> exact validation
(-> repair).

`plan` builds one frozen `PlanningModel` (`ctrplan.planning.model`) and hands it to every step; each
search keeps its caches and counters in a `ConfigurationChecker`. Wiring follows OMPL's
``demos/OptimalPlanning.py``: a `BoxSpace` state space, a `ValidityChecker`, a
`BatchMotionValidator`, a `TipGoal` (IK-sampled goal region), a planner from the table of
`ctrplan.planning.planners`, a solve budgeted in work (`ctrplan.planning.budget`), path
simplification; then `validate_planned_path` with the model's exact backend. All OMPL objects
live inside function scope (docs/design.md §4: module-level OMPL
objects leak at exit).
"""

from __future__ import annotations

import gc
import math
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from ompl import base as ob
from ompl import util as ou

from ctrplan.base.errors import InputError
from ctrplan.base.machine import numba_threads_at_most
from ctrplan.collision.world import CollisionWorld
from ctrplan.kinematics import make_backend
from ctrplan.kinematics.backbone import Backbone
from ctrplan.kinematics.base import Backend
from ctrplan.kinematics.blas import single_threaded_blas
from ctrplan.kinematics.pinn import ROW_BLOCKS
from ctrplan.planning.budget import (
    GUARD_FACTOR,
    PlanClock,
    SearchBudget,
    check_max_states,
    clock_message,
    clock_record,
    states_for,
)
from ctrplan.planning.goal import ANGLE_WEIGHT_MM_PER_RAD, GoalSampler, TipGoal, tip_tangents
from ctrplan.planning.ik import backend_tip_jacobian, compile_ik, solve_ik
from ctrplan.planning.model import PlanningModel
from ctrplan.planning.planners import PlannerSpec, scene_planner
from ctrplan.planning.scene_check import check_scene
from ctrplan.planning.shortcut import shortcut_path
from ctrplan.planning.validate import ValidatedPath, Validation, repair_path, validate_planned_path
from ctrplan.planning.validity import BatchMotionValidator, ConfigurationChecker, ValidityChecker
from ctrplan.scene.objects import Scene

#: Share of a search's work budget between two goal-sampling batches once goals are known.
REFILL_SHARE = 0.05
#: How close (mm) `exact_goal` brings the exact tip to the surrogate's.
EXACT_GOAL_TOL_MM = 0.05

Progress = Callable[..., None]


def _quiet(*_args: Any, **_kw: Any) -> None:
    return None


def resolve_backend(name: str | Backend | None, robot) -> Backend:
    """A backend instance: given, or by name (default ``pinn``). One that cannot be built raises
    (`InputError` naming why): never a silent fallback to another backend."""
    if isinstance(name, Backend):
        return name
    return make_backend(name or "pinn", robot)


def seed_ompl(seed: int | None) -> None:
    """Seed OMPL's random number generators for the planners and samplers created from now on.

    OMPL hands every new ``RNG`` a seed drawn from one process-wide seed generator. Re-seeding that
    generator after the first draw works (the same seed gives the same runs again, in any process)
    but makes OMPL print an error meant for code that re-seeds mid-run; it is silenced here.
    """
    if seed is None:
        return
    level = ou.getLogLevel()
    ou.setLogLevel(ou.LOG_NONE)
    try:
        ou.RNG.setSeed(int(seed) + 1)  # OMPL refuses 0
    finally:
        ou.setLogLevel(level)


@dataclass
class SearchOutcome:
    """Raw result of one OMPL search."""

    path_q: np.ndarray | None
    status: str
    exact: bool
    time_s: float
    goal_stats: dict
    message: str = ""
    goals: list[np.ndarray] = field(default_factory=list)  # goal configurations the search found
    budget: dict = field(default_factory=dict)  # `SearchBudget.to_json`: work used, guard, cut short


@dataclass
class PlanningProblem:
    """The OMPL objects of one planning problem, for use with any planner from user code.

    Build with `build_problem`; then e.g. ``planner = og.PRMstar(problem.si)`` (single goal state
    planners only with PRM: see docs/design.md §4), ``planner.setProblemDefinition(problem.pdef)``,
    ``planner.solve(5.0)`` and `PlanningProblem.solution` for the joint path.
    """

    scene: Scene
    checker: ConfigurationChecker
    space: Any
    si: Any
    pdef: Any
    goal: Any
    sampler: GoalSampler
    validity: ValidityChecker
    motion_validator: BatchMotionValidator
    start: np.ndarray | None = None  # joints (2N,) mm, rad
    box: Any = field(init=False)

    def __post_init__(self) -> None:
        self.box = self.checker.space

    def solution(self) -> np.ndarray | None:
        """The current solution path as joints (K, 2N), or None."""
        if not self.pdef.hasSolution():
            return None
        path = self.pdef.getSolutionPath()
        return np.stack([self.box.state_to_q(path.getState(i)) for i in range(path.getStateCount())])


def build_problem(scene: Scene, backend: Backend, *, start: np.ndarray | None = None,
                  rng: np.random.Generator | None = None, goal_q: np.ndarray | None = None,
                  goal_hints: np.ndarray | None = None) -> PlanningProblem:
    """The OMPL objects of planning on ``scene`` with ``backend`` as it is (`PlanningModel.of`): see
    `problem_for`."""
    return problem_for(ConfigurationChecker(PlanningModel.of(scene, backend)), start=start, rng=rng,
                       goal_q=goal_q, goal_hints=goal_hints)


def problem_for(checker: ConfigurationChecker, *, start: np.ndarray | None = None,
                rng: np.random.Generator | None = None, goal_q: np.ndarray | None = None,
                goal_hints: np.ndarray | None = None) -> PlanningProblem:
    """State space, validity checker, motion validator, start and goal wired into OMPL objects, checking
    with ``checker`` (a search's data of a planning model).

    The goal is the scene's target region (a `TipGoal` sampled by IK, its first batches from
    ``goal_hints`` if given), or the single configuration ``goal_q`` (an ``ob.GoalState``, e.g. to
    reconnect two states of a path)."""
    scene = checker.scene
    box = checker.space
    start = scene.start if start is None else start
    space = box.make_ompl_space()
    si = ob.SpaceInformation(space)
    validity = ValidityChecker(si, checker)
    si.setStateValidityChecker(validity)
    mv = BatchMotionValidator(si, checker)
    si.setMotionValidator(mv)
    si.setup()
    pdef = ob.ProblemDefinition(si)
    st = si.allocState()
    box.set_state(st, start)
    pdef.addStartState(st)
    sampler = GoalSampler(checker, scene.target, rng or np.random.default_rng(),
                          seeds_per_batch=max(4, 3 * scene.settings.goal_samples), start=start,
                          hints=goal_hints)
    if goal_q is None:
        goal = TipGoal(si, sampler)
    else:
        goal = ob.GoalState(si)
        gs = si.allocState()
        box.set_state(gs, goal_q)
        goal.setState(gs)
        goal.setThreshold(1e-6)
    pdef.setGoal(goal)
    return PlanningProblem(scene, checker, space, si, pdef, goal, sampler, validity, mv,
                           np.asarray(start, dtype=float))


def _path_q(problem: PlanningProblem, path) -> np.ndarray:
    return np.stack([problem.box.state_to_q(path.getState(i)) for i in range(path.getStateCount())])


def _progress_hook(problem: PlanningProblem, budget: SearchBudget, progress: Progress) -> Callable[[], None]:
    """A checker hook that reports the search's progress at most every 0.1 s."""
    last = [0.0]
    counters = problem.checker.counters

    def hook() -> None:
        now = time.perf_counter()
        if now - last[0] > 0.1:
            last[0] = now
            progress("search", elapsed=budget.elapsed(), states=budget.used(), max_states=budget.max_states,
                     kinematics_calls=counters.kinematics_calls, goals=len(problem.sampler.goals))

    return hook


@contextmanager
def gc_paused() -> Iterator[None]:
    """Python's cyclic garbage collector off inside: a search creates hundreds of thousands of small
    acyclic objects (cache entries, arrays), and every full collection would rescan the whole state
    cache."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


@contextmanager
def _hooked(checker: ConfigurationChecker, hook: Callable[[], None]) -> Iterator[None]:
    """``checker`` calls ``hook`` after every kinematics call inside (progress reports)."""
    checker.hook = hook
    try:
        yield
    finally:
        checker.hook = None


def _sample_goals(goal: TipGoal, budget: SearchBudget) -> None:
    """Goal configurations first: they tell early whether the target is reachable at all."""
    sampler = goal.sampler
    for _ in range(6):
        if sampler.goals or budget.exhausted():
            break
        goal.sample_batch()
        if sampler.stats.batches >= 2 and sampler.stats.ik_reached == 0 and not sampler.goals:
            break


def _fix_goal_set(problem: PlanningProblem, budget: SearchBudget) -> None:
    """For planners that drain every goal sample when they (re)start a batch and restart on new
    goals (BIT*): a fixed set of goal configurations, sampled now with at most half the budget."""
    sampler = problem.sampler
    while (len(sampler.goals) < 8 and budget.share_used() < 0.5 and not budget.exhausted()
           and sampler.stats.batches < 12):
        problem.goal.sample_batch()
    problem.goal.max_batches = sampler.stats.batches


def _setup_planner(spec: PlannerSpec, problem: PlanningProblem, range_mm: float | None) -> Any:
    """The OMPL planner of ``spec`` on ``problem``: its range, and a path-length objective if it
    optimises."""
    pl = spec.make(problem.si, range_mm, problem)
    if spec.optimizing:
        problem.pdef.setOptimizationObjective(ob.PathLengthOptimizationObjective(problem.si))
    pl.setProblemDefinition(problem.pdef)
    pl.setup()
    return pl


def _simplified_path(problem: PlanningProblem, simplify: bool, timings: dict,
                     stop: Callable[[], bool] | None = None) -> np.ndarray:
    """The solution as joints (K, 2N), continuous (`BoxSpace.unwrap`), shortcut first if ``simplify``
    (`shortcut_path`: batched, lazy checks at the motion validator's resolution, until ``stop()``)."""
    box, checker = problem.box, problem.checker
    path_q = box.unwrap(_path_q(problem, problem.pdef.getSolutionPath()))
    if not simplify:
        return path_q
    t_simp = time.perf_counter()
    cut = shortcut_path(box.to_coords(path_q), lambda y: checker.validate(box.to_joints(y))[0],
                        problem.motion_validator.resolution, box.difference, stop)
    timings["simplify_s"] = time.perf_counter() - t_simp
    if cut.stopped:
        timings["simplify_stopped"] = True
    timings["simplify_states"] = cut.states
    return path_q[cut.vertices]


def _failure_message(problem: PlanningProblem, budget: SearchBudget, to_configuration: bool) -> str:
    sampler = problem.sampler
    within = f"within {budget.describe()}"
    if to_configuration:
        return f"no path to the given configuration {within}"
    if not sampler.goals:
        st = sampler.stats
        turned = f", {st.wrong_direction} of them not along the approach direction" \
            if st.wrong_direction else ""
        return (f"no collision-free goal configuration found ({st.ik_reached} IK solutions reached "
                f"the target{turned}, all {problem.checker.model.stability.invalid}; {budget.describe()})")
    return f"no path found {within} ({len(sampler.goals)} goal configurations)"


def search(checker: ConfigurationChecker, *, start: np.ndarray | None = None, planner: str | None = None,
           time_limit_s: float | None = None, max_states: int | None = None, seed: int | None = None,
           progress: Progress = _quiet, simplify: bool | None = None, goal_q: np.ndarray | None = None,
           goal_hints: np.ndarray | None = None, wall_s: float | None = None) -> SearchOutcome:
    """One OMPL search from ``start`` (default: the scene's) to the target region (or to the
    configuration ``goal_q``) with the planning model of ``checker``, whose counters and cache it
    extends; ``goal_hints`` (K, 2N): where goal sampling starts (see `GoalSampler`).

    Budget (`ctrplan.planning.budget`): ``max_states`` states evaluated (goal sampling included;
    default: the scene's ``max_states``, else what ``time_limit_s`` buys with this backend on the
    reference machine), under a
    wall-clock guard of `GUARD_FACTOR` x ``time_limit_s`` (default: the scene's), or, with ``wall_s``,
    the time limit of a plan: stopped after ``wall_s`` seconds. The outcome's ``budget`` says how much
    was used and whether the clock cut the search short.

    Steps: build the problem, sample goal configurations, set up the planner, solve, simplify."""
    model = checker.model
    s = model.scene.settings
    planner, spec = scene_planner(model.scene, planner)
    simplify = s.simplify if simplify is None else simplify
    limit_s = time_limit_s if time_limit_s is not None else s.time_limit_s
    seed_ompl(seed)
    problem = problem_for(checker, start=start, rng=np.random.default_rng(seed), goal_q=goal_q,
                          goal_hints=goal_hints)
    sampler = problem.sampler
    budget = SearchBudget.start(max_states or s.max_states or states_for(model.backend.name, limit_s),
                                GUARD_FACTOR * limit_s if wall_s is None else wall_s,
                                lambda: checker.counters.kinematics_calls, time_limit=wall_s is not None)
    with single_threaded_blas(), numba_threads_at_most(ROW_BLOCKS), gc_paused(), \
            _hooked(checker, _progress_hook(problem, budget, progress)):
        region_goal = isinstance(problem.goal, TipGoal)
        if region_goal:
            problem.goal.budget = budget
            problem.goal.refill_states = max(1, round(REFILL_SHARE * budget.max_states))
            progress("goal", elapsed=0.0, states=0, max_states=budget.max_states)
            _sample_goals(problem.goal, budget)
        timings = {"goal_sampling_s": budget.elapsed()}

        def outcome(path_q: np.ndarray | None, status: str, exact: bool, message: str) -> SearchOutcome:
            return SearchOutcome(path_q, status, exact, budget.elapsed(),
                                 {**vars(sampler.stats), **timings}, message, list(sampler.goals),
                                 budget.to_json())

        if region_goal and not sampler.goals and sampler.stats.ik_reached == 0 and not budget.exhausted():
            return outcome(None, "INVALID_GOAL", False,
                           f"target unreachable: inverse kinematics got the tip no closer than "
                           f"{sampler.stats.closest_mm:.1f} mm to the target region after "
                           f"{sampler.stats.seeds} seeds")
        if budget.exhausted():
            reached = sampler.stats.ik_reached
            why = f": {reached} IK solutions reached the target, all {model.stability.invalid}" \
                if reached and not sampler.goals else ""
            ended = "time limit reached" if budget.cut_short and budget.time_limit else "budget used up"
            return outcome(None, "TIMEOUT", False,
                           f"{ended} while sampling goal configurations ({len(sampler.goals)} "
                           f"found{why}; {budget.describe()})")
        if spec.fixed_goal_set and region_goal:
            _fix_goal_set(problem, budget)
        pl = _setup_planner(spec, problem, s.range_mm)
        progress("search", elapsed=budget.elapsed(), states=budget.used(), max_states=budget.max_states,
                 kinematics_calls=checker.counters.kinematics_calls, goals=len(sampler.goals))
        t_solve = time.perf_counter()
        status = pl.solve(budget.termination_condition())
        timings["search_s"] = time.perf_counter() - t_solve
        status_name = status.asString() if hasattr(status, "asString") else str(status)
        if not problem.pdef.hasExactSolution():
            return outcome(None, status_name, False,
                           _failure_message(problem, budget, goal_q is not None))
        if simplify:
            progress("simplify", elapsed=budget.elapsed())
        stop = (lambda: budget.elapsed() >= budget.guard_s) if budget.time_limit else None
        path_q = _simplified_path(problem, simplify, timings, stop)
        budget.cut_short = budget.cut_short or timings.get("simplify_stopped", False)
        return outcome(path_q, status_name, True, "")


@dataclass
class PlanResult:
    """Everything `plan` found out; `to_json` gives the CLI document (docs/design.md §3)."""

    solved: bool
    planner: str
    backend: str
    planning_time_s: float
    kinematics_calls: int
    path: np.ndarray
    target_mm: np.ndarray
    goal_tolerance_mm: float
    base_pose: np.ndarray
    tip_mm: np.ndarray | None = None
    validated: Validation | None = None
    message: str = ""
    status: str = ""
    seed: int | None = None
    time_limit_s: float = 0.0
    scene: str = ""
    details: dict = field(default_factory=dict)
    dense: ValidatedPath | None = None
    max_states: int = 0
    cut_short: bool = False

    def to_json(self) -> dict:
        return {
            "solved": bool(self.solved),
            "planner": self.planner,
            "backend": self.backend,
            "planning_time_s": round(float(self.planning_time_s), 4),
            "kinematics_calls": int(self.kinematics_calls),
            "path": np.asarray(self.path, dtype=float).tolist(),
            "tip_mm": None if self.tip_mm is None else np.asarray(self.tip_mm, dtype=float).tolist(),
            "target_mm": np.asarray(self.target_mm, dtype=float).tolist(),
            "goal_tolerance_mm": float(self.goal_tolerance_mm),
            "base_pose": np.asarray(self.base_pose, dtype=float).tolist(),
            "validated": None if self.validated is None else self.validated.to_json(),
            "status": self.status,
            "message": self.message,
            "seed": self.seed,
            "time_limit_s": self.time_limit_s,
            "max_states": int(self.max_states),
            "cut_short": bool(self.cut_short),
            "scene": self.scene,
            "details": self.details,
        }


def check_start(model: PlanningModel, start_backbone: Backbone | None = None) -> None:
    """Raise `InputError` with what `ctrplan.planning.scene_check` finds before a search (obstacles
    of the wrong scale, a target inside an obstacle, a start outside the domain, not converged,
    unstable or colliding under the model's exact backend -- with the nearest valid start), one line.
    ``start_backbone``: the exact backbone of the start, if solved already (`compile_kernels`)."""
    report = check_scene(model.scene, reach=False, model=model, start_backbone=start_backbone)
    if not report.usable:
        raise InputError("; ".join(p.message for p in report.problems))


def compile_kernels(model: PlanningModel, progress: Progress = _quiet) -> Backbone:
    """Run the model's backends on the start and on it twice, and the IK kernels on a dummy seed, so
    that numba compiles (first run only) or loads from its cache every kernel a plan uses before the
    planning clock starts. Returns the exact backbone of the start (the start check uses it: the
    start is solved once).
    ``progress("compile", done=k, total=n)`` counts the n kernel sets (a backend's single-query and
    batched ones, and the exact backend's along a path where validation uses it), k of them ready."""
    q = np.asarray(model.scene.start, dtype=float)
    backends = [model.backend] if model.backend is model.exact else [model.backend, model.exact]
    calls = [(be.forward, batch) for be in backends for batch in (q, np.stack([q, q]))]  # single, batched
    if model.stability.continuation:
        calls.append((model.exact.forward_path, np.stack([q, q])))
    bb = None
    for done, (forward, batch) in enumerate(calls):
        progress("compile", done=done, total=len(calls))
        out = forward(batch, points=model.points, check=False)
        if batch.ndim == 1:
            bb = out
    compile_ik(model.space)
    progress("compile", done=len(calls), total=len(calls))
    return bb


def _time_limit(scene: Scene, time_limit_s: float | None) -> float:
    limit = float(time_limit_s if time_limit_s is not None else scene.settings.time_limit_s)
    if not math.isfinite(limit) or limit <= 0:
        raise InputError(f"time_limit_s: must be > 0, got {limit}")
    return limit


def exact_goal(path_q: np.ndarray, checker: ConfigurationChecker) -> np.ndarray:
    """The path with one more state, where the *exact* tip (the exact backend of ``checker``'s model)
    lies where the planning backend put the tip of the path's last state (inside the target), when the
    planning backend is a surrogate and the exact tip of that state misses the target.

    A surrogate's goal configuration misses the target by its tip error, often as much as the target
    is wide; a few exact damped-least-squares iterations from that configuration close the gap for the
    price of a few dozen exact solves, where re-planning the end with the exact model costs seconds.
    With an approach direction the iterations aim at the surrogate's tip pose (tangent weighted by
    `ANGLE_WEIGHT_MM_PER_RAD`): its orientation error can exceed the angular tolerance too.
    The surrogate's own view of the new state is beside the point (it is off by the same error), so
    the short move there is left to exact validation, like the rest of the path. Returns ``path_q``
    unchanged for an exact planning backend, or when the exact iterations fail."""
    if checker.backend.exact:
        return path_q
    exact = checker.model.exact
    goal = path_q[-1]
    scene = checker.scene
    bb = exact.forward(goal[None], points=2, check=False)
    tip = scene.to_scene(bb.tip_mm[0])
    target = scene.target
    if bb.converged[0] and target.contains(tip) and target.direction_ok(tip_tangents(scene, bb))[0]:
        return path_q
    aim, tangent, _ = checker.tips(goal[None])
    weight = None
    if target.direction is not None:  # the tip's direction matters too: aim at the surrogate's pose
        weight = ANGLE_WEIGHT_MM_PER_RAD
        aim = np.concatenate([aim, weight * tangent], axis=1)
    ik = solve_ik(backend_tip_jacobian(exact, checker.space, tangent_weight_mm=weight), checker.space,
                  goal[None], aim, tol_mm=EXACT_GOAL_TOL_MM, max_iterations=8)
    return np.vstack([path_q, ik.q]) if ik.success[0] else path_q


def _replanner(checker: ConfigurationChecker, seed: int | None, hints: np.ndarray,
               time_s: float, wall_end: float | None = None) -> tuple[Callable[..., np.ndarray | None], dict]:
    """``replan(start_q, goal_q)`` for `repair_path`: RRTConnect searches with ``checker`` (of the
    exact model), not shortcut (a shortcut hugs the obstacles: with the exact model's bare margin,
    one checked at the planner's resolution can fail the finer exact validation), sharing one work
    budget (what ``time_s`` buys with the exact model; each search gets what is left, at least a
    tenth) and one wall-clock guard, or the plan's time limit (``wall_end``, perf_counter: every
    search stops by then); and the budget's record (``max_states``, ``states``, ``cut_short``),
    updated by every search."""
    total = states_for(checker.backend.name, time_s)
    guard_end = time.perf_counter() + GUARD_FACTOR * time_s
    record = {"max_states": total, "states": 0, "cut_short": False}

    def replan(start_q: np.ndarray, goal_q: np.ndarray | None) -> np.ndarray | None:
        left = max(total - record["states"], total // 10)
        limit = max(guard_end - time.perf_counter(), 0.5 * GUARD_FACTOR) / GUARD_FACTOR
        wall = None if wall_end is None else max(0.0, wall_end - time.perf_counter())
        out = search(checker, start=start_q, goal_q=goal_q, planner="rrtconnect", time_limit_s=limit,
                     max_states=left, seed=seed, goal_hints=hints if goal_q is None else None,
                     simplify=False, wall_s=wall)
        record["states"] += out.budget["states"]
        record["cut_short"] = record["cut_short"] or out.budget["cut_short"]
        return out.path_q

    return replan, record


def _validate_and_repair(model: PlanningModel, path_q: np.ndarray, result: PlanResult, repair: bool,
                         progress: Progress, goals: list[np.ndarray],
                         clock: PlanClock | None = None) -> tuple[ValidatedPath, np.ndarray]:
    """Exact validation of a planned path; if it fails and ``repair``, the failing stretches are
    re-planned with the exact model and the repaired path is validated again -- an end re-planned
    to the target samples its exact goals from the path's last state and the search's ``goals``
    first (exact inverse kinematics from scratch costs most of a repair). Records repair time and
    calls in ``result``; returns the validated path and its joints. With the plan's ``clock`` (a time
    limit) the repair's searches stop in time to validate the repaired path before it runs out."""
    progress("validate")
    vp = validate_planned_path(model, path_q)
    result.details["validation_time_s"] = vp.report.time_s
    if vp.report.ok or not repair:
        return vp, path_q
    wall_end = None if clock is None else time.perf_counter() + clock.left() - 1.5 * vp.report.time_s
    if wall_end is not None and wall_end <= time.perf_counter():
        result.details["repair"] = "not tried: no time left within the time limit"
        result.cut_short = True
        return vp, path_q
    progress("repair")
    t_rep = time.perf_counter()
    rep_checker = ConfigurationChecker(model.exact_search())
    rep_seed = None if result.seed is None else result.seed + 1
    hints = np.stack([path_q[-1], *goals])
    replan, budget = _replanner(rep_checker, rep_seed, hints, max(5.0, result.time_limit_s), wall_end)
    fixed = repair_path(vp, replan)
    result.details["repair_budget"] = budget
    result.cut_short = result.cut_short or budget["cut_short"]
    rep_time = time.perf_counter() - t_rep
    result.details["repair_time_s"] = rep_time
    result.planning_time_s += rep_time
    result.kinematics_calls += rep_checker.counters.kinematics_calls
    result.details["first_validation"] = vp.report.to_json()
    if fixed is None:
        result.details["repair"] = "re-planning with the exact model failed"
        return vp, path_q
    fixed = model.space.unwrap(fixed)
    vp2 = validate_planned_path(model, fixed)
    vp2.report.repaired = True
    if vp2.report.ok:
        return vp2, fixed
    result.details["repair"] = "the repaired path failed exact validation"
    return vp, path_q


def _verdict(report: Validation, repair: bool) -> str:
    """The result message of a validated path."""
    if report.ok:
        return "solved" + (" (repaired with the exact model)" if report.repaired else "")
    why = []
    if not report.collision_free:
        fc = report.first_collision or {}
        why.append(f"the exact robot collides along the path ({len(report.colliding_states)} of "
                   f"{report.states} states; first with {', '.join(fc.get('obstacles', []))})")
    if not report.tip_in_target:
        why.append("the exact tip misses the target")
    if not report.stable:
        why.append("the path passes through unstable equilibria (the robot would snap)")
    return "not solved: " + "; ".join(why) + ("" if repair else " (repair disabled)")


def _report_guard(result: PlanResult, clock: PlanClock | None) -> None:
    """Say so when the clock cut a search of the plan short (then, and only then, the verdict depends
    on the machine's speed and load), and, for a time limit, how to make it reproducible."""
    if result.cut_short and "wall-clock guard" not in result.message and "--max-states" not in result.message:
        result.message += clock_message(clock, result.max_states)


def plan(scene: Scene, backend: str | Backend | None = None, *, planner: str | None = None,
         time_limit_s: float | None = None, max_states: int | None = None, seed: int | None = None,
         progress: Progress = _quiet,
         exact: Backend | None = None, repair: bool | None = None,
         goal_hints: np.ndarray | None = None, world: CollisionWorld | None = None,
         wall_limit: bool | None = None) -> PlanResult:
    """Plan a collision-free motion from the scene's start to its target, then validate it exactly.

    With an approximate backend (the PINN) the capsules get extra radius while planning: its
    calibrated error bound by arc-length region at the scene's ``surrogate_coverage``, or the
    scene's ``surrogate_margin_mm`` (see `ctrplan.planning.model.planning_backend`). The planning
    model (`PlanningModel.build`: backends, margins, collision world, the stability decision) is
    built once here and handed to the search, validation and repair. Every path is re-validated with the
    exact model at the planner's resolution (refined where the backbone moves more than a capsule
    radius); a path that fails there is repaired (colliding stretches re-planned with the exact
    model) or reported as not solved. ``solved`` is True only if the exact model confirms a
    collision-free path that ends with the tip in the target. Kernels are compiled before the clock
    starts; a plan that takes longer than ``time_limit_s`` says so. Bad input (an unknown planner,
    a start in collision) raises `InputError` naming the parameter. ``goal_hints`` (K, 2N): goal
    configurations known already (e.g. from a reachability screen), where goal sampling starts.
    ``world``: the scene's collision world if already built (a design study plans many targets in
    one anatomy); by default it is built here.

    The clock (`ctrplan.planning.budget`): with ``wall_limit`` (default: when no work budget is given,
    neither ``max_states`` nor the scene's) ``time_limit_s`` is a time limit -- everything after
    kernel compilation ends within `WALL_FACTOR` x it; otherwise the work budget decides and the
    clock only guards.
    """
    t_entry = time.perf_counter()
    s = scene.settings
    wall_limit = (max_states is None and s.max_states is None) if wall_limit is None else wall_limit
    planner, _ = scene_planner(scene, planner)
    time_limit_s = _time_limit(scene, time_limit_s)
    max_states = check_max_states(max_states) or s.max_states
    seed = s.seed if seed is None else seed
    repair = s.repair if repair is None else repair
    progress("compile")  # loading a backend compiles its kernels too
    t_compile = time.perf_counter()
    scene.robot.calibration.refuse(scene.robot.name, "plan")
    model = PlanningModel.build(scene, resolve_backend(backend, scene.robot), exact, world)
    start_bb = compile_kernels(model, progress)
    compile_s = time.perf_counter() - t_compile
    clock = PlanClock(time_limit_s, t_entry + compile_s) if wall_limit else None
    progress("start")  # the collision world: its distance grid and kernels on first use
    check_start(model, start_bb)  # the start under the exact model, solved once
    checker = ConfigurationChecker(model)
    result = PlanResult(False, planner, model.backend.name, 0.0, 0, np.zeros((0, len(scene.start))),
                        scene.target.center, scene.target.tolerance_mm, scene.base_pose, seed=seed,
                        time_limit_s=time_limit_s, scene=scene.name,
                        max_states=max_states or states_for(model.backend.name, time_limit_s))
    result.details = {"planning_margin_mm": model.margin_mm, "surrogate_margin": model.margin_source,
                      "compile_s": compile_s}
    if not checker.is_valid(scene.start):  # under the planning backend: cached for the search
        # valid for the exact model (checked above), not for the planning backend + its margin
        result.status = "INVALID_START"
        result.message = (f"the start configuration collides under the {model.backend.name} backend with "
                          f"its planning margin ({model.margin_source['source']}) but not under the exact "
                          f"model with {s.margin_mm:g} mm")
        result.details["counters"] = vars(checker.counters).copy()
        return result
    outcome = search(checker, planner=planner, time_limit_s=time_limit_s, max_states=result.max_states,
                     seed=seed, progress=progress, goal_hints=goal_hints,
                     wall_s=None if clock is None else clock.search_left())
    _record_search(result, outcome, checker)
    if outcome.path_q is not None:
        t_goal = time.perf_counter()
        path_q = model.space.unwrap(exact_goal(outcome.path_q, checker))
        result.details["exact_goal"] = {"appended": len(path_q) > len(outcome.path_q),
                                        "time_s": time.perf_counter() - t_goal}
        result.planning_time_s += result.details["exact_goal"]["time_s"]
        vp, result.path = _validate_and_repair(model, path_q, result, repair, progress, outcome.goals,
                                               clock)
        result.validated, result.dense = vp.report, vp
        result.tip_mm = np.asarray(vp.report.tip_mm)
        result.solved = vp.report.ok
        result.message = _verdict(vp.report, repair)
    _report_guard(result, clock)
    result.details["clock"] = clock_record(clock, time_limit_s, model.backend.name)
    return result


def _record_search(result: PlanResult, outcome: SearchOutcome, checker: ConfigurationChecker) -> None:
    """The search's outcome, work and budget in ``result``."""
    result.planning_time_s = outcome.time_s
    result.kinematics_calls = checker.counters.kinematics_calls
    result.status, result.message = outcome.status, outcome.message
    result.details["counters"] = vars(checker.counters).copy()
    result.details["goal_sampling"] = outcome.goal_stats
    result.details["budget"] = outcome.budget
    result.cut_short = outcome.budget["cut_short"]
