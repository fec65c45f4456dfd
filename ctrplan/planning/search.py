"""One OMPL search of a planning model: the problem (state space, validity checker, batched motion
validator, IK-sampled goal region), goal sampling first, the planner from the table of
`ctrplan.planning.planners`, a solve budgeted in work (`ctrplan.planning.budget`), path simplification.
Wiring follows OMPL's ``demos/OptimalPlanning.py``. All OMPL objects live inside function scope
(docs/design.md §4: module-level OMPL objects leak at exit).

`search` is what `ctrplan.planning.plan` runs first and its repair runs again with the exact model;
`build_problem` / `problem_for` give the OMPL objects to user code (any OMPL planner).
"""

from __future__ import annotations

import gc
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from copy import copy
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from ompl import base as ob
from ompl import util as ou

from ctrplan.base.machine import numba_threads_at_most
from ctrplan.kinematics.base import Backend
from ctrplan.kinematics.blas import single_threaded_blas
from ctrplan.kinematics.pinn import ROW_BLOCKS
from ctrplan.planning.budget import GUARD_FACTOR, SearchBudget, states_for
from ctrplan.planning.goal import GoalSampler, TipGoal
from ctrplan.planning.model import PlanningModel
from ctrplan.planning.planners import PlannerSpec, scene_planner
from ctrplan.planning.result import BudgetUse, SearchRecord, SearchTimings
from ctrplan.planning.shortcut import shortcut_path
from ctrplan.planning.validity import BatchMotionValidator, ConfigurationChecker, ValidityChecker
from ctrplan.scene.objects import Scene

#: Share of a search's work budget between two goal-sampling batches once goals are known.
REFILL_SHARE = 0.05

Progress = Callable[..., None]


def no_progress(*_args: Any, **_kw: Any) -> None:
    """A `Progress` that reports nothing."""
    return None


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
    """Raw result of one OMPL search: the path (K, 2N) or None, OMPL's status, whether the solution is
    exact, the time (s), the record (goal sampling, stage timings, budget use), why it failed, and
    the goal configurations it found."""

    path_q: np.ndarray | None
    status: str
    exact: bool
    time_s: float
    record: SearchRecord
    message: str = ""
    goals: list[np.ndarray] = field(default_factory=list)

    @property
    def budget(self) -> BudgetUse:
        """Work used, the guard, and whether it cut the search short."""
        return self.record.budget


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
                     stop: Callable[[], bool] | None = None) -> tuple[np.ndarray, bool]:
    """The solution as joints (K, 2N), continuous (`BoxSpace.unwrap`), shortcut first if ``simplify``
    (`shortcut_path`: batched, lazy checks at the motion validator's resolution, until ``stop()``);
    and whether ``stop`` ended the shortcut early."""
    box, checker = problem.box, problem.checker
    path_q = box.unwrap(_path_q(problem, problem.pdef.getSolutionPath()))
    if not simplify:
        return path_q, False
    t_simp = time.perf_counter()
    cut = shortcut_path(box.to_coords(path_q), lambda y: checker.validate(box.to_joints(y))[0],
                        problem.motion_validator.resolution, box.difference, stop)
    timings["simplify_s"] = time.perf_counter() - t_simp
    timings["simplify_states"] = cut.states
    return path_q[cut.vertices], cut.stopped


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
           progress: Progress = no_progress, simplify: bool | None = None, goal_q: np.ndarray | None = None,
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
            record = SearchRecord(copy(sampler.stats), SearchTimings(**timings),
                                  BudgetUse(**budget.to_json()))
            return SearchOutcome(path_q, status, exact, budget.elapsed(), record, message,
                                 list(sampler.goals))

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
        path_q, stopped = _simplified_path(problem, simplify, timings, stop)
        budget.cut_short = budget.cut_short or stopped
        return outcome(path_q, status_name, True, "")
