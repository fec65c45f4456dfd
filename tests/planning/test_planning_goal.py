"""A target with an approach direction: scene input, goal sampling, exact validation, planning."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from ctrplan.base.errors import InputError
from ctrplan.kinematics import make_backend
from ctrplan.planning import ConfigurationChecker, GoalSampler, plan, validate_path
from ctrplan.planning.goal import tip_tangents
from ctrplan.planning.model import PlanningModel
from ctrplan.scene.loader import load_scene
from tests.paths import SCENES


def test_scene_reads_the_approach_direction(tmp_path):
    sc = load_scene(SCENES / "skullbase_approach.yaml")
    assert np.allclose(sc.target.direction, [0, 0, 1])
    assert math.isclose(sc.target.angle_tolerance_rad, math.radians(20))
    assert sc.target.to_dict()["angle_tolerance_deg"] == pytest.approx(20)
    base = (SCENES / "open.yaml").read_text()
    for extra, msg in (("  direction: [0, 0, 1]\n", "give direction and angle_tolerance_deg together"),
                       ("  direction: [0, 0, 0]\n  angle_tolerance_deg: 10\n", "zero vector"),
                       ("  direction: [0, 0, 1]\n  angle_tolerance_deg: 180\n", "must be < 180")):
        bad = tmp_path / "bad.yaml"
        bad.write_text(base.replace("  tolerance_mm: 3.0\n", "  tolerance_mm: 3.0\n" + extra))
        with pytest.raises(InputError, match=msg) as err:
            load_scene(bad)
        assert "bad.yaml:" in str(err.value) and "target" in str(err.value)


def test_goal_sampling_and_validation_respect_the_direction(open_scene, exact):
    free = GoalSampler(ConfigurationChecker(PlanningModel.of(open_scene, exact)), open_scene.target,
                       np.random.default_rng(0), start=open_scene.start)
    goals = np.stack(free.sample_batch())
    tangents = tip_tangents(open_scene, exact.forward(goals, points=2, check=False))
    # aim at the first goal's approach, 10 deg wide: other goals point elsewhere
    target = replace(open_scene.target, direction=tangents[0], angle_tolerance_rad=math.radians(10))
    off = np.degrees(target.angle_rad(tangents))
    assert off.max() > 10, "the goals all point the same way: the test would prove nothing"
    scene = replace(open_scene, target=target)

    sampler = GoalSampler(ConfigurationChecker(PlanningModel.of(scene, exact)), target,
                          np.random.default_rng(1), start=scene.start)
    for _ in range(4):
        sampler.sample_batch()
    assert sampler.goals and sampler.stats.wrong_direction > 0
    found = exact.forward(np.stack(sampler.goals), points=2, check=False)
    assert np.all(np.degrees(target.angle_rad(tip_tangents(scene, found))) <= 10 + 1e-9)

    wrong = goals[int(np.argmax(off))]
    rep = validate_path(scene, np.stack([scene.start, wrong]), exact, exact=exact).report
    assert scene.target.contains(np.array(rep.tip_mm)) and rep.tip_angle_deg > 10
    assert not rep.tip_in_target and not rep.ok


def test_plan_reaches_the_target_along_the_direction(open_scene, exact):
    goals = GoalSampler(ConfigurationChecker(PlanningModel.of(open_scene, exact)), open_scene.target,
                        np.random.default_rng(0), start=open_scene.start).sample_batch()
    tangent = tip_tangents(open_scene, exact.forward(goals[0], points=2, check=False))[0]
    scene = replace(open_scene, target=replace(open_scene.target, direction=tangent,
                                               angle_tolerance_rad=math.radians(15)))
    res = plan(scene, exact, seed=0, time_limit_s=10.0)
    assert res.solved, res.message
    assert res.validated.tip_angle_deg <= 15
    assert res.to_json()["validated"]["tip_angle_deg"] <= 15


def test_rrtconnect_keeps_asking_for_goals_while_none_is_found(open_scene):
    """While no goal configuration is known, the goal region promises OMPL one more sample than it
    has drawn, so RRTConnect keeps running inverse-kinematics batches instead of waiting out its
    budget after the first empty one (a skullbase_strict run once did: 10 s, unsolved)."""
    from ompl import base as ob
    from ompl import geometric as og

    from ctrplan.kinematics import make_backend
    from ctrplan.planning.search import build_problem

    far = replace(open_scene.target, center=open_scene.target.center + np.array([0.0, 0.0, 500.0]))
    scene = replace(open_scene, target=far)  # out of reach: every batch comes back empty
    problem = build_problem(scene, make_backend("pinn", scene.robot), rng=np.random.default_rng(0))
    planner = og.RRTConnect(problem.si)
    planner.setProblemDefinition(problem.pdef)
    planner.setup()
    # Stop at the third goal batch, or after 60 s (a planner that waits out its budget after the first
    # empty batch only stops there): the verdict depends on the work done, not on the machine's speed.
    planner.solve(ob.plannerOrTerminationCondition(
        ob.PlannerTerminationCondition(lambda: problem.goal.calls >= 3),
        ob.timedPlannerTerminationCondition(60.0)))
    assert not problem.sampler.goals and problem.goal.calls >= 3
    assert problem.sampler.stats.batches == problem.goal.calls  # each draw ran a batch
    assert problem.goal.maxSampleCount() > problem.goal.calls


def test_goal_sampling_starts_from_hints(open_scene, exact):
    """Hints (e.g. the PINN's goals, for an exact repair) are the first batch's only seeds, and goals
    next to them come back from few exact solves; later batches sample as usual."""
    pinn = ConfigurationChecker(PlanningModel.of(open_scene, make_backend("pinn", open_scene.robot)))
    pinn_goals = GoalSampler(pinn, open_scene.target, np.random.default_rng(0),
                             start=open_scene.start).sample_batch()
    assert len(pinn_goals) >= 2
    checker = ConfigurationChecker(PlanningModel.of(open_scene, exact))
    hinted = GoalSampler(checker, open_scene.target, np.random.default_rng(1), start=open_scene.start,
                         hints=np.stack(pinn_goals))
    found = hinted.sample_batch()
    assert hinted.stats.seeds == len(pinn_goals) and len(found) >= 1 and not len(hinted.hints)
    assert checker.check(np.stack(found)).all()
    calls = checker.counters.kinematics_calls
    hinted.sample_batch()  # hints are used once: a usual batch now
    assert hinted.stats.seeds - len(pinn_goals) >= hinted.seeds_per_batch
    plain = GoalSampler(ConfigurationChecker(PlanningModel.of(open_scene, exact)), open_scene.target,
                        np.random.default_rng(1), start=open_scene.start)
    plain.sample_batch()
    assert calls < plain.checker.counters.kinematics_calls  # cheaper than a batch from scratch
