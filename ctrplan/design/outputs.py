"""What a design study leaves behind, built from the study's records alone (so a finished or
interrupted study can rewrite them at any time):

- ``best_robot.yaml``: the best design as a robot file every command accepts, its domain certified
  snap-free here (the certificate `ctrplan stability --robot best_robot.yaml` finds);
- ``paths/<target>/scene.yaml`` for every target (the task's scene with the best robot, its start
  and that target: ``ctrplan plan`` it); for each reached target also ``path.json``, ``plan.png``,
  ``plan.html`` and ``obstacles.ply`` as ``ctrplan plan --out`` writes them, from the path the trial
  found, validated again here with the exact model;
- ``designs.csv``: every finished trial, its parameters, objectives and reached targets;
- ``pareto.png``, ``report.html`` (`ctrplan.viz.design_report`) and ``design.json`` (the JSON summary).

`collect` computes what the outputs show (`StudyOutcome`: the ranking, the best design's paths
validated again and measured, the backbones at their ends) and writes the files that are data (robot,
scenes, ``designs.csv``); the command then has `ctrplan.viz` render the figures and pages, and
`write_summary` writes ``design.json`` last.

The best design is the feasible one first in the task's objectives taken in order (most targets
reached, then the second objective, ...) -- never below the base design: when no trial beats the base
design (evaluated the same way as every trial), the base design is the best, marked as such
(``best.is_base_design`` in ``design.json``, a comment in ``best_robot.yaml``, the report and the
terminal say so). The Pareto front holds the feasible trials no other feasible trial dominates.
"""

from __future__ import annotations

import csv
import io
import json
import os
import shutil
import statistics
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import optuna

from ctrplan.base.dataio import atomic_write
from ctrplan.base.machine import machine_info
from ctrplan.base.yamlio import dump_yaml, load_yaml
from ctrplan.design.objectives import OBJECTIVES
from ctrplan.design.ranking import Design, best_design, designs_of, nominal_of, pareto_front, ranked
from ctrplan.design.record import DesignRecord, TargetRecord
from ctrplan.design.study import finished_trials
from ctrplan.design.task import DesignTask
from ctrplan.kinematics import EXACT_MODEL, make_backend
from ctrplan.kinematics.stability import certify, is_certified
from ctrplan.model.robot import robot_from_dict
from ctrplan.planning.execution import TrajectoryTable, trajectory_table
from ctrplan.planning.result import PlanResult
from ctrplan.scene.objects import Scene

#: Backbone points of the best design's backbones drawn at the end of each path (report overview).
OVERVIEW_POINTS = 60


@dataclass(frozen=True)
class BestPath:
    """A reached target of the best design: its folder, scene, scene file, the trial's path
    validated again with the exact model, clearances measured, and its timed trajectory (what
    ``ctrplan plan --out`` writes)."""

    folder: Path
    scene: Scene
    scene_file: Path
    result: PlanResult
    trajectory: TrajectoryTable


@dataclass(frozen=True)
class StudyOutcome:
    """What the outputs of a study show: the task, its finished designs, the base design, the best
    design and the Pareto front, the best design's reached paths (`BestPath`, by target), its
    backbones at the end of each (target name, (P, 3) scene frame, mm), and the JSON summary."""

    task: DesignTask
    designs: list[Design]
    nominal: Design | None
    best: Design | None
    front: list[Design]
    paths: dict[str, BestPath]
    backbones: list[tuple[str, np.ndarray]]
    doc: dict[str, Any]


def targets_of(record: DesignRecord) -> dict[str, dict]:
    """Per target: reached, the path's clearance (mm) and planning time (s), and what happened."""
    keys = ("reached", "stage", "min_clearance_mm", "planning_time_s", "states", "cut_short", "message")
    return {t.name: {k: getattr(t, k) for k in keys} for t in record.targets}


def objectives_of(record: DesignRecord, task: DesignTask) -> dict[str, float | int]:
    """The record's objectives by name (targets reached as a count)."""
    values = {o.name: o.value(record) for o in task.objectives}
    return {**values, "targets_reached": len(record.reached)}


def collect(task: DesignTask, study: optuna.Study, out: Path, *, storage: str, seed: int,
            time_s: float, executor: str, cut_short: str | None = None) -> StudyOutcome:
    """What the outputs in ``out`` show (see the module docstring), with the data files written.
    ``cut_short``: what the run's wall-clock limit stopped (None: it did not fire)."""
    designs = designs_of(study)
    nominal = nominal_of(study)
    best = best_design(ranked(designs, task), nominal, task)
    front = pareto_front(designs, task)
    if (out / "paths").exists():  # a previous best's folders would mislead
        shutil.rmtree(out / "paths")
    paths = write_best(task, best, out, study.study_name) if best is not None else {}
    write_designs_csv(task, designs, out / "designs.csv")
    times = [d.record.time_s for d in designs]
    trials = finished_trials(study)
    span = None if not trials else (max(t.datetime_complete for t in trials)
                                    - min(t.datetime_start for t in trials)).total_seconds()
    doc = {
        "study": study.study_name, "storage": storage, "task": str(task.path), "seed": seed,
        "trials": len(designs), "feasible": sum(d.record.feasible for d in designs),
        "targets": [t.name for t in task.targets], "objectives": [o.label for o in task.objectives],
        "best": None if best is None else {
            "trial": best.trial, "is_base_design": best.trial is None,
            "robot_file": str(out / "best_robot.yaml"),
            "reached": best.record.reached, "objectives": objectives_of(best.record, task),
            "parameters": best.record.parameters, "robot": best.record.robot,
            "targets": targets_of(best.record),
            "paths": {name: str(p.folder / "path.json") for name, p in paths.items()}},
        "pareto": [{"trial": d.trial, "parameters": d.record.parameters,
                    "objectives": objectives_of(d.record, task), "reached": d.record.reached}
                   for d in front],
        "nominal": None if nominal is None else {
            "reached": nominal.record.reached, "feasible": nominal.record.feasible,
            "objectives": objectives_of(nominal.record, task), "robot": nominal.record.robot,
            "targets": targets_of(nominal.record), "cut_short": nominal.record.cut_short},
        "cut_short": cut_short,
        "guarded_trials": sum(bool(d.record.cut_short)
                              for d in designs + ([nominal] if nominal else [])),
        "time_s": round(time_s, 2),
        "study_wall_s": None if span is None else round(span, 2),
        "trial_time_s": None if not times else {
            "median": round(statistics.median(times), 2), "mean": round(statistics.fmean(times), 2),
            "max": round(max(times), 2), "total": round(sum(times), 2)},
        "executor": executor,
        "machine": machine_info(),
        "outputs": {name: str(out / name) for name in
                    ("design.json", "designs.csv", "pareto.png", "report.html", "best_robot.yaml", "paths")
                    if best is not None or name not in ("best_robot.yaml", "paths")},
    }
    return StudyOutcome(task, designs, nominal, best, front, paths, best_backbones(task, best), doc)


def write_summary(outcome: StudyOutcome, out: Path) -> None:
    """``design.json``: the JSON summary, written last (it names every other output)."""
    with atomic_write(out / "design.json") as fh:
        fh.write(json.dumps(outcome.doc, indent=2) + "\n")


def best_backbones(task: DesignTask, best: Design | None) -> list[tuple[str, np.ndarray]]:
    """The best design's exact backbone (`OVERVIEW_POINTS` points, scene frame, mm) at the end of its
    path to each reached target, by target name."""
    reached = [] if best is None else [t for t in best.record.targets if t.reached]
    if not reached:
        return []
    robot = robot_from_dict(best.record.robot, "best design")
    bb = make_backend(EXACT_MODEL, robot).forward(np.array([t.path[-1] for t in reached]),
                                                  points=OVERVIEW_POINTS, check=False)
    return list(zip([t.name for t in reached], task.scene.to_scene(bb.positions_mm), strict=True))


def write_best(task: DesignTask, best: Design, out: Path, study: str) -> dict[str, BestPath]:
    """``best_robot.yaml`` (certified here when the task asks for snap-free designs) and the folder
    of every target with its scene file; returns the reached targets' paths, validated again."""
    from ctrplan.planning.model import exact_backend

    record = best.record
    robot = robot_from_dict(record.robot, str(out / "best_robot.yaml"))
    certificate = "not requested (constraints.snap_free: false): planning tests stability per state"
    if task.snap_free:
        if not is_certified(robot):
            report, _ = certify(robot)
            if not report.snap_free:
                raise RuntimeError(f"trial {best.trial}: the stability sweep here disagrees with the trial's "
                                   f"snap-free verdict (fingerprint {robot.fingerprint})")
        certificate = (f"snap-free over the whole joint domain (ctrplan stability; fingerprint "
                       f"{robot.fingerprint})")
    which = (f"the base design: no trial of study {study} beats it in the task's objectives"
             if best.trial is None else f"study {study}, trial {best.trial}")
    header = (f"# The best design of `ctrplan design {task.path.name}` ({which}):\n"
              f"# reaches {len(record.reached)} of {len(task.targets)} targets "
              f"({', '.join(record.reached) or 'none'}).\n# Certified: {certificate}.\n")
    with atomic_write(out / "best_robot.yaml") as fh:
        fh.write(header + dump_yaml(record.robot))
    start = np.asarray(record.start)
    exact = exact_backend(robot)
    paths = {}
    for target, result in zip(task.targets, record.targets, strict=True):
        folder = out / "paths" / target.name
        folder.mkdir(parents=True, exist_ok=True)
        scene_file = write_target_scene(task, target, start, out / "best_robot.yaml", folder / "scene.yaml")
        if result.reached:
            scene, plan = validate_target_path(task, exact, scene_file, result)
            paths[target.name] = BestPath(folder, scene, scene_file, plan, trajectory_table(scene, plan.path))
    return paths


def write_target_scene(task: DesignTask, target, start: np.ndarray, robot_file: Path, path: Path) -> Path:
    """The task's scene file with ``robot_file``, ``start`` and ``target``: what ``ctrplan plan``
    needs to plan that target with the design (mesh and robot paths made relative to ``path``)."""
    from ctrplan.scene.loader import load_scene

    source = task.scene.path
    data = dict(load_yaml(source).data)
    here = path.parent.resolve()

    def moved(rel: str) -> str:
        p = Path(rel) if Path(rel).is_absolute() else source.parent / rel
        return os.path.relpath(p.resolve(), here)

    data["name"] = f"{task.name}_{target.name}"
    data["description"] = (f"{target.name} of design task {task.path.name} with its best design. "
                           f"{target.reason}").strip()
    data["robot"] = moved(str(robot_file.resolve()))
    data["obstacles"] = [{**o, "mesh": moved(o["mesh"])} if "mesh" in o else o
                         for o in data.get("obstacles") or []]
    data["target"] = target.region.to_yaml()
    data["start"] = [float(v) for v in start]
    with atomic_write(path) as fh:
        fh.write(dump_yaml(data))
    load_scene(path)  # every command must accept it
    return path


def validate_target_path(task: DesignTask, exact, scene_file: Path, result: TargetRecord
                         ) -> tuple[Scene, PlanResult]:
    """The scene of a reached target and the trial's path to it, validated again with the exact model
    (clearances measured), as a `PlanResult` of the outputs."""
    from ctrplan.planning import validate_path
    from ctrplan.planning.budget import states_for
    from ctrplan.scene.loader import load_scene

    scene = load_scene(scene_file)
    path_q = np.asarray(result.path)
    vp = validate_path(scene, path_q, exact, exact=exact, measure=True)
    if not vp.report.ok:
        raise RuntimeError(f"{result.name}: the exact validation here disagrees with the trial's "
                           f"(a path the trial confirmed fails now)")
    return scene, PlanResult(True, scene.settings.planner, exact.name, scene.name, scene.target.center,
                             scene.target.tolerance_mm, scene.base_pose, path_q, status="Exact solution",
                             message="solved", seed=result.seed, time_limit_s=task.plan_time_s,
                             max_states=task.plan_states or states_for(exact.name, task.plan_time_s),
                             planning_time_s=result.planning_time_s,
                             kinematics_calls=result.kinematics_calls, dense=vp)


def csv_rows(task: DesignTask, designs: list[Design]) -> tuple[list[str], list[list[Any]]]:
    """Header and rows of ``designs.csv``: trial, feasibility, objectives, parameters, the reached
    targets (names, then one 0/1 column per target), times (s), the robot's fingerprint, why it is
    infeasible, and the targets whose search a wall-clock guard cut short (empty unless the machine
    was far slower than the reference: only then does a row depend on the machine)."""
    params = sorted({k for d in designs for k in d.record.parameters})
    names = [t.name for t in task.targets]
    header = (["trial", "feasible", "infeasible", *OBJECTIVES, *params, "reached",
               *[f"reached_{n}" for n in names], "time_s",
               "stability_s", "plan_s", "fingerprint", "message", "cut_short"])
    rows = []
    for d in designs:
        r = d.record
        why = r.infeasible
        rows.append([d.trial, int(r.feasible), "" if why is None else why.constraint,
                     *[c.column(r) for c in OBJECTIVES.values()],
                     *[r.parameters.get(p, "") for p in params], ";".join(r.reached),
                     *[int(n in r.reached) for n in names], round(r.time_s, 3),
                     round(r.timings.stability_s or 0.0, 3), round(r.timings.plan_s or 0.0, 3),
                     r.fingerprint or "", "" if why is None else why.message, ";".join(r.cut_short)])
    return header, rows


def write_designs_csv(task: DesignTask, designs: list[Design], path: Path) -> None:
    header, rows = csv_rows(task, designs)
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(header)
    writer.writerows([["" if v is None else v for v in row] for row in rows])
    with atomic_write(path) as fh:
        fh.write(buf.getvalue())
