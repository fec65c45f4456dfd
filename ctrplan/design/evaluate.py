"""Evaluate one design: is it buildable and snap-free, and which targets does it provably reach?

A design counts only what is proven. It is **feasible** when

1. the robot loader accepts its robot file (plausibility limits, nesting, pre-curvature strain);
2. its largest pre-curvature strain is within the task's ``max_strain``;
3. its joint domain (the base robot's: the actuator strokes) is physically possible for its tube
   lengths in every corner (tube order, no tube reaching past an inner one);
4. with ``snap_free`` its whole domain is snap-free by the stability sweep of `ctrplan stability`
   (same settings; a certificate, keyed by the robot's fingerprint, is reused or written);
5. a collision-free, stable start exists: the scene's start, or else the nearest (in the planning
   metric) of the scene's start translations and the fully retracted ones with every tube turned by
   multiples of 1/8 turn -- a new tube set needs its own way in.

A target is **reached** only when a cheap screen finds a collision-free goal configuration by inverse
kinematics with the exact model (none within `SCREEN_BATCHES` batches: not reachable, no planning)
and then `ctrplan.planning.plan`
with the exact Cosserat backend finds a path from the start that its exact validation confirms
(collision-free, stable, tip in the target, approach direction respected). Planning seeds come from
the study seed, the design's fingerprint and the target's name, and every search is budgeted in work
(``plan_states`` of the task: states the exact model evaluates; `ctrplan.planning.budget`): the same
design gives the same record on any executor and under any load, only the times differ -- unless a
search's wall-clock guard fired, which the record names (``cut_short``).

The record is a `ctrplan.design.record.DesignRecord` (see `evaluate`).
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass, field, replace

import numpy as np

from ctrplan.base.errors import InputError
from ctrplan.collision.world import CollisionWorld
from ctrplan.design.record import DesignRecord, DesignTimings, Infeasible, StabilityVerdict, TargetRecord
from ctrplan.design.space import Parameters, max_strain, robot_dict, total_length_mm
from ctrplan.design.task import DesignTask, NamedTarget, load_task
from ctrplan.kinematics import EXACT_MODEL, make_backend
from ctrplan.kinematics.stability import certify, is_certified
from ctrplan.model.robot import Robot, robot_from_dict
from ctrplan.scene.objects import Scene

#: Goal-sampling batches of the reachability screen (each of 3 x the scene's goal_samples IK seeds);
#: it gives up after SCREEN_GIVE_UP of them when no IK solution got the tip into the target at all.
SCREEN_BATCHES = 4
SCREEN_GIVE_UP = 2


@dataclass(frozen=True)
class DesignJob:
    """One evaluation for `ctrplan.base.parallel`: the task file, the design's parameters (``{}``: the
    base design) and the study seed."""

    task_file: str
    parameters: Parameters = field(default_factory=dict)
    seed: int = 0


class DesignContext:
    """What the evaluations in one process share: the tasks loaded by file, each task's collision
    world (its meshes and broadphase grid built once) and the stability verdicts found so far, by
    robot fingerprint. A worker builds one (`ctrplan.base.parallel.open_pool` with
    ``context=DesignContext``) and hands it to every `evaluate_job`; a fresh one shares nothing."""

    def __init__(self) -> None:
        self.tasks: dict[str, DesignTask] = {}
        self.worlds: dict[str, CollisionWorld] = {}
        self.verdicts: dict[str, StabilityVerdict] = {}

    def task(self, task_file: str) -> DesignTask:
        """The task in ``task_file``, loaded on first use."""
        if task_file not in self.tasks:
            self.tasks[task_file] = load_task(task_file)
        return self.tasks[task_file]

    def world(self, task: DesignTask) -> CollisionWorld:
        """The collision world of the task's scene, built on first use."""
        key = str(task.path)
        if key not in self.worlds:
            self.worlds[key] = CollisionWorld.from_scene(task.scene)
        return self.worlds[key]


def evaluate_job(context: DesignContext, job: DesignJob) -> DesignRecord:
    """`evaluate` a `DesignJob` with the worker's ``context`` (the task is loaded once per worker)."""
    from ompl import util as ou

    # a target a design cannot reach is a result (recorded with its stage), not an error to print
    # over the progress bar ("Unable to sample any valid states for goal tree")
    ou.setLogLevel(ou.LOG_NONE)
    return evaluate(context.task(job.task_file), job.parameters, job.seed, context=context)


def target_seed(seed: int, fingerprint: str, target: str) -> int:
    """The planning seed of one design and target (OMPL and goal sampling), from the study seed."""
    digest = hashlib.sha256(f"{seed}:{fingerprint}:{target}".encode()).digest()
    return int.from_bytes(digest[:4], "little") % (2**31 - 1)


def evaluate(task: DesignTask, parameters: Parameters, seed: int = 0, *,
             context: DesignContext | None = None) -> DesignRecord:
    """The record of one design (`DesignRecord`); ``context``: what earlier evaluations in this
    worker built (none: a fresh `DesignContext`).

    The feasibility conditions are checked in order; the first that fails is recorded (``infeasible``:
    ``robot``, ``max_strain``, ``snap_free``, ``start``) with what was learnt up to it. A feasible
    design gets a record per target (`TargetRecord`: reached, stage, message, goals, seed, planning
    time, kinematics calls, states, cut short, clearance, path -- the joints (K, 2N) of the validated
    path of a reached target), the stage times (s) and its total time.
    """
    t0 = time.perf_counter()
    context = context or DesignContext()
    data = robot_dict(task, parameters)
    strain = max_strain(data)
    known: dict = {"parameters": dict(parameters), "max_strain": strain,
                   "total_length_mm": total_length_mm(data), "robot": data}
    timings: dict[str, float] = {}

    def record(infeasible: Infeasible | None = None, **found) -> DesignRecord:
        return DesignRecord(feasible=infeasible is None, infeasible=infeasible, **known, **found,
                            timings=DesignTimings(**timings), time_s=time.perf_counter() - t0)

    try:
        robot = robot_from_dict(data, "design")
    except InputError as exc:
        return record(Infeasible("robot", str(exc).removeprefix("design: ")))
    known["fingerprint"] = robot.fingerprint
    if strain > task.max_strain:
        return record(Infeasible("max_strain", f"pre-curvature strain {100 * strain:.2f} % above the limit "
                                               f"{100 * task.max_strain:.2f} %"))
    if task.snap_free:
        t = time.perf_counter()
        verdict = known["stability"] = stability_verdict(robot, context)
        timings["stability_s"] = time.perf_counter() - t
        if not verdict.snap_free:
            return record(Infeasible("snap_free", f"the joint domain is not snap-free "
                                                  f"({verdict.example_reason} at q = "
                                                  f"{np.round(verdict.example_q, 3).tolist()})"))
    from ctrplan.planning.scene_check import valid_start

    t = time.perf_counter()
    scene, checker = _design_scene(task, robot, context)
    start = valid_start(scene, checker)
    timings["start_s"] = time.perf_counter() - t
    if start is None:
        return record(Infeasible("start", "no collision-free stable start configuration"))
    targets = _reach(task, replace(scene, start=start), checker, seed, timings)
    return record(start=start.tolist(), targets=targets)


def stability_verdict(robot: Robot, context: DesignContext) -> StabilityVerdict:
    """Whether the robot's domain is snap-free: a certificate if one exists (shipped or made here),
    else the sweep of `ctrplan stability` with its default settings, stopped at the first flagged
    sweep (a snap-free verdict is stored as a certificate); remembered in ``context`` by
    fingerprint."""
    verdicts = context.verdicts
    fp = robot.fingerprint
    if fp not in verdicts:
        if is_certified(robot):
            verdicts[fp] = StabilityVerdict(True, "certificate")
        else:
            report, _ = certify(robot, stop_at_first=True)
            verdicts[fp] = StabilityVerdict(report.snap_free, "sweep", report.checked, report.example_q,
                                            report.example_reason)
    return verdicts[fp]


def _design_scene(task: DesignTask, robot: Robot, context: DesignContext):
    """The task's scene with the design's robot, and a configuration checker with the exact model
    (testing stability per state unless the robot is certified), on the task's collision world of
    ``context``."""
    from ctrplan.planning import ConfigurationChecker, PlanningModel

    scene = replace(task.scene, robot=robot)
    return scene, ConfigurationChecker(PlanningModel.of(scene, world=context.world(task)))


def _reach(task: DesignTask, scene: Scene, checker, seed: int, timings: dict[str, float]
           ) -> tuple[TargetRecord, ...]:
    """Screen every target, then plan to those with goal configurations (with the exact model, which
    is its own exact companion); the stage times go into ``timings``."""
    from ctrplan.planning import GoalSampler, plan

    robot = scene.robot
    exact = make_backend(EXACT_MODEL, robot)
    screen_s = plan_s = 0.0
    out = []
    for target in task.targets:
        plan_seed = target_seed(seed, robot.fingerprint, target.name)
        t = time.perf_counter()
        sampler = GoalSampler(checker, target.region, np.random.default_rng(plan_seed),
                              seeds_per_batch=max(4, 3 * scene.settings.goal_samples), start=scene.start)
        for k in range(1, SCREEN_BATCHES + 1):
            if sampler.sample_batch() or (k >= SCREEN_GIVE_UP and sampler.stats.ik_reached == 0):
                break
        screen_s += time.perf_counter() - t
        if not sampler.goals:
            st = sampler.stats
            out.append(TargetRecord(target.name, seed=plan_seed, message=(
                f"no collision-free goal configuration ({st.ik_reached} of {st.seeds} IK solutions reached "
                f"the target, closest {st.closest_mm:.2f} mm)")))
            continue
        t = time.perf_counter()
        result = plan(_target_scene(scene, target), exact, world=checker.world,
                      time_limit_s=task.plan_time_s, max_states=task.plan_states, seed=plan_seed,
                      goal_hints=np.stack(sampler.goals), wall_limit=False,  # work decides a trial
                      explain=False)  # a failed target is a trial's outcome, not a question
        plan_s += time.perf_counter() - t
        solved = bool(result.solved)
        out.append(TargetRecord(
            target.name, reached=solved, stage="plan", message=result.message, goals=len(sampler.goals),
            seed=plan_seed, planning_time_s=result.planning_time_s,
            kinematics_calls=result.kinematics_calls, states=result.states, cut_short=result.cut_short,
            min_clearance_mm=float(result.validated.min_clearance_mm) if solved else None,
            path=np.asarray(result.path).tolist() if solved else None))
    timings.update(screen_s=screen_s, plan_s=plan_s)
    return tuple(out)


def _target_scene(scene: Scene, target: NamedTarget) -> Scene:
    """The design's scene aimed at one target."""
    return replace(scene, target=target.region, name=f"{scene.name}:{target.name}")
