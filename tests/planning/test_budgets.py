"""Search budgets (issue 25): work decides a verdict, wall-clock time only guards it.

A seeded plan gives the same path when the machine is slowed down (every kinematics call made to
sleep); a wall-clock guard that fires says so; a design study whose trials do not beat the base
design returns the base design, marked as such.
"""

from __future__ import annotations

import json
import re
import time

import numpy as np
import pytest

from ctrplan.cli.app import main
from ctrplan.design.ranking import Design, best_design
from ctrplan.design.record import DesignRecord, TargetRecord
from ctrplan.design.task import Objective
from ctrplan.kinematics.base import DEFAULT_POINTS, Backend
from ctrplan.model.robot import Robot
from ctrplan.planning import plan
from ctrplan.planning.budget import GUARD_FACTOR, states_for
from ctrplan.scene.loader import load_scene
from tests.design.test_design import read_csv, write_one_tube_task
from tests.paths import SCENES


class Sleepy(Backend):
    """A backend made slow, as on a loaded machine: every call sleeps ``sleep_s`` first, then asks
    the wrapped backend (same name, so the same default work budget)."""

    def __init__(self, inner: Backend, sleep_s: float):
        super().__init__(inner.robot)
        self.inner = inner
        self.sleep_s = sleep_s
        self.name = inner.name
        self.exact = inner.exact
        self.warm_startable = inner.warm_startable
        self.analytic_tip_jacobian = inner.analytic_tip_jacobian
        self.partial_backbones_cheap = inner.partial_backbones_cheap

    def forward(self, q, points=DEFAULT_POINTS, *, guess=None, check=True):
        time.sleep(self.sleep_s)
        return self.inner.forward(q, points, guess=guess, check=check)

    def body(self, q, points, *, guess=None, check=True):
        time.sleep(self.sleep_s)
        return self.inner.body(q, points, guess=guess, check=check)

    def tip_and_tangent(self, q, *, check=True):
        time.sleep(self.sleep_s)
        return self.inner.tip_and_tangent(q, check=check)

    def tip_jacobian(self, q):
        time.sleep(self.sleep_s)
        return self.inner.tip_jacobian(q)

    @property
    def error_bound(self):
        return self.inner.error_bound


def test_a_seeded_plan_is_the_same_path_on_a_slowed_machine(open_scene, pinn):
    """Given a work budget (what 1 s buys) and no time limit, the slowed run sleeps 2 s in all --
    twice that second (a time-limited plan would stop early) but within the guard -- and finds the
    very same path with the same work."""
    work = states_for("pinn", 1.0)
    fast = plan(open_scene, pinn, seed=7, max_states=work)
    assert fast.solved, fast.message
    calls = fast.work.counters.kinematics_batches + 4  # + compiling and the start check
    slow = plan(open_scene, Sleepy(pinn, 2.0 / calls), seed=7, max_states=work)
    assert slow.solved, slow.message
    assert slow.work.search.budget.elapsed_s > 1.0  # really slowed past the time budget
    assert np.array_equal(slow.path, fast.path)
    assert slow.states == fast.states
    assert slow.max_states == fast.max_states == work
    assert not slow.cut_short and not fast.cut_short
    assert slow.work.clock["mode"] == "guard"


def test_a_time_limit_is_a_time_limit(open_scene, pinn):
    """A time limit on a machine too slow for the work budget: the clock stops the search by
    1.25 x the limit (the validation fits in the rest of 1.5 x), and the result says so and how to
    make it reproducible."""
    res = plan(open_scene, Sleepy(pinn, 0.3), seed=7, time_limit_s=1.0)
    budget, clock = res.work.search.budget, res.work.clock
    assert clock["mode"] == "time limit" and clock["wall_limit_s"] == pytest.approx(1.5)
    assert budget.clock == "time limit" and budget.guard_s <= 1.25
    assert res.cut_short and budget.states < res.max_states
    assert "time limit reached while sampling goal configurations" in res.message
    assert "the time limit of 1 s stopped a search" in res.message
    assert f"--max-states {states_for('pinn', 1.0)} without --time-limit" in res.message


def test_the_wall_clock_guard_fires_and_says_so(open_scene, pinn):
    """A machine far slower than the guard allows: 0.1 s per call, a 0.02 s time budget (guard
    GUARD_FACTOR x 0.02 s: a few calls; the search needs dozens) and a work budget it cannot use up.
    The search stops at the guard and the result says so."""
    res = plan(open_scene, Sleepy(pinn, 0.1), seed=7, time_limit_s=0.02, max_states=10**7)
    budget = res.work.search.budget
    assert budget.guard_s == pytest.approx(GUARD_FACTOR * 0.02)
    assert res.cut_short and budget.cut_short and budget.states < 10**7
    assert budget.elapsed_s >= budget.guard_s
    assert not res.solved and "wall-clock guard" in res.message
    doc = res.to_json()
    assert doc["cut_short"] is True and doc["max_states"] == 10**7


def test_cli_max_states(tmp_path, capsys):
    """--max-states is the work budget in the JSON; a budget the goal sampling alone uses up ends the
    plan (exit 1) with that reason; a bad value is one line, exit 2."""
    scene = str(SCENES / "open.yaml")
    rc = main(["plan", scene, "--backend", "cosserat", "--max-states", "50", "--seed", "1", "--json"])
    doc = json.loads(capsys.readouterr().out)
    assert rc == 1 and doc["max_states"] == 50 and doc["cut_short"] is False
    assert "budget used up" in doc["message"] and doc["details"]["budget"]["states"] >= 50
    rc = main(["plan", scene, "--max-states", "0"])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "--max-states" in err


def _record(reached: list[str], strain: float, feasible: bool = True) -> DesignRecord:
    return DesignRecord({}, feasible, strain, 0.0, {}, targets=tuple(
        TargetRecord(name, reached=True, stage="plan", min_clearance_mm=1.0) for name in reached))


def test_best_design_never_falls_below_the_base_design():
    """Objective order (targets reached, then -max_strain): a trial replaces the base design only
    when it is better; a tie keeps the base design; an infeasible base design is no fallback."""
    objectives = (Objective("targets_reached"), Objective("max_strain", maximize=False))
    base = Design(None, _record(["a", "b"], 0.02))
    fewer = Design(0, _record(["a"], 0.001))
    tie = Design(1, _record(["a", "b"], 0.02))
    straighter = Design(2, _record(["b", "a"], 0.01))

    class Task:
        pass

    task = Task()
    task.objectives = objectives
    assert best_design([fewer], base, task) is base
    assert best_design([tie, fewer], base, task) is base
    assert best_design([straighter, fewer], base, task) is straighter
    assert best_design([], base, task) is base
    assert best_design([fewer], Design(None, _record(["a", "b", "c"], 0.0, feasible=False)), task) is fewer


def test_a_study_that_beats_nothing_returns_the_base_design(tmp_path, capsys, monkeypatch):
    """The base design (25 1/m) reaches the arc target; the trials may only vary the curvature in
    [10, 14] 1/m, whose arcs pass > 5 mm from it (closed form in test_design): no trial beats the
    base design, so the best is the base design, marked as such everywhere."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    task = write_one_tube_task(tmp_path, kappa=(10.0, 14.0), base_kappa=25.0, trials=2)
    out = tmp_path / "out"
    assert main(["design", str(task), "--out", str(out)]) == 0
    terminal = capsys.readouterr().out
    doc = json.loads((out / "design.json").read_text())
    assert doc["nominal"]["reached"] == ["arc"]
    rows = read_csv(out / "designs.csv")
    assert len(rows) == 2 and all(r["reached_arc"] == "0" for r in rows)
    best = doc["best"]
    assert best["is_base_design"] is True and best["trial"] is None and best["reached"] == ["arc"]
    robot_file = out / "best_robot.yaml"
    assert "the base design" in robot_file.read_text().splitlines()[0]
    assert Robot.load(robot_file).tubes[0].curvature_per_mm == pytest.approx(25e-3)
    assert "no trial beats the base design" in " ".join(terminal.split())
    assert "No trial beats the base design" in (out / "report.html").read_text()
    assert (out / "paths" / "arc" / "path.json").is_file()


@pytest.mark.parametrize("value, error", [(500, None), (0, ">= 1"), (2.5, "expected an integer"),
                                          (True, "expected an integer")])
def test_task_and_scene_work_budgets(tmp_path, value, error):
    """``budget.plan_states`` of a task and ``planner.max_states`` of a scene: integers >= 1 (states),
    else one error naming the key and line."""
    from ctrplan.base.errors import InputError
    from ctrplan.design.task import load_task

    task_file = write_one_tube_task(tmp_path)
    text = task_file.read_text().replace("plan_time_s: 3.0}", f"plan_time_s: 3.0, plan_states: {value}}}")
    task_file.write_text(text)
    if error is None:
        assert load_task(task_file).plan_states == 500
    else:
        with pytest.raises(InputError, match=rf"task.yaml:\d+: budget\.plan_states: .*{re.escape(error)}"):
            load_task(task_file)
    scene_file = tmp_path / "scene.yaml"
    scene_file.write_text(scene_file.read_text().replace("points: 20}", f"points: 20, max_states: {value}}}"))
    if error is None:
        assert load_scene(scene_file).settings.max_states == 500
    else:
        with pytest.raises(InputError, match=rf"scene.yaml:\d+: planner\.max_states: .*{re.escape(error)}"):
            load_scene(scene_file)
