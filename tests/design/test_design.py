"""`ctrplan design` end to end on small robots with known answers: the optimiser finds the curvature
of a one-tube arc (closed form), infeasible designs (over-strained, snapping) are never best, a study
continues from its storage, and a trial's evaluation is the same in this process, on local workers and
on a local Ray instance."""

from __future__ import annotations

import csv
import json
import math
import re
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import optuna
import pytest
from scipy.optimize import brentq

from ctrplan.base.parallel import run_jobs
from ctrplan.cli.app import main
from ctrplan.design.evaluate import DesignContext, DesignJob, evaluate, evaluate_job
from ctrplan.design.record import DesignRecord
from ctrplan.design.task import load_task
from ctrplan.kinematics import CosseratBackend
from ctrplan.kinematics.cosserat import SolverSettings
from ctrplan.kinematics.stability import critical_length_mm, is_certified
from ctrplan.model.robot import Robot
from ctrplan.planning import BoxSpace

# One tube: 50 mm straight, 40 mm curved, translation beta in [-10, 0], any rotation. In front of the
# plate it is a straight segment and a circular arc of curvature kappa: the tip lies at the distance
# r(kappa) = (1 - cos(kappa L)) / kappa from the axis (any rotation), at depth beta + 50 + sin(kappa L)
# / kappa. A target at distance r* from the axis is reachable exactly when |r(kappa) - r*| <= its
# tolerance (when the depth fits the stroke, which it does here).
STRAIGHT, CURVED = 50.0, 40.0
KAPPA_ARC, BETA_ARC, PHI_ARC = 25.0, -5.0, 0.3  # 1/m, mm, rad: where the target lies
TOL = 2.0


def radial_mm(kappa_per_m: float) -> float:
    k = kappa_per_m * 1e-3
    return (1.0 - math.cos(k * CURVED)) / k


def arc_target() -> list[float]:
    k = KAPPA_ARC * 1e-3
    r = radial_mm(KAPPA_ARC)
    return [r * math.sin(PHI_ARC), -r * math.cos(PHI_ARC), BETA_ARC + STRAIGHT + math.sin(k * CURVED) / k]


def reach_band(tol: float) -> tuple[float, float]:
    """Curvatures (1/m) whose arc passes within ``tol`` of the target (r is increasing here)."""
    r_star = radial_mm(KAPPA_ARC)
    return (brentq(lambda k: radial_mm(k) - (r_star - tol), 1.0, KAPPA_ARC),
            brentq(lambda k: radial_mm(k) - (r_star + tol), KAPPA_ARC, 60.0))


def write_one_tube_task(folder: Path, *, kappa=(10.0, 40.0), base_kappa=12.0, max_strain=0.08,
                        objectives=("targets_reached", "-max_strain"), trials=12) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "robot.yaml").write_text(
        "name: one_tube\ntubes:\n  - {inner_diameter_mm: 0.4, outer_diameter_mm: 0.6, "
        f"straight_length_mm: {STRAIGHT}, curved_length_mm: {CURVED}, curvature_1_per_m: {base_kappa}}}\n"
        "domain: {beta1_mm: [-10.0, 0.0], alpha_rad: [-3.141592653589793, 3.141592653589793]}\n")
    (folder / "scene.yaml").write_text(
        "name: one_tube_open\nrobot: robot.yaml\nbase_pose: {position: [0.0, 0.0, 0.0]}\n"
        "obstacles:\n  - {name: post, sphere: {center: [40.0, 40.0, 30.0], radius: 5.0}}\n"
        "target: {point: [0.0, 0.0, 80.0], tolerance_mm: 2.0}\nstart: [-10.0, 0.0]\n"
        "planner: {time_limit_s: 5.0, points: 20}\n")
    (folder / "task.yaml").write_text(
        "scene: scene.yaml\ntargets:\n"
        f"  - {{name: arc, point: {arc_target()}, tolerance_mm: {TOL}, reason: on the arc}}\n"
        "  - {name: behind, point: [0.0, 0.0, -30.0], tolerance_mm: 1.0, reason: behind the plate}\n"
        f"vary:\n  1: {{curvature_1_per_m: [{kappa[0]}, {kappa[1]}]}}\n"
        f"constraints: {{max_strain: {max_strain}, snap_free: true}}\n"
        f"objectives: [{', '.join(objectives)}]\nbudget: {{trials: {trials}, plan_time_s: 3.0}}\n")
    return folder / "task.yaml"


@pytest.fixture(scope="module", autouse=True)
def own_cache(tmp_path_factory):
    """Stability certificates and distance grids in a cache of this module's own (workers inherit it)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("XDG_CACHE_HOME", str(tmp_path_factory.mktemp("cache")))
        yield


def run_design(args: list[str], capsys) -> dict:
    rc = main(["design", *args, "--json"])
    out = capsys.readouterr().out
    assert rc == 0
    return json.loads(out)


def kappa_of(entry: dict) -> float:
    return entry["parameters"]["tube1.curvature_1_per_m"]


def read_csv(path: Path) -> list[dict]:
    with path.open() as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def arc_study(tmp_path_factory):
    """Twelve trials of the one-tube task (base design 12 1/m: far from the arc)."""
    folder = tmp_path_factory.mktemp("arc")
    task = write_one_tube_task(folder)
    out = folder / "out"
    rc = main(["design", str(task), "--out", str(out), "--json"])
    assert rc == 0
    return task, out, json.loads((out / "design.json").read_text())


def test_optimiser_finds_the_arc_curvature(arc_study):
    _, _, doc = arc_study
    lo, hi = reach_band(TOL)
    assert lo < KAPPA_ARC < hi and hi - lo < 0.25 * (40.0 - 10.0)  # a narrow band of the range
    assert doc["nominal"]["reached"] == []  # 12 1/m: r = 9.4 mm, the target is at 18.4 mm
    best = doc["best"]
    assert best["reached"] == ["arc"]
    assert lo <= kappa_of(best) <= hi
    # -max_strain second: of the reaching designs the least curved one (strain = kappa * OD / 2)
    rows = read_csv(arc_study[1] / "designs.csv")
    reaching = [float(r["tube1.curvature_1_per_m"]) for r in rows if r["reached_arc"] == "1"]
    assert kappa_of(best) == pytest.approx(min(reaching))
    assert best["objectives"]["max_strain"] == pytest.approx(kappa_of(best) * 1e-3 * 0.3)


def test_reach_is_the_closed_form(arc_study):
    """Reached only within the band of the closed form; always well inside it; never behind the plate."""
    rows = read_csv(arc_study[1] / "designs.csv")
    assert len(rows) == 12 and all(r["feasible"] == "1" for r in rows)
    r_star = radial_mm(KAPPA_ARC)
    for r in rows:
        miss = abs(radial_mm(float(r["tube1.curvature_1_per_m"])) - r_star)
        if r["reached_arc"] == "1":
            assert miss <= TOL + 1e-6, r
        if miss <= 0.5 * TOL:
            assert r["reached_arc"] == "1", r
        assert r["reached_behind"] == "0"
    assert any(r["reached_arc"] == "0" for r in rows)


def test_outputs_are_usable(arc_study, capsys):
    task, out, doc = arc_study
    robot = Robot.load(out / "best_robot.yaml")
    assert robot.tubes[0].curvature_per_mm * 1e3 == pytest.approx(kappa_of(doc["best"]))
    assert is_certified(robot)
    rc = main(["stability", "--robot", str(out / "best_robot.yaml"), "--out", str(out / "st"), "--json"])
    assert rc == 0 and json.loads(capsys.readouterr().out)["snap_free"] is True
    # the reached target's path: its exact tip in the target; its scene plans with the exact model
    path = json.loads((out / "paths" / "arc" / "path.json").read_text())
    assert path["solved"] and path["validated"]["collision_free"]
    assert np.linalg.norm(np.array(path["validated"]["tip_mm"]) - arc_target()) <= TOL
    for name in ("plan.png", "plan.html", "obstacles.ply", "scene.yaml"):
        assert (out / "paths" / "arc" / name).stat().st_size > 0
    assert not (out / "paths" / "behind" / "path.json").exists()
    rc = main(["plan", str(out / "paths" / "arc" / "scene.yaml"), "--backend", "cosserat", "--json"])
    assert rc == 0 and json.loads(capsys.readouterr().out)["solved"]
    # designs.csv and the JSON agree; the study in the storage holds the same trials
    rows = read_csv(out / "designs.csv")
    study = optuna.load_study(study_name=doc["study"], storage=doc["storage"])
    assert [t.number for t in study.trials] == [int(r["trial"]) for r in rows]
    for t, r in zip(study.trials, rows, strict=True):
        assert t.values[0] == float(r["targets_reached"])
        assert t.params["tube1.curvature_1_per_m"] == float(r["tube1.curvature_1_per_m"])
    assert doc["trials"] == 12 and doc["feasible"] == 12 and doc["pareto"][0]["trial"] == doc["best"]["trial"]
    assert (out / "pareto.png").stat().st_size > 10_000
    report = (out / "report.html").read_text()
    assert "data:image/png;base64," in report
    assert not re.search(r"""(src|href)=["']?(https?:)?//""", report)  # nothing to fetch: offline


def test_one_worker_study_is_reproducible(arc_study, tmp_path):
    """The same task and seed on one worker: the same twelve designs (ten random, then TPE's) with the
    same outcomes."""
    task, out, _ = arc_study
    assert main(["design", str(task), "--out", str(tmp_path / "again")]) == 0
    drop = ("time_s", "stability_s", "plan_s")
    first, again = (read_csv(folder / "designs.csv") for folder in (out, tmp_path / "again"))
    assert [{k: v for k, v in r.items() if k not in drop} for r in again] == \
        [{k: v for k, v in r.items() if k not in drop} for r in first]


def test_over_strained_designs_are_never_best(tmp_path, capsys):
    """Maximising strain second would pick the most curved reaching design; above the strain limit
    (kappa > 25 1/m: 0.75 % for OD 0.6 mm) designs are infeasible -- not planned, never best."""
    task = write_one_tube_task(tmp_path, kappa=(20.0, 30.0), max_strain=0.0075,
                               objectives=("targets_reached", "max_strain"), trials=10)
    doc = run_design([str(task), "--out", str(tmp_path / "out")], capsys)
    rows = read_csv(tmp_path / "out" / "designs.csv")
    lo, hi = reach_band(TOL)
    over = [r for r in rows if float(r["max_strain"]) > 0.0075]
    assert over and all(r["feasible"] == "0" and r["infeasible"] == "max_strain" and r["reached"] == ""
                        for r in over)
    assert any(lo + 0.5 < float(r["tube1.curvature_1_per_m"]) < hi for r in over)  # would have reached
    best = doc["best"]
    assert best["reached"] == ["arc"] and kappa_of(best) <= 25.0 + 1e-9
    assert best["objectives"]["max_strain"] <= 0.0075
    # an over-strained design reaches nothing but is more strained than any feasible one: were it
    # ranked, maximising strain would put it on the Pareto front
    feasible = {r["trial"] for r in rows if r["feasible"] == "1"}
    assert doc["pareto"] and all(str(d["trial"]) in feasible for d in doc["pareto"])


def write_pair_task(folder: Path, target: tuple[float, ...] = (0.0, 0.0, 40.0), tolerance: float = 15.0,
                    constraints: str = "") -> tuple[Path, float]:
    """Two fully overlapping curved tubes (50 mm, tube 2 at 20 1/m), only rotations; tube 1's
    curvature varies across the closed-form snapping threshold. Returns the task and that threshold
    (1/m)."""
    folder.mkdir(parents=True, exist_ok=True)
    tube = ("{{inner_diameter_mm: {}, outer_diameter_mm: {}, straight_length_mm: 0.0, "
            "curved_length_mm: 50.0, curvature_1_per_m: 20.0}}")
    (folder / "robot.yaml").write_text(
        f"name: pair\ntubes:\n  - {tube.format(0.4, 0.6)}\n  - {tube.format(0.7, 0.9)}\n"
        "domain: {beta2_mm: [0.0, 0.0], beta2_minus_beta1_mm: [0.0, 0.0], "
        "alpha_rad: [-3.141592653589793, 3.141592653589793]}\n")
    (folder / "scene.yaml").write_text(
        "robot: robot.yaml\nbase_pose: {position: [0.0, 0.0, 0.0]}\nobstacles: []\n"
        "target: {point: [0.0, 0.0, 40.0], tolerance_mm: 15.0}\nstart: [0.0, 0.0, 0.0, 0.0]\n"
        "planner: {time_limit_s: 2.0, points: 20}\n")
    (folder / "task.yaml").write_text(
        "scene: scene.yaml\ntargets:\n"
        f"  - {{name: ahead, point: {list(target)}, tolerance_mm: {tolerance}}}\n"
        f"vary:\n  1: {{curvature_1_per_m: [5.0, 65.0]}}\n{constraints}"
        "objectives: [targets_reached, max_strain]\nbudget: {trials: 10, plan_time_s: 2.0}\n")
    robot = Robot.load(folder / "robot.yaml")
    # L sqrt((1 + nu) k1 k2) = pi / 2 at L = 50 mm: k1 = k2 (L_crit(k1 = k2) / L)^2
    return folder / "task.yaml", 20.0 * (critical_length_mm(robot) / 50.0) ** 2


def test_snapping_designs_are_never_best(tmp_path, capsys):
    task, critical = write_pair_task(tmp_path)
    assert 30.0 < critical < 45.0
    doc = run_design([str(task), "--out", str(tmp_path / "out")], capsys)
    rows = read_csv(tmp_path / "out" / "designs.csv")
    for r in rows:
        k1 = float(r["tube1.curvature_1_per_m"])
        if k1 < 0.8 * critical:
            assert r["feasible"] == "1", r
        if k1 > 1.25 * critical:
            assert r["feasible"] == "0" and r["infeasible"] == "snap_free", r
    best = doc["best"]
    assert best is not None and kappa_of(best) < 1.25 * critical
    most = max(int(r["targets_reached"]) for r in rows if r["feasible"] == "1")
    feasible = [float(r["tube1.curvature_1_per_m"]) for r in rows
                if r["feasible"] == "1" and int(r["targets_reached"]) == most]
    assert kappa_of(best) == pytest.approx(max(feasible))  # the most strained of the feasible ones
    assert any(float(r["tube1.curvature_1_per_m"]) > kappa_of(best) and r["feasible"] == "0" for r in rows)


def test_without_the_snap_free_constraint_paths_stay_stable(tmp_path):
    """``snap_free: false``: a design that snaps somewhere in its domain is not refused, but planning
    tests every state for stability: what it reaches, it reaches through stable equilibria only, and
    a target only unstable configurations reach (tubes opposed) is not reached."""
    _, critical = write_pair_task(tmp_path)
    robot = Robot.load(tmp_path / "robot.yaml")
    robot = robot.with_changes(tubes=(replace(robot.tubes[0], curvature_per_mm=1.5e-3 * critical),
                                      robot.tubes[1]))
    # the target: this design's tip with both tubes bent the same way (a stable equilibrium)
    tip = CosseratBackend(robot).forward(np.array([0.0, 0.0, 0.0, 0.0]), points=2).tip_mm[0]
    task_file, _ = write_pair_task(tmp_path, tuple(float(v) for v in tip), 3.0,
                                   "constraints: {snap_free: false}\n")
    record = evaluate(load_task(task_file), {"tube1.curvature_1_per_m": 1.5 * critical})
    assert record.feasible and record.stability is None and record.reached == ["ahead"]
    assert not is_certified(robot)
    path = np.asarray(record.targets[0].path)
    dense = BoxSpace.for_robot(robot).densify(path, 0.5)
    checking = CosseratBackend(robot, SolverSettings(stability=True))
    bb = checking.forward(dense, points=2, check=False)
    assert bb.converged.all() and bb.stable.all()
    opposed = np.array([0.0, 0.0, 0.0, math.pi])
    assert not checking.forward(opposed, points=2, check=False).stable[0]
    tip = CosseratBackend(robot).forward(opposed, points=2).tip_mm[0]
    task_file, _ = write_pair_task(tmp_path, tuple(float(v) for v in tip), 1.0,
                                   "constraints: {snap_free: false}\n")
    record = evaluate(load_task(task_file), {"tube1.curvature_1_per_m": 1.5 * critical})
    assert record.feasible and record.reached == []
    assert re.match(r"no collision-free goal configuration \([1-9]\d* of", record.targets[0].message)


@pytest.fixture(scope="module")
def two_trials(tmp_path_factory):
    """Two trials of the one-tube task on one worker, in their own SQLite storage."""
    folder = tmp_path_factory.mktemp("two")
    task = write_one_tube_task(folder, trials=2)
    out = folder / "out"
    assert main(["design", str(task), "--out", str(out), "--study", "s"]) == 0
    return task, out


def test_storage_resume_continues_the_study(two_trials, tmp_path, capsys):
    task, first = two_trials
    storage = f"sqlite:///{tmp_path / 'copy.db'}"
    shutil.copy(first / "study.db", tmp_path / "copy.db")
    before = optuna.load_study(study_name="s", storage=storage)
    old = [(t.params, t.values, t.user_attrs["record"]["time_s"]) for t in before.trials]
    nominal_time = before.user_attrs["nominal"]["time_s"]
    doc = run_design([str(task), "--trials", "3", "--storage", storage, "--study", "s",
                      "--out", str(tmp_path / "out")], capsys)
    assert doc["trials"] == 3
    after = optuna.load_study(study_name="s", storage=storage)
    assert [(t.params, t.values, t.user_attrs["record"]["time_s"]) for t in after.trials[:2]] == old
    assert after.user_attrs["nominal"]["time_s"] == nominal_time  # not evaluated again
    assert after.trials[2].params not in [p for p, _, _ in old]  # a new design, not a replay
    # the budget is spent: the same command only rewrites the outputs
    assert run_design([str(task), "--trials", "3", "--storage", storage, "--study", "s",
                       "--out", str(tmp_path / "out")], capsys)["trials"] == 3
    # another seed, or another task, does not continue this study
    other = tmp_path / "other"
    shutil.copytree(task.parent, other, ignore=shutil.ignore_patterns("out"))
    (other / "task.yaml").write_text(task.read_text().replace("[10.0, 40.0]", "[10.0, 41.0]"))
    for task_file, extra, needle in ((task, ["--seed", "7"], "was started with --seed 0"),
                                     (other / "task.yaml", [], "was run for another task")):
        rc = main(["design", str(task_file), "--storage", storage, "--study", "s", "--out",
                   str(tmp_path / "o2"), *extra])
        err = capsys.readouterr().err.strip()
        assert rc == 2 and err.startswith("ctrplan: error: --study: 's'") and needle in err, err
        assert len(err.splitlines()) == 1


def content(record: DesignRecord | dict) -> dict:
    """What a trial's evaluation decides (all but the times), of a record or the study's copy."""
    doc = record.to_json() if isinstance(record, DesignRecord) else record
    keep = ("parameters", "feasible", "infeasible", "max_strain", "total_length_mm", "fingerprint", "start",
            "reached", "min_clearance_mm")
    targets = [{k: v for k, v in t.items() if k != "planning_time_s"} for t in doc["targets"]]
    return {**{k: doc[k] for k in keep}, "targets": targets}


def test_evaluation_is_deterministic_on_every_executor(two_trials, tmp_path):
    task, first = two_trials
    study = optuna.load_study(study_name="s", storage=f"sqlite:///{first / 'study.db'}")
    records = [t.user_attrs["record"] for t in study.trials]
    specs = [DesignJob(str(task.resolve()), r["parameters"], 0) for r in records]
    specs.append(DesignJob(str(task.resolve()), {"tube1.curvature_1_per_m": KAPPA_ARC}, 0))  # reaches
    here = [evaluate(load_task(task), s.parameters, s.seed) for s in specs]
    assert [content(r) for r in here[:2]] == [content(r) for r in records]
    assert here[2].reached == ["arc"] and here[2].targets[1].stage == "screen"
    assert all(DesignRecord.from_json(r.to_json()) == r for r in here)  # the study's copy reads back
    pool = run_jobs(evaluate_job, specs, workers=2, context=DesignContext)
    ray = run_jobs(evaluate_job, specs, ray_address="local", workers=2, context=DesignContext)
    assert [content(r) for r in here] == [content(r) for r in pool] == [content(r) for r in ray]


def test_workers_and_ray_run_the_same_study(two_trials, tmp_path):
    """Two trials at once on local workers and as Ray tasks: the same designs, the same objectives."""
    task, first = two_trials
    expect = read_csv(first / "designs.csv")
    drop = ("time_s", "stability_s", "plan_s")
    for args in (["--workers", "2"], ["--ray", "local", "--workers", "2"]):
        out = tmp_path / args[1]
        assert main(["design", str(task), "--trials", "2", "--out", str(out), *args]) == 0
        rows = read_csv(out / "designs.csv")
        assert [{k: v for k, v in r.items() if k not in drop} for r in rows] == \
            [{k: v for k, v in r.items() if k not in drop} for r in expect]
