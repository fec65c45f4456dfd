"""Planning pipeline: scene + backend -> OMPL problem -> path -> exact validation (-> repair).

Wiring follows OMPL's ``demos/OptimalPlanning.py``: a `BoxSpace` state space, a `ValidityChecker`,
a `BatchMotionValidator`, a `TipGoal` (IK-sampled goal region), a planner by name, a time-limited
solve, path simplification; then `validate_path` with the exact Cosserat model. All OMPL objects live
inside function scope (DESIGN §4: module-level OMPL objects leak at exit).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from ompl import base as ob
from ompl import geometric as og
from ompl import util as ou

from ctrplan.errors import InputError
from ctrplan.kinematics import make_backend
from ctrplan.kinematics.base import Backend
from ctrplan.kinematics.cosserat import CosseratBackend
from ctrplan.planning.goal import GoalSampler, TipGoal
from ctrplan.planning.validate import ValidatedPath, Validation, repair_path, validate_path
from ctrplan.planning.validity import BatchMotionValidator, ConfigurationChecker, ValidityChecker
from ctrplan.scene import PLANNERS, Scene

PLANNER_CLASSES = {
    "rrtconnect": og.RRTConnect,
    "rrt": og.RRT,
    "rrtstar": og.RRTstar,
    "bitstar": og.BITstar,
    "kpiece": og.KPIECE1,
}
#: Names OMPL uses for the planners (for logs and benchmark databases).
OMPL_NAMES = {"rrtconnect": "RRTConnect", "rrt": "RRT", "rrtstar": "RRTstar", "bitstar": "BITstar",
              "kpiece": "KPIECE1"}
OPTIMIZING = {"rrtstar", "bitstar"}

Progress = Callable[..., None]


def _quiet(*_args: Any, **_kw: Any) -> None:
    return None


def resolve_backend(name: str | Backend | None, robot) -> Backend:
    """A backend instance: given, or by name (default ``pinn``). One that cannot be built raises
    (`InputError` naming why): never a silent fallback to another backend."""
    if isinstance(name, Backend):
        return name
    return make_backend(name or "pinn", robot)


def make_planner(name: str, si) -> Any:
    """An OMPL geometric planner by ctrplan name (`PLANNERS`)."""
    try:
        cls = PLANNER_CLASSES[name]
    except KeyError:
        raise InputError(f"--planner: unknown planner {name!r} (choose from {', '.join(PLANNERS)})") \
            from None
    return cls(si)


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


@dataclass
class PlanningProblem:
    """The OMPL objects of one planning problem, for use with any planner from user code.

    Build with `build_problem`; then e.g. ``planner = og.PRMstar(problem.si)`` (single goal state
    planners only with PRM: see DESIGN §4), ``planner.setProblemDefinition(problem.pdef)``,
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
    box: Any = field(init=False)

    def __post_init__(self) -> None:
        self.box = self.checker.space

    def solution(self) -> np.ndarray | None:
        """The current solution path as joints (K, 6), or None."""
        if not self.pdef.hasSolution():
            return None
        path = self.pdef.getSolutionPath()
        return np.stack([self.box.state_to_q(path.getState(i)) for i in range(path.getStateCount())])


def build_problem(scene: Scene, backend: Backend, *, start: np.ndarray | None = None,
                  rng: np.random.Generator | None = None,
                  checker: ConfigurationChecker | None = None,
                  goal_q: np.ndarray | None = None) -> PlanningProblem:
    """State space, validity checker, motion validator, start and goal wired into OMPL objects.

    The goal is the scene's target region (a `TipGoal` sampled by IK), or the single configuration
    ``goal_q`` (an ``ob.GoalState``, e.g. to reconnect two states of a path)."""
    checker = checker or ConfigurationChecker(scene, backend)
    box = checker.space
    space = box.make_ompl_space()
    si = ob.SpaceInformation(space)
    validity = ValidityChecker(si, checker)
    si.setStateValidityChecker(validity)
    mv = BatchMotionValidator(si, checker)
    si.setMotionValidator(mv)
    si.setup()
    pdef = ob.ProblemDefinition(si)
    st = si.allocState()
    box.set_state(st, scene.start if start is None else start)
    pdef.addStartState(st)
    sampler = GoalSampler(checker, scene.target, rng or np.random.default_rng(),
                          seeds_per_batch=max(4, 3 * scene.settings.goal_samples),
                          start=scene.start if start is None else start)
    if goal_q is None:
        goal = TipGoal(si, sampler)
    else:
        goal = ob.GoalState(si)
        gs = si.allocState()
        box.set_state(gs, goal_q)
        goal.setState(gs)
        goal.setThreshold(1e-6)
    pdef.setGoal(goal)
    return PlanningProblem(scene, checker, space, si, pdef, goal, sampler, validity, mv)


def _path_q(problem: PlanningProblem, path) -> np.ndarray:
    return np.stack([problem.box.state_to_q(path.getState(i)) for i in range(path.getStateCount())])


def search(scene: Scene, backend: Backend, *, start: np.ndarray | None = None, planner: str | None = None,
           time_limit_s: float | None = None, seed: int | None = None, progress: Progress = _quiet,
           simplify: bool | None = None, checker: ConfigurationChecker | None = None,
           goal_q: np.ndarray | None = None) -> tuple[SearchOutcome, ConfigurationChecker]:
    """One OMPL search from ``start`` (default: the scene's) to the target region (or to the
    configuration ``goal_q``) with ``backend``."""
    s = scene.settings
    planner = planner or s.planner
    time_limit_s = float(time_limit_s if time_limit_s is not None else s.time_limit_s)
    simplify = s.simplify if simplify is None else simplify
    t0 = time.perf_counter()
    seed_ompl(seed)
    rng = np.random.default_rng(seed)
    problem = build_problem(scene, backend, start=start, rng=rng, checker=checker, goal_q=goal_q)
    checker = problem.checker
    last = [0.0]

    def hook() -> None:
        now = time.perf_counter()
        if now - last[0] > 0.1:
            last[0] = now
            progress("search", elapsed=now - t0, limit=time_limit_s,
                     kinematics_calls=checker.counters.kinematics_calls,
                     goals=len(problem.sampler.goals))

    checker.hook = hook
    if isinstance(problem.goal, TipGoal):
        problem.goal.deadline = t0 + time_limit_s

    def remaining() -> float:
        return time_limit_s - (time.perf_counter() - t0)

    # Goal configurations first: they tell early whether the target is reachable at all.
    sampler = problem.sampler
    progress("goal", elapsed=0.0, limit=time_limit_s)
    for _ in range(6 if goal_q is None else 0):
        if sampler.goals or remaining() <= 0:
            break
        sampler.sample_batch()
        if sampler.stats.batches >= 2 and sampler.stats.ik_reached == 0 and not sampler.goals:
            break
    gstats = sampler.stats
    if goal_q is None and not sampler.goals and gstats.ik_reached == 0:
        msg = (f"target unreachable: inverse kinematics got the tip no closer than "
               f"{gstats.closest_mm:.1f} mm to the target region after {gstats.seeds} seeds")
        checker.hook = None
        return SearchOutcome(None, "INVALID_GOAL", False, time.perf_counter() - t0, vars(gstats).copy(),
                             msg), checker

    if planner == "bitstar" and isinstance(problem.goal, TipGoal):
        # BIT* drains every goal sample when it (re)starts a batch and restarts on new goals: give
        # it a fixed set
        while len(sampler.goals) < 8 and remaining() > 0.5 * time_limit_s and sampler.stats.batches < 12:
            sampler.sample_batch()
        problem.goal.max_batches = sampler.stats.batches
    pl = make_planner(planner, problem.si)
    if s.range_mm is not None and hasattr(pl, "setRange"):
        pl.setRange(float(s.range_mm))
    if planner in OPTIMIZING:
        problem.pdef.setOptimizationObjective(ob.PathLengthOptimizationObjective(problem.si))
    pl.setProblemDefinition(problem.pdef)
    pl.setup()
    progress("search", elapsed=time.perf_counter() - t0, limit=time_limit_s,
             kinematics_calls=checker.counters.kinematics_calls, goals=len(sampler.goals))
    t_solve = time.perf_counter()
    timings = {"goal_sampling_s": t_solve - t0}
    status = pl.solve(max(remaining(), 1e-3))
    timings["search_s"] = time.perf_counter() - t_solve
    status_name = status.asString() if hasattr(status, "asString") else str(status)
    exact = bool(problem.pdef.hasExactSolution())
    path_q = None
    msg = ""
    if exact:
        path = problem.pdef.getSolutionPath()
        if simplify:
            progress("simplify", elapsed=time.perf_counter() - t0)
            simp = og.PathSimplifier(problem.si, problem.pdef.getGoal())
            t_simp = time.perf_counter()
            # shortcuts between random vertex pairs; full `simplify` (B-spline smoothing) costs
            # seconds with an exact backend and adds many vertices
            simp.reduceVertices(path)
            simp.collapseCloseVertices(path)
            timings["simplify_s"] = time.perf_counter() - t_simp
        path_q = _path_q(problem, path)
    else:
        if goal_q is not None:
            msg = f"no path to the given configuration within {time_limit_s:g} s"
        elif not sampler.goals:
            msg = (f"no collision-free goal configuration found ({gstats.ik_reached} IK solutions "
                   f"reached the target, all in collision)")
        else:
            msg = f"no path found within {time_limit_s:g} s ({len(sampler.goals)} goal configurations)"
    checker.hook = None
    out = SearchOutcome(path_q, status_name, exact, time.perf_counter() - t0,
                        {**vars(gstats), **timings}, msg)
    return out, checker


@dataclass
class PlanResult:
    """Everything `plan` found out; `to_json` gives the CLI document (DESIGN §3)."""

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
            "scene": self.scene,
            "details": self.details,
        }


def check_start(scene: Scene, checker: ConfigurationChecker, exact: Backend) -> None:
    """Raise `InputError` if the start collides under the exact model (bad input)."""
    from ctrplan.collision import RobotCollisionChecker

    bb = exact.forward(scene.start, points=checker.points, check=False)
    rc = RobotCollisionChecker(checker.world, scene.base_pose, checker.points, scene.settings.margin_mm)
    if not bb.converged[0]:
        raise InputError(f"{scene.where('start')}: the exact model does not converge at the start "
                         f"configuration")
    contacts = rc.contacts(bb.positions_mm[0], bb.radius_mm[0])
    if contacts:
        names = ", ".join(sorted({n for _, n in contacts}))
        raise InputError(f"{scene.where('start')}: the start configuration is in collision with "
                         f"{names} (margin {scene.settings.margin_mm:g} mm)")


def plan(scene: Scene, backend: str | Backend | None = None, *, planner: str | None = None,
         time_limit_s: float | None = None, seed: int | None = None, progress: Progress = _quiet,
         exact: Backend | None = None, repair: bool | None = None) -> PlanResult:
    """Plan a collision-free motion from the scene's start to its target, then validate it exactly.

    With an approximate backend (the PINN) the capsules get ``surrogate_margin_mm`` extra while
    planning. Every path is re-validated with the exact model at the planner's resolution; a path
    that fails there is repaired (colliding stretches re-planned with the exact model) or reported
    as not solved. ``solved`` is True only if the exact model confirms a collision-free path that
    ends with the tip in the target. Bad input (e.g. a start in collision) raises `InputError`.
    """
    s = scene.settings
    planner = planner or s.planner
    if planner not in PLANNERS:
        raise InputError(f"--planner: unknown planner {planner!r} (choose from {', '.join(PLANNERS)})")
    time_limit_s = float(time_limit_s if time_limit_s is not None else s.time_limit_s)
    if not math.isfinite(time_limit_s) or time_limit_s <= 0:
        raise InputError(f"--time-limit: must be > 0, got {time_limit_s}")
    seed = s.seed if seed is None else seed
    repair = s.repair if repair is None else repair
    be = resolve_backend(backend, scene.robot)
    exact = exact or (be if be.exact and be.robot is scene.robot else CosseratBackend(scene.robot))
    margin = s.margin_mm + (0.0 if be.exact else s.surrogate_margin_mm)
    checker = ConfigurationChecker(scene, be, margin_mm=margin)
    check_start(scene, checker, exact)

    def result_of(outcome: SearchOutcome | None, message: str, status: str) -> PlanResult:
        r = PlanResult(False, planner, be.name, 0.0 if outcome is None else outcome.time_s,
                       checker.counters.kinematics_calls, np.zeros((0, 6)), scene.target.center,
                       scene.target.tolerance_mm, scene.base_pose, message=message, status=status,
                       seed=seed, time_limit_s=time_limit_s, scene=scene.name)
        r.details = {"planning_margin_mm": margin, "counters": vars(checker.counters).copy()}
        if outcome is not None:
            r.details["goal_sampling"] = outcome.goal_stats
        return r

    if not checker.is_valid(scene.start):
        # valid for the exact model (checked above), not for the planning backend + its margin
        return result_of(None, f"the start configuration collides under the {be.name} backend "
                               f"with its planning margin of {margin:g} mm (but not under the exact "
                               f"model with {s.margin_mm:g} mm)", "INVALID_START")

    outcome, checker = search(scene, be, planner=planner, time_limit_s=time_limit_s, seed=seed,
                              progress=progress, checker=checker)
    result = result_of(outcome, outcome.message, outcome.status)
    if outcome.path_q is None:
        return result

    progress("validate")
    vp = validate_path(scene, outcome.path_q, be, exact=exact, world=checker.world)
    path_q = outcome.path_q
    result.details["validation_time_s"] = vp.report.time_s
    if not vp.report.ok and repair:
        progress("repair")
        t_rep = time.perf_counter()
        rep_checker = ConfigurationChecker(scene, exact, world=checker.world)
        rep_seed = None if seed is None else seed + 1

        def replan(start_q: np.ndarray, goal_q: np.ndarray | None, limit: float) -> np.ndarray | None:
            out, _ = search(scene, exact, start=start_q, goal_q=goal_q, planner="rrtconnect",
                            time_limit_s=limit, seed=rep_seed, checker=rep_checker)
            return out.path_q

        fixed = repair_path(vp, replan, max(5.0, time_limit_s))
        rep_time = time.perf_counter() - t_rep
        result.details["repair_time_s"] = rep_time
        result.planning_time_s += rep_time
        result.kinematics_calls += rep_checker.counters.kinematics_calls
        result.details["first_validation"] = vp.report.to_json()
        if fixed is not None:
            vp2 = validate_path(scene, fixed, be, exact=exact, world=checker.world)
            vp2.report.repaired = True
            if vp2.report.ok:
                vp, path_q = vp2, fixed
            else:
                result.details["repair"] = "the repaired path failed exact validation"
        else:
            result.details["repair"] = "re-planning with the exact model failed"

    result.validated = vp.report
    result.dense = vp
    result.tip_mm = np.asarray(vp.report.tip_mm)
    result.path = path_q
    result.solved = vp.report.ok
    if result.solved:
        result.message = "solved" + (" (repaired with the exact model)" if vp.report.repaired else "")
    else:
        why = []
        if not vp.report.collision_free:
            fc = vp.report.first_collision or {}
            why.append(f"the exact robot collides along the path ({len(vp.report.colliding_states)} of "
                       f"{vp.report.states} states; first with {', '.join(fc.get('obstacles', []))})")
        if not vp.report.tip_in_target:
            why.append("the exact tip misses the target")
        result.message = "not solved: " + "; ".join(why) + ("" if repair else " (repair disabled)")
    return result
