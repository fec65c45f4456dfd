"""The surrogate's calibrated error bound: conformal quantile, tail metrics, model card, planner use."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from ctrplan.base.errors import InputError
from ctrplan.kinematics import CosseratBackend
from ctrplan.kinematics.error_bound import region_bounds_mm
from ctrplan.kinematics.model_file import read_card, resolve_model
from ctrplan.kinematics.pinn import ERROR_BOUND_KEY
from ctrplan.model.robot import Robot
from ctrplan.planning.model import RegionMarginBackend, planning_backend
from ctrplan.scene.loader import load_scene
from ctrplan.training.evaluate import (
    CALIBRATION_SEED,
    COVERAGES,
    EVAL_SEED,
    REGIONS,
    Comparison,
    compare,
    conformal_quantile,
    error_bound,
)
from tests.paths import SCENES


def test_conformal_quantile_is_the_right_order_statistic_and_covers():
    scores = np.arange(1.0, 100.0)  # 99 scores
    assert conformal_quantile(scores[::-1], 0.9) == 90.0  # ceil(100 * 0.9) = 90th smallest
    assert conformal_quantile(scores, 0.995) == np.inf  # 99 scores cannot promise 99.5 %
    rng = np.random.default_rng(0)
    q = conformal_quantile(rng.lognormal(size=2000), 0.99)
    assert 0.985 <= np.mean(rng.lognormal(size=100_000) <= q) <= 0.995


def test_error_bound_holds_on_fresh_configurations(pinn):
    robot = pinn.robot
    bound = error_bound(compare(pinn, robot, n=400, points=40, seed=CALIBRATION_SEED), (0.5, 0.95))
    assert [r["s_fraction"] for r in bound["regions"]] == [list(r) for r in REGIONS]
    fresh = compare(pinn, robot, n=400, points=40, seed=EVAL_SEED)
    d = np.linalg.norm(fresh.predicted.positions_mm - fresh.exact.positions_mm, axis=-1)
    frac = fresh.exact.s_mm / fresh.exact.s_mm[:, -1:]
    for r in bound["regions"]:
        lo, hi = r["s_fraction"]
        score = np.where((frac >= lo) & (frac <= hi), d, 0).max(axis=1)
        assert 0.42 <= np.mean(score <= r["bound_mm"][0]) <= 0.58
        assert np.mean(score <= r["bound_mm"][1]) >= 0.92
    tip = region_bounds_mm(bound, 0.95)
    assert tip[0] < tip[-1]  # the error grows towards the tip
    with pytest.raises(InputError, match="surrogate_coverage: .* at coverages 0.5, 0.95 only"):
        region_bounds_mm(bound, 0.9)


def quaternion_about_z(angle_rad: np.ndarray) -> np.ndarray:
    """Unit quaternions (B, 4), scalar first, of rotations by ``angle_rad`` (B,) about z."""
    return np.stack([np.cos(angle_rad / 2), 0 * angle_rad, 0 * angle_rad, np.sin(angle_rad / 2)], axis=-1)


def quaternion_product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a b of scalar-first quaternions (..., 4)."""
    w1, x1, y1, z1 = np.moveaxis(a, -1, 0)
    w2, x2, y2, z2 = np.moveaxis(b, -1, 0)
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2], axis=-1)


def linear_percentile(sorted_x: np.ndarray, pct: float) -> float:
    """The pct-th percentile by linear interpolation between order statistics (written out here)."""
    h = (len(sorted_x) - 1) * pct / 100.0
    lo = int(np.floor(h))
    return float(sorted_x[lo] + (h - lo) * (sorted_x[min(lo + 1, len(sorted_x) - 1)] - sorted_x[lo]))


def test_metrics_report_the_tail():
    """A surrogate with known errors: the exact backbones of 200 configurations, configuration k
    shifted by d_k = 2 k / 199 mm along x and turned by 10 k / 199 deg about z. Every tip error of
    configuration k is d_k and every orientation error is that angle, so the tail statistics are
    those of two evenly spaced sequences: computed here, not by the code under test."""
    robot = Robot.nominal()
    q = robot.sample_joints(200, rng=3)
    exact = CosseratBackend(robot).forward(q, 20)
    assert exact.converged.all()
    k = np.arange(200)
    shift, turn = 2.0 * k / 199, np.radians(10.0 * k / 199)
    state = exact.state.copy()
    i = 2 * robot.n_tubes + 2
    state[..., i] += shift[:, None]
    state[..., -4:] = quaternion_product(quaternion_about_z(turn)[:, None, :], state[..., -4:])
    tips = exact.tips_mm.copy()
    tips[..., 0] += shift[:, None]
    m = Comparison(predicted=replace(exact, state=state, tips_mm=tips), exact=exact).metrics()
    for name, seq in (("tip_error_mm", shift), ("orientation_error_deg", np.degrees(turn))):
        tails = [m[name][t] for t in ("tube1", "tube2", "tube3")] if name == "tip_error_mm" else [m[name]]
        for t in tails:
            assert t["mean"] == pytest.approx(seq.mean(), abs=1e-6)
            assert t["p99"] == pytest.approx(linear_percentile(seq, 99.0), abs=1e-6)
            assert t["max"] == pytest.approx(seq.max(), abs=1e-6)
        if name == "tip_error_mm":
            assert tails[0]["p99_9"] == pytest.approx(linear_percentile(seq, 99.9), abs=1e-6)
    np.testing.assert_allclose(m["tip_orientation_error_deg"]["max"], 10.0, atol=1e-5)
    pct = 100.0 * shift / exact.tube_ends_mm[:, 0]
    assert m["tip_error_pct_length"]["mean"] == pytest.approx(pct.mean(), rel=1e-9)
    along = 100.0 * shift[:, None] / exact.s_mm[:, 1:]
    assert m["backbone_error_pct"]["mean"] == pytest.approx(along.mean(), rel=1e-9)


def test_shipped_model_card_has_a_calibrated_bound_that_the_planner_uses(pinn):
    card = read_card(resolve_model(None))
    bound = card[ERROR_BOUND_KEY]
    assert bound["configurations"] >= 2000 and bound["seed"] == CALIBRATION_SEED
    assert bound["truth"] == "cosserat" and tuple(bound["coverages"]) == COVERAGES
    for r in bound["regions"]:
        assert np.all(np.diff(r["bound_mm"]) > 0) and r["bound_mm"][-1] <= r["max_mm"]
    assert pinn.card[ERROR_BOUND_KEY] == bound  # the card still loads: the weights hash is valid

    scene = load_scene(SCENES / "open.yaml")
    be, margin, source = planning_backend(scene, pinn)
    assert isinstance(be, RegionMarginBackend) and margin == scene.settings.margin_mm
    assert source["source"] == f"model card {ERROR_BOUND_KEY} at coverage 0.8"
    expected = region_bounds_mm(bound, scene.settings.surrogate_coverage)
    q = scene.start
    plain, inflated = pinn.forward(q, 30), be.forward(q, 30)
    assert np.array_equal(plain.positions_mm, inflated.positions_mm)
    extra = inflated.radius_mm - plain.radius_mm
    assert np.isclose(extra[0, 0], expected[0]) and np.isclose(extra[0, -1], expected[-1])

    fixed = scene.with_settings(surrogate_margin_mm=0.5)
    be, margin, source = planning_backend(fixed, pinn)
    assert be is pinn and margin == pytest.approx(scene.settings.margin_mm + 0.5)
    with pytest.raises(InputError, match="surrogate_coverage"):
        planning_backend(scene.with_settings(surrogate_coverage=0.7), pinn)


def test_eval_model_prints_the_tail(tmp_path, capsys):
    from ctrplan.cli.app import main

    assert main(["eval-model", "--n", "30", "--points", "20", "--out", str(tmp_path)]) in (0, None)
    out = capsys.readouterr().out
    assert "tube1 tip error: mean" in out and "p99 " in out and "p99.9 " in out and "max " in out
    assert main(["eval-model", "--n", "30", "--points", "20", "--out", str(tmp_path), "--json"]) in (0, None)
    doc = json.loads(capsys.readouterr().out)
    assert set(doc["tip_error_mm"]["tube1"]) == {"mean", "p99", "p99_9", "max"}
