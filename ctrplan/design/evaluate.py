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

The record is a JSON-ready dict (see `evaluate`).
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ctrplan.base.errors import InputError
from ctrplan.collision.world import CollisionWorld
from ctrplan.design.space import Parameters, build_robot, max_strain, robot_dict, total_length_mm
from ctrplan.design.task import DesignTask, NamedTarget, load_task
from ctrplan.kinematics import CosseratBackend
from ctrplan.kinematics.stability import certify, is_certified
from ctrplan.model.robot import Robot
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
        self.verdicts: dict[str, dict] = {}

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


def evaluate_job(context: DesignContext, job: DesignJob) -> dict:
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
             context: DesignContext | None = None) -> dict:
    """The record of one design; ``context``: what earlier evaluations in this worker built (none:
    a fresh `DesignContext`).

    Keys: ``parameters``; ``feasible`` and, when not, ``infeasible`` ``{constraint, message}``
    (constraint one of ``robot``, ``max_strain``, ``domain``, ``snap_free``, ``start``);
    ``max_strain`` (fraction), ``total_length_mm``, ``robot`` (the robot file as a dict),
    ``fingerprint``, ``stability`` ``{snap_free, source (certificate | sweep), checked, example_q,
    example_reason}`` (with ``snap_free`` constraints), ``start`` (joints, mm and rad);
    ``targets``: per target ``{name, reached, stage (screen | plan), message, goals, seed,
    planning_time_s, kinematics_calls, states, cut_short, min_clearance_mm, path}`` (path: joints
    (K, 2N) of the validated path, reached targets only; ``states``: the work its plan used;
    ``cut_short``: a wall-clock guard stopped its plan); ``reached`` (names); ``cut_short`` (names of
    the targets whose verdict a guard decided: empty unless the machine was far slower than the
    reference); ``min_clearance_mm`` (smallest over the reached targets' paths, None if none);
    ``time_s`` and ``timings`` (s).
    """
    t0 = time.perf_counter()
    data = robot_dict(task, parameters)
    record: dict[str, Any] = {
        "parameters": dict(parameters), "feasible": False, "infeasible": None,
        "max_strain": max_strain(data), "total_length_mm": total_length_mm(data), "robot": data,
        "fingerprint": None, "stability": None, "start": None, "targets": [], "reached": [],
        "cut_short": [], "min_clearance_mm": None, "time_s": 0.0, "timings": {},
    }
    design = _feasible(task, record, context or DesignContext())
    if design is not None:
        _reach(task, *design, record, seed)
    record["time_s"] = time.perf_counter() - t0
    return record


def _refuse(record: dict, constraint: str, message: str) -> None:
    record["infeasible"] = {"constraint": constraint, "message": message}


def _feasible(task: DesignTask, record: dict, context: DesignContext):
    """Check the feasibility conditions in order, filling ``record``; the design's scene (with its
    start) and exact configuration checker, or None after recording the first condition that
    fails."""
    try:
        robot = build_robot(record["robot"], "design")
    except InputError as exc:
        return _refuse(record, "robot", str(exc).removeprefix("design: "))
    record["fingerprint"] = robot.fingerprint
    if record["max_strain"] > task.max_strain:
        return _refuse(record, "max_strain", f"pre-curvature strain {100 * record['max_strain']:.2f} % "
                                             f"above the limit {100 * task.max_strain:.2f} %")
    if task.snap_free:
        t = time.perf_counter()
        verdict = record["stability"] = stability_verdict(robot, context)
        record["timings"]["stability_s"] = time.perf_counter() - t
        if not verdict["snap_free"]:
            return _refuse(record, "snap_free", f"the joint domain is not snap-free "
                                                f"({verdict['example_reason']} at q = "
                                                f"{np.round(verdict['example_q'], 3).tolist()})")
    from ctrplan.planning.scene_check import valid_start

    t = time.perf_counter()
    scene, checker = _design_scene(task, robot, context)
    start = valid_start(scene, checker)
    record["timings"]["start_s"] = time.perf_counter() - t
    if start is None:
        return _refuse(record, "start", "no collision-free stable start configuration")
    record["start"] = start.tolist()
    record["feasible"] = True
    return replace(scene, start=start), checker


def stability_verdict(robot: Robot, context: DesignContext) -> dict:
    """Whether the robot's domain is snap-free: a certificate if one exists (shipped or made here),
    else the sweep of `ctrplan stability` with its default settings, stopped at the first flagged
    sweep (a snap-free verdict is stored as a certificate); remembered in ``context`` by
    fingerprint."""
    verdicts = context.verdicts
    fp = robot.fingerprint
    if fp not in verdicts:
        if is_certified(robot):
            verdicts[fp] = {"snap_free": True, "source": "certificate", "checked": None,
                            "example_q": None, "example_reason": None}
        else:
            report, _ = certify(robot, stop_at_first=True)
            verdicts[fp] = {"snap_free": report.snap_free, "source": "sweep", "checked": report.checked,
                            "example_q": report.example_q, "example_reason": report.example_reason}
    return dict(verdicts[fp])


def _design_scene(task: DesignTask, robot: Robot, context: DesignContext):
    """The task's scene with the design's robot, and a configuration checker with the exact model
    (testing stability per state unless the robot is certified), on the task's collision world of
    ``context``."""
    from ctrplan.planning import ConfigurationChecker, PlanningModel

    scene = replace(task.scene, robot=robot)
    return scene, ConfigurationChecker(PlanningModel.of(scene, world=context.world(task)))


def _reach(task: DesignTask, scene: Scene, checker, record: dict, seed: int) -> None:
    """Screen every target, then plan to those with goal configurations; fill ``record``."""
    from ctrplan.planning import GoalSampler, plan

    robot = scene.robot
    exact = CosseratBackend(robot)
    screen_s = plan_s = 0.0
    for target in task.targets:
        out: dict[str, Any] = {"name": target.name, "reached": False, "stage": "screen", "message": "",
                               "goals": 0, "seed": target_seed(seed, robot.fingerprint, target.name),
                               "planning_time_s": None, "kinematics_calls": None, "states": None,
                               "cut_short": False, "min_clearance_mm": None, "path": None}
        record["targets"].append(out)
        t = time.perf_counter()
        sampler = GoalSampler(checker, target.region, np.random.default_rng(out["seed"]),
                              seeds_per_batch=max(4, 3 * scene.settings.goal_samples), start=scene.start)
        for k in range(1, SCREEN_BATCHES + 1):
            if sampler.sample_batch() or (k >= SCREEN_GIVE_UP and sampler.stats.ik_reached == 0):
                break
        screen_s += time.perf_counter() - t
        out["goals"] = len(sampler.goals)
        if not sampler.goals:
            st = sampler.stats
            out["message"] = (f"no collision-free goal configuration ({st.ik_reached} of {st.seeds} IK "
                              f"solutions reached the target, closest {st.closest_mm:.2f} mm)")
            continue
        t = time.perf_counter()
        result = plan(_target_scene(scene, target), exact, exact=exact, world=checker.world,
                      time_limit_s=task.plan_time_s, max_states=task.plan_states, seed=out["seed"],
                      goal_hints=np.stack(sampler.goals), wall_limit=False)  # work decides a trial
        plan_s += time.perf_counter() - t
        out.update(stage="plan", message=result.message, reached=bool(result.solved),
                   planning_time_s=result.planning_time_s, kinematics_calls=result.kinematics_calls,
                   states=result.details["budget"]["states"], cut_short=result.cut_short)
        if result.solved:
            out["min_clearance_mm"] = float(result.validated.min_clearance_mm)
            out["path"] = np.asarray(result.path).tolist()
    reached = [t for t in record["targets"] if t["reached"]]
    record["reached"] = [t["name"] for t in reached]
    record["cut_short"] = [t["name"] for t in record["targets"] if t["cut_short"]]
    if reached:
        record["min_clearance_mm"] = min(t["min_clearance_mm"] for t in reached)
    record["timings"].update(screen_s=screen_s, plan_s=plan_s)


def _target_scene(scene: Scene, target: NamedTarget) -> Scene:
    """The design's scene aimed at one target."""
    return replace(scene, target=target.region, name=f"{scene.name}:{target.name}")
