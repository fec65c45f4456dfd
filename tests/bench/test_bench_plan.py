"""`ctrplan bench plan`: records, summary, OMPL log + Planner Arena database, and the executors
(in-process, local worker processes, a local Ray instance) giving the same content for the same seeds."""

from __future__ import annotations

import json
import sqlite3

import numpy as np
import pytest

from ctrplan.base.parallel import available_cores, run_jobs
from ctrplan.bench import planning as planning_bench
from ctrplan.bench.ompl_log import STATUS, planner_label, status_index
from ctrplan.cli.app import main
from tests.paths import SCENES

OPEN = str((SCENES / "open.yaml").resolve())


@pytest.fixture(scope="module")
def bench_run(tmp_path_factory):
    """One small benchmark through the CLI: two backends, two planners, two seeds."""
    out = tmp_path_factory.mktemp("bench") / "out"
    rc = main(["bench", "plan", OPEN, "--backend", "pinn,cosserat", "--planner", "rrtconnect,kpiece",
               "--runs", "2", "--time-limit", "5", "--out", str(out), "--json"])
    assert rc == 0
    return out, json.loads((out / "results.json").read_text())


def test_specs_pair_seeds_across_backends_and_planners():
    specs = planning_bench.make_specs([(OPEN, 5.0)], ["pinn", "cosserat"], ["rrt", "rrtconnect"], 3, 7)
    assert len(specs) == 12
    for backend in ("pinn", "cosserat"):
        for planner in ("rrt", "rrtconnect"):
            assert sorted(s.seed for s in specs if (s.backend, s.planner) == (backend, planner)) == [7, 8, 9]
    assert {(s.backend, s.planner) for s in specs[:4]} == {(b, p) for b in ("pinn", "cosserat")
                                                           for p in ("rrt", "rrtconnect")}


def test_records_and_summary(bench_run):
    _, doc = bench_run
    runs, summary = doc["runs"], doc["summary"]
    assert len(runs) == 8 and len(summary) == 4
    for r in runs:
        split = r["kinematics_s"] + r["collision_s"] + r["planner_s"]
        assert split == pytest.approx(r["planning_time_s"], abs=1e-3)
        assert r["kinematics_s"] > 0 and r["collision_s"] > 0 and r["kinematics_calls"] > 0
        assert r["checks_per_s"] == pytest.approx(r["kinematics_calls"] / r["planning_time_s"], rel=1e-3)
        # the open scene is mostly empty space: the broadphase decides most checks without FCL
        assert r["narrow_checks"] < 0.5 * r["collision_checks"]
        if r["solved"]:  # solved means: the exact model confirms the whole path
            assert r["found"] and r["exact_collision_free"] and r["exact_tip_in_target"]
            assert r["path_length_mm"] > 0 and r["tip_travel_mm"] > 0 and r["min_clearance_mm"] > 0
        if r["backend"] == "cosserat" and r["found"]:
            assert r["max_position_error_mm"] == 0.0
    assert sum(r["narrow_checks"] for r in runs) > 0 and sum(r["fcl_tests"] for r in runs) > 0
    for s in summary:
        mine = [r for r in runs if (r["backend"], r["planner"]) == (s["backend"], s["planner"])]
        assert s["runs"] == 2 and s["solved"] == sum(r["solved"] for r in mine)
        assert s["planning_time_s"]["median"] == pytest.approx(
            np.median([r["planning_time_s"] for r in mine]), abs=1e-3)
        assert sum(s["time_share"].values()) == pytest.approx(1.0, abs=0.01)
    assert doc["machine"]["cpu"] and doc["settings"]["runs"] == 2


def test_ompl_log_and_planner_arena_database(bench_run):
    out, doc = bench_run
    log = (out / "open.log").read_text()
    assert log.startswith("OMPL version") and "Experiment open" in log
    db = sqlite3.connect(out / "benchmark.db")
    names = {n for (n,) in db.execute("SELECT name FROM plannerConfigs")}
    assert names == {planner_label(p, b) for b in ("pinn", "cosserat") for p in ("rrtconnect", "kpiece")}
    assert "RRTConnect [pinn]" in names
    rows = db.execute("SELECT plannerConfigs.name, runs.seed, runs.solved, runs.time, runs.kinematics_calls "
                      "FROM runs JOIN plannerConfigs ON runs.plannerid = plannerConfigs.id").fetchall()
    assert len(rows) == len(doc["runs"])
    by_key = {(planner_label(r["planner"], r["backend"]), r["seed"]): r for r in doc["runs"]}
    for name, seed, solved, time_s, calls in rows:
        r = by_key[(name, seed)]
        assert bool(solved) == r["solved"] and time_s == pytest.approx(r["planning_time_s"])
        assert calls == r["kinematics_calls"]
    assert db.execute("SELECT COUNT(*) FROM bestPlannerConfigs").fetchone()[0] == 4
    assert db.execute("SELECT name FROM experiments").fetchone()[0] == "open"
    for name in ("planning_times.png", "time_split.png"):
        assert (out / name).stat().st_size > 10_000


def test_status_enum():
    assert STATUS[status_index("Exact solution")] == "Exact solution"
    assert STATUS[status_index("INVALID_GOAL")] == "Invalid goal"
    assert status_index("something else") == 0


def test_executors_give_the_same_content():
    """Same seeds -> same runs in this process (on one core and on two), over two local worker
    processes and on local Ray."""
    specs = planning_bench.make_specs([(OPEN, 5.0)], ["pinn"], ["rrtconnect"], 2, 3)
    here = run_jobs(planning_bench.run_one, specs)
    again = run_jobs(planning_bench.run_one, specs, threads=min(2, len(available_cores())))
    pool = run_jobs(planning_bench.run_one, specs, workers=2)
    ray = run_jobs(planning_bench.run_one, specs, ray_address="local", workers=2)

    def content(records):
        return [{k: r[k] for k in planning_bench.CONTENT_FIELDS} for r in records]

    assert all(r["solved"] for r in here)
    assert content(here) == content(again) == content(pool) == content(ray)
    assert content(here)[0] != content(here)[1]  # different seeds, different runs


@pytest.mark.parametrize("args, needle", [
    (["--planner", "prm"], "--planner: unknown planner 'prm'"),
    (["--backend", "magic"], "--backend: unknown backend 'magic'"),
    (["--runs", "0"], "--runs: need at least 1 run"),
    (["--time-limit", "-1"], "--time-limit: must be a positive duration"),
    (["--workers", "64"], "--workers: 64 workers but only"),
    (["--threads", "0"], "--threads: need at least 1"),
    (["--threads", "2", "--workers", "2"], "--threads: 2 cores per run needs one local worker"),
    (["--threads", "100000"], "--threads: 100000 cores per run but only"),
])
def test_bad_options(args, needle, tmp_path, capsys):
    out = tmp_path / "o"
    rc = main(["bench", "plan", OPEN, "--runs", "1", "--out", str(out), *args])
    err = capsys.readouterr().err
    assert rc == 2 and needle in err and len(err.strip().splitlines()) == 1
    assert not out.exists() or not any(out.iterdir())


def test_missing_scene(tmp_path, capsys):
    rc = main(["bench", "plan", str(tmp_path / "nope.yaml"), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert rc == 2 and "nope.yaml" in err and len(err.strip().splitlines()) == 1
