"""Planning pipeline: scene + backend -> planning model -> search -> exact goal -> exact validation
(-> repair) -> one `PlanResult`.

`plan` builds one frozen `PlanningModel` (`ctrplan.planning.model`) and hands it to every step; each
search (`ctrplan.planning.search`) keeps its caches and counters in a `ConfigurationChecker`. The path
is then checked by `validate_planned_path` with the model's exact backend, repaired where it fails,
and -- when the caller renders it -- its clearances measured once (`measure_clearance`). Each step
returns a typed record; the result is built from them when the plan ends (`ctrplan.planning.result`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from copy import copy
from dataclasses import replace
from typing import Any

import numpy as np

from ctrplan.base.errors import InputError
from ctrplan.collision.world import CollisionWorld
from ctrplan.kinematics import DEFAULT_PLANNING_BACKEND, make_backend
from ctrplan.kinematics.backbone import Backbone
from ctrplan.kinematics.base import Backend
from ctrplan.planning.budget import (
    GUARD_FACTOR,
    PlanClock,
    check_max_states,
    clock_message,
    clock_record,
    states_for,
)
from ctrplan.planning.failure import FailureAnalysis, explain_failure
from ctrplan.planning.goal import ANGLE_WEIGHT_MM_PER_RAD, tip_tangents
from ctrplan.planning.ik import backend_tip_jacobian, compile_ik, solve_ik
from ctrplan.planning.model import PlanningModel
from ctrplan.planning.planners import scene_planner
from ctrplan.planning.result import ExactGoal, PlanResult, PlanWork, RepairRecord
from ctrplan.planning.scene_check import check_scene
from ctrplan.planning.search import Progress, SearchOutcome, no_progress, search
from ctrplan.planning.validate import (
    ValidatedPath,
    Validation,
    measure_clearance,
    repair_path,
    validate_planned_path,
)
from ctrplan.planning.validity import ConfigurationChecker
from ctrplan.scene.objects import Scene

#: How close (mm) `exact_goal` brings the exact tip to the surrogate's.
EXACT_GOAL_TOL_MM = 0.05


def resolve_backend(name: str | Backend | None, robot) -> Backend:
    """A backend instance: given, or by name (default: `DEFAULT_PLANNING_BACKEND`). One that cannot be
    built raises (`InputError` naming why): never a silent fallback to another backend."""
    if isinstance(name, Backend):
        return name
    return make_backend(name or DEFAULT_PLANNING_BACKEND, robot)


def check_start(model: PlanningModel, start_backbone: Backbone | None = None) -> None:
    """Raise `InputError` with what `ctrplan.planning.scene_check` finds before a search (obstacles
    of the wrong scale, a target inside an obstacle, a start outside the domain, not converged,
    unstable or colliding under the model's exact backend -- with the nearest valid start), one line.
    ``start_backbone``: the exact backbone of the start, if solved already (`compile_kernels`)."""
    report = check_scene(model.scene, reach=False, model=model, start_backbone=start_backbone)
    if not report.usable:
        raise InputError("; ".join(p.message for p in report.problems))


def compile_kernels(model: PlanningModel, progress: Progress = no_progress) -> Backbone:
    """Run the model's backends on the start and on it twice, the IK kernels on a dummy seed and the
    collision checks on the start, so that numba compiles (first run only) or loads from its cache
    every kernel a plan uses before the planning clock starts. Returns the exact backbone of the start
    (the start check uses it: the start is solved once).
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
    # the collision checks' kernels (single and batched) and the world's grids, on throwaway checkers
    # (their counters are no plan's; two, since one's state cache would answer the batch from the single
    # check): on a cold cache they took the whole time limit of a first plan
    ConfigurationChecker(model).is_valid(q)
    ConfigurationChecker(model).check(np.stack([q, q]))
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
    search stops by then); and the budget's running count (``max_states``, ``states``,
    ``cut_short``), updated by every search."""
    total = states_for(checker.backend.name, time_s)
    guard_end = time.perf_counter() + GUARD_FACTOR * time_s
    used = {"max_states": total, "states": 0, "cut_short": False}

    def replan(start_q: np.ndarray, goal_q: np.ndarray | None) -> np.ndarray | None:
        left = max(total - used["states"], total // 10)
        limit = max(guard_end - time.perf_counter(), 0.5 * GUARD_FACTOR) / GUARD_FACTOR
        wall = None if wall_end is None else max(0.0, wall_end - time.perf_counter())
        out = search(checker, start=start_q, goal_q=goal_q, planner="rrtconnect", time_limit_s=limit,
                     max_states=left, seed=seed, goal_hints=hints if goal_q is None else None,
                     simplify=False, wall_s=wall)
        used["states"] += out.budget.states
        used["cut_short"] = used["cut_short"] or out.budget.cut_short
        return out.path_q

    return replan, used


def _repair(model: PlanningModel, first: ValidatedPath, path_q: np.ndarray, seed: int | None,
            time_limit_s: float, progress: Progress, goals: list[np.ndarray], clock: PlanClock | None
            ) -> tuple[ValidatedPath, np.ndarray, RepairRecord]:
    """Re-plan the stretches of a path that failed exact validation (``first``) with the exact model
    and validate the repaired path again -- an end re-planned to the target samples its exact goals
    from the path's last state and the search's ``goals`` first (exact inverse kinematics from scratch
    costs most of a repair). Returns the validated path (the repaired one if it passes, else
    ``first``), its joints, and the repair's record. With the plan's ``clock`` (a time limit) the
    repair's searches stop in time to validate the repaired path before it runs out."""
    t_rep = time.perf_counter()
    rep_checker = ConfigurationChecker(model.exact_search())
    wall_end = None if clock is None else t_rep + clock.left() - 1.5 * first.report.time_s
    hints = np.stack([path_q[-1], *goals])
    replan, used = _replanner(rep_checker, None if seed is None else seed + 1, hints, max(5.0, time_limit_s),
                              wall_end)
    if wall_end is not None and wall_end <= t_rep:
        used["cut_short"] = True
        fixed, failure = None, "not tried: no time left within the time limit"
    else:
        progress("repair")
        fixed, failure = repair_path(first, replan), "re-planning with the exact model failed"
    rep_time = time.perf_counter() - t_rep

    def record(failure: str | None) -> RepairRecord:
        return RepairRecord(used["max_states"], used["states"], used["cut_short"], rep_time,
                            rep_checker.counters.kinematics_calls, first.report, failure)

    if fixed is None:
        return first, path_q, record(failure)
    fixed = model.space.unwrap(fixed)
    second = validate_planned_path(model, fixed)
    second.report.repaired = True
    if second.report.ok:
        return second, fixed, record(None)
    return first, path_q, record("the repaired path failed exact validation")


def _verdict(report: Validation, repair: bool) -> str:
    """The result message of a validated path."""
    if report.ok:
        return "solved" + (" (repaired with the exact model)" if report.repaired else "")
    why = []
    if not report.collision_free:
        fc = report.first_collision
        names = ", ".join([] if fc is None else fc.labels)
        why.append(f"the exact robot collides along the path ({len(report.colliding_states)} of "
                   f"{report.states} states; first with {names})")
    if not report.tip_in_target:
        why.append("the exact tip misses the target")
    if not report.stable:
        why.append("the path passes through unstable equilibria (the robot would snap)")
    return "not solved: " + "; ".join(why) + ("" if repair else " (repair disabled)")


def _guard_note(message: str, cut_short: bool, clock: PlanClock | None, max_states: int) -> str:
    """``message``, saying so when the clock cut a search of the plan short (then, and only then, the
    verdict depends on the machine's speed and load), and, for a time limit, how to make it
    reproducible."""
    if cut_short and "wall-clock guard" not in message and "--max-states" not in message:
        return message + clock_message(clock, max_states)
    return message


def plan(scene: Scene, backend: str | Backend | None = None, *, planner: str | None = None,
         time_limit_s: float | None = None, max_states: int | None = None, seed: int | None = None,
         progress: Progress = no_progress,
         exact: Backend | None = None, repair: bool | None = None,
         goal_hints: np.ndarray | None = None, world: CollisionWorld | None = None,
         clearances: bool = False, wall_limit: bool | None = None, explain: bool = True) -> PlanResult:
    """Plan a collision-free motion from the scene's start to its target, then validate it exactly.

    With an approximate backend (the PINN) the capsules get extra radius while planning: its
    calibrated error bound by arc-length region at the scene's ``surrogate_coverage``, or the
    scene's ``surrogate_margin_mm`` (see `ctrplan.planning.model.planning_backend`). The planning
    model (`PlanningModel.build`) is built once and shared. Every path is re-validated with the
    exact model -- ``exact``, by default the backend's exact companion
    (`ctrplan.kinematics.registry.exact_companion`) -- at the planner's resolution (refined where
    the backbone moves more than a capsule radius); a path that fails there is repaired (colliding
    stretches re-planned with the exact model) or reported as not solved. ``solved`` is True only if
    the exact model confirms a collision-free path that ends with the tip in the target. Kernels are
    compiled and the start checked before the clock starts; a plan that takes longer than
    ``time_limit_s`` says so. Bad input (an unknown planner, a start in collision) raises
    `InputError` naming the parameter.
    ``goal_hints`` (K, 2N): goal configurations known already (e.g. from a reachability screen),
    where goal sampling starts. ``world``: the scene's collision world if already built (a design
    study plans many targets in one anatomy); by default it is built here. ``clearances``: also
    measure the validated path's clearances for the outputs (`measure_clearance`; after the clock).
    ``explain``: when the search finds no path, examine what it rejected (`explain_failure`: the
    blocking structures with counts, collision against instability, suggestions) into the result's
    ``failure`` and message -- within the time limit, if there is one.

    The clock (`ctrplan.planning.budget`): with ``wall_limit`` (default: when no work budget is given,
    neither ``max_states`` nor the scene's) ``time_limit_s`` is a time limit -- everything after
    the set-up (kernel compilation, the start check) ends within `WALL_FACTOR` x it; otherwise the
    work budget decides and the clock only guards.
    """
    t_entry = time.perf_counter()
    s = scene.settings
    wall_limit = (max_states is None and s.max_states is None) if wall_limit is None else wall_limit
    planner, _ = scene_planner(scene, planner)
    time_limit_s = _time_limit(scene, time_limit_s)
    max_states = check_max_states(max_states) or s.max_states
    seed, repair = (s.seed if seed is None else seed), (s.repair if repair is None else repair)
    model, start_bb, compile_s = _set_up(scene, backend, exact, world, progress)
    clock = PlanClock(time_limit_s, t_entry + compile_s) if wall_limit else None
    checker = ConfigurationChecker(model)
    max_states = max_states or states_for(model.backend.name, time_limit_s)

    def result(status: str, message: str, work: PlanWork, **found: Any) -> PlanResult:
        return PlanResult(planner=planner, backend=model.backend.name, scene=scene.name,
                          target_mm=scene.target.center, goal_tolerance_mm=scene.target.tolerance_mm,
                          base_pose=scene.base_pose, status=status, seed=seed, time_limit_s=time_limit_s,
                          max_states=max_states, start=start_bb,
                          work=replace(work, clock=clock_record(clock, time_limit_s, model.backend.name)),
                          message=_guard_note(message, found.get("cut_short", False), clock, max_states),
                          **{"solved": False, "path": np.zeros((0, len(scene.start))), **found})

    if not checker.is_valid(scene.start):  # under the planning backend: cached for the search
        # valid for the exact model (checked above), not for the planning backend + its margin
        return result("INVALID_START", _start_invalid_message(model, s.margin_mm),
                      PlanWork(model.margin_mm, model.margin_source, compile_s, copy(checker.counters)))
    outcome = search(checker, planner=planner, time_limit_s=time_limit_s, max_states=max_states,
                     seed=seed, progress=progress, goal_hints=goal_hints,
                     wall_s=None if clock is None else clock.search_left())
    work = PlanWork(model.margin_mm, model.margin_source, compile_s, copy(checker.counters), outcome.record)
    searched = {"planning_time_s": outcome.time_s, "kinematics_calls": checker.counters.kinematics_calls,
                "cut_short": outcome.budget.cut_short}
    if outcome.path_q is None:
        why = _why_not(checker, outcome, seed, clock, progress) if explain else None
        told = "" if why is None else why.summary()
        return result(outcome.status, f"{outcome.message}. {told}" if told else outcome.message, work,
                      failure=why, **searched)
    vp, path_q, work, searched = _confirm(model, checker, outcome, work, searched, seed=seed,
                                          time_limit_s=time_limit_s, repair=repair, clock=clock,
                                          clearances=clearances, progress=progress)
    return result(outcome.status, _verdict(vp.report, repair), work,
                  **{**searched, "solved": vp.report.ok, "path": path_q, "dense": vp})


def _set_up(scene: Scene, backend: str | Backend | None, exact: Backend | None, world: CollisionWorld | None,
            progress: Progress) -> tuple[PlanningModel, Backbone, float]:
    """What a plan does before its clock starts: the planning model, its kernels compiled
    (`compile_kernels`) and the start checked (`check_start`). Returns the model, the start's exact
    backbone and the seconds the set-up took."""
    progress("compile")  # loading a backend compiles its kernels too
    t0 = time.perf_counter()
    scene.robot.calibration.refuse(scene.robot.name, "plan")
    model = PlanningModel.build(scene, resolve_backend(backend, scene.robot), exact, world)
    start_bb = compile_kernels(model, progress)
    progress("start")  # the collision world: its distance grid on first use
    check_start(model, start_bb)  # the start under the exact model, solved once
    return model, start_bb, time.perf_counter() - t0


def _start_invalid_message(model: PlanningModel, margin_mm: float) -> str:
    """Why a start valid under the exact model is not under the planning backend with its margin."""
    return (f"the start configuration collides under the {model.backend.name} backend with its planning "
            f"margin ({model.margin_source['source']}) but not under the exact model with {margin_mm:g} mm")


def _why_not(checker: ConfigurationChecker, outcome: SearchOutcome, seed: int, clock: PlanClock | None,
             progress: Progress) -> FailureAnalysis | None:
    """What blocked a search that found no path (`explain_failure`), within what is left of the
    clock; None when the search kept nothing to examine."""
    if outcome.sampler is None:
        return None
    progress("explain")
    return explain_failure(checker, outcome.sampler, seed=seed,
                           deadline=None if clock is None else time.perf_counter() + clock.left())


def _confirm(model: PlanningModel, checker: ConfigurationChecker, outcome: SearchOutcome, work: PlanWork,
             searched: dict, *, seed: int, time_limit_s: float, repair: bool, clock: PlanClock | None,
             clearances: bool, progress: Progress) -> tuple[ValidatedPath, np.ndarray, PlanWork, dict]:
    """The found path under the exact model: its goal corrected (`exact_goal`), validated, repaired
    where it fails (with ``repair``), its clearances measured (with ``clearances``); returns the
    validated path, its joints (K, 2N), the work record and ``searched`` with the time and calls of
    these steps added."""
    t_goal = time.perf_counter()
    path_q = model.space.unwrap(exact_goal(outcome.path_q, checker))
    goal = ExactGoal(len(path_q) > len(outcome.path_q), time.perf_counter() - t_goal)
    progress("validate")
    vp = validate_planned_path(model, path_q)
    work = replace(work, exact_goal=goal, validation_time_s=vp.report.time_s)
    searched = {**searched, "planning_time_s": searched["planning_time_s"] + goal.time_s}
    if not vp.report.ok and repair:
        vp, path_q, fixed = _repair(model, vp, path_q, seed, time_limit_s, progress, outcome.goals, clock)
        work = replace(work, repair=fixed)
        searched.update(planning_time_s=searched["planning_time_s"] + fixed.time_s,
                        kinematics_calls=searched["kinematics_calls"] + fixed.kinematics_calls,
                        cut_short=searched["cut_short"] or fixed.cut_short)
    if clearances:
        progress("clearance")
        vp = measure_clearance(model, vp)
    return vp, path_q, work, searched
