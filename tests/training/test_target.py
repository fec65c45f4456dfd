"""The accuracy target and the time to reach it (issue 40): the verdict on a tip-error tail, when a
training curve first met the target, the extrapolation of a curve that did not (closed forms of
power laws), and where the tail lives (next to a jump of the exact model, or not)."""

from __future__ import annotations

import itertools
import json
import math

import numpy as np
import pytest
import yaml

from ctrplan.kinematics import CosseratBackend
from ctrplan.kinematics.pinn import PinnBackend
from ctrplan.model.robot import Robot
from ctrplan.training.evaluate import (
    JUMP_MM,
    Comparison,
    accuracy_verdict,
    compare,
    exact_tip_steps,
    jumps_within,
    worst_configurations,
)
from ctrplan.training.recipes import get_recipe
from ctrplan.training.target import ACCURACY_TARGET, CurvePoint, Monitor, meets, summary, time_to_target
from ctrplan.training.trainer import train
from tests.paths import REPO


def tip(p99_9: float, peak: float) -> dict:
    return {"mean": p99_9 / 5, "p99": p99_9 / 2, "p99_9": p99_9, "max": peak}


def test_the_target_is_issue_40s_and_needs_both_statistics():
    assert ACCURACY_TARGET == {"tube1_tip_p99_9_mm": 0.5, "tube1_tip_max_mm": 1.0}
    assert meets(tip(0.5, 1.0)) and meets(tip(0.1, 0.2))
    assert not meets(tip(0.51, 0.9)) and not meets(tip(0.4, 1.01))


def test_a_cut_evaluation_is_not_the_verdict():
    """The hjhdog1 run of issue 40: a time limit cut the card's evaluation to 100 configurations, which
    all met the target (max 0.27 mm), while the monitor's last measurement of the same network, on its
    5,000, hit the robot's jump band (max 12.6 mm). The verdict is the larger set's."""
    cut = {"tip_error_mm": {"tube1": tip(0.27, 0.27)}, "configurations": 100}
    v = accuracy_verdict(cut, tip(0.45, 12.6), 5000)
    assert v["meets_target"] is False and v["accuracy_target"]["judged_on"] == "monitor"
    assert v["accuracy_target"]["configurations"] == 5000
    assert v["accuracy_target"]["measured"] == {"tube1_tip_p99_9_mm": 0.45, "tube1_tip_max_mm": 12.6}
    whole = {"tip_error_mm": {"tube1": tip(0.3, 0.6)}, "configurations": 5000}
    v = accuracy_verdict(whole, tip(0.45, 12.6), 5000)     # as many: the card's own evaluation
    assert v["meets_target"] is True and v["accuracy_target"]["judged_on"] == "evaluation"
    assert accuracy_verdict(cut)["accuracy_target"]["judged_on"] == "evaluation"  # no monitor


def test_time_to_target_is_the_first_point_of_the_curve_that_meets_it():
    curve = [CurvePoint(60.0 * k, 100 * k, tip(2.0 / k, 4.0 / k)) for k in range(1, 11)]
    out = time_to_target(curve, tip(0.2, 0.4))
    assert out["reached_at_s"] == 240.0            # k = 4: p99.9 0.5, max 1.0
    assert "extrapolation" not in out and len(out["curve"]) == 10


def test_a_power_law_curve_is_extrapolated_to_where_both_statistics_meet_the_target():
    """p99.9 = 8 t^-0.5 reaches 0.5 at t = 256 s; max = 40 t^-0.5 reaches 1 at t = 1600 s: the later
    one is the answer, from the last half of a curve that ends at 100 s."""
    curve = [CurvePoint(float(t), t, tip(8 * t ** -0.5, 40 * t ** -0.5)) for t in range(10, 101, 10)]
    out = time_to_target(curve, curve[-1].tip_mm)
    assert out["reached_at_s"] is None
    ex = out["extrapolation"]
    assert ex["extrapolated_s"] == pytest.approx(1600.0, rel=1e-6)
    assert ex["exponents"] == {"p99_9": -0.5, "max": -0.5}
    text = summary(out, curve[-1].tip_mm, 100.0)
    assert text.startswith("misses the accuracy target") and "EXTRAPOLATED" in text and "27 min" in text
    assert "likely more" in text   # the schedule's decay steepens the fitted half (docs/benchmarks.md)
    assert "in 1.7 min: got" in text  # the 100 s the run took


def test_a_flat_tail_has_no_extrapolation():
    curve = [CurvePoint(float(t), t, tip(0.3 * t ** -0.5, 8.0)) for t in range(10, 101, 10)]
    ex = time_to_target(curve, curve[-1].tip_mm)["extrapolation"]
    assert ex["extrapolated_s"] is None and ex["exponents"]["max"] == 0.0
    assert "did not fall" in summary(time_to_target(curve, curve[-1].tip_mm), curve[-1].tip_mm, 100.0)


def test_worst_configurations_find_a_jump_of_the_exact_model(tmp_path):
    """three_tube_fixed with tube 1 retracted to 100 mm snaps with tubes 1 and 2 nearly opposed
    (its robot file says so). A 'surrogate' that is the exact model 0.02 rad off in alpha2: the
    configuration next to the jump is the worst and is flagged; the smooth ones are not."""
    data = yaml.safe_load((REPO / "examples" / "robots" / "three_tube_fixed.yaml").read_text())
    data["domain"]["beta2_minus_beta1_mm"] = [0.0, 100.0]
    (tmp_path / "r.yaml").write_text(yaml.safe_dump(data))
    robot = Robot.load(tmp_path / "r.yaml")
    q = np.array([[-177.9563, -90.0, 0.0, 2.6579, -0.1476, -0.4519],   # 0.01 rad below a jump
                  [-120.0, -90.0, 0.0, 0.3, 1.2, -0.4],
                  [-100.0, -90.0, 0.0, -1.0, 0.5, 2.0]])
    exact = CosseratBackend(robot)
    off = q + np.array([0, 0, 0, 0, 0.02, 0])
    cmp = Comparison(predicted=exact.forward(off, 10), exact=exact.forward(q, 10))
    w = worst_configurations(cmp, robot, k=3)
    first = w["configurations"][0]
    assert first["q"] == q[0].tolist() and first["tip_error_mm"] > JUMP_MM
    assert first["exact_tip_step_mm"] > 10.0
    assert w["next_to_jump"] == 1 and w["checked"] == 3
    assert all(c["exact_tip_step_mm"] < 1.5 for c in w["configurations"][1:])
    assert math.isclose(w["probe_step"]["rotation_rad"], 0.01)


def test_a_steep_smooth_place_is_not_a_jump():
    """design_1 is snap-free by the stability sweep; here a 0.03-rad step moves its exact tip 3.6 mm
    (121 mm/rad, smooth: 0.12 mm across 0.001 rad). The single step would call it a jump; bisecting
    it does not."""
    robot = Robot.load(REPO / "docs" / "training" / "design_robots" / "design_1.yaml")
    q = np.array([[-26.7585, -13.1626, -8.6932, -1.4499, -1.2164, 2.091]])
    tips = CosseratBackend(robot).forward(q, 2).tips_mm[:, 0]
    assert exact_tip_steps(robot, q, tips, {"rotation_rad": 0.03, "translation_mm": 0.3})[0] > JUMP_MM
    assert not jumps_within(robot, q, tips, 0.03)[0]


def test_a_short_run_on_a_small_robot_meets_a_proportionally_loose_target(tmp_path):
    """The two-tube example robot from scratch, 300 steps on a 4,000-configuration pool (about 1/150 of
    the steps of a 20-minute run on two cores): tube-1 tip p99.9 <= 2 mm and max <= 4 mm on 1,000 unseen
    configurations (4x the 20-minute target; measured 0.91 / 0.98 mm), and the card's curve says when
    the 500 monitor configurations first met that."""
    robot = Robot.load(REPO / "examples" / "robots" / "two_tube.yaml")
    recipe = get_recipe("fast", steps=300, dense_configs=4000, dense_batch=1024, collocation=256, boundary=64,
                        mining={"every": 100, "candidates": 2000, "keep": 200})
    result = train(robot, recipe, tmp_path / "two", seed=0, monitor=Monitor(robot, n=500),
                   evaluate=lambda net: compare(PinnBackend(robot, net), robot, n=1000, points=2).metrics())
    tip1 = result.card["metrics"]["tip_error_mm"]["tube1"]
    assert tip1["p99_9"] <= 2.0 and tip1["max"] <= 4.0, tip1
    curve = result.card["time_to_target"]["curve"]
    assert curve[-1]["step"] == 300 and all(a["time_s"] < b["time_s"] for a, b in itertools.pairwise(curve))
    written = json.loads((tmp_path / "two.json").read_text())
    assert result.net.frame == 1 and written["network"]["frame_tube"] == 2  # tube 2 moves the tip most
