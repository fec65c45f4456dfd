"""The real-like lab (`tests/independent/lab.real_like`: fixed joints, play + hysteresis lag, a large
tracker registration, only tube 1 measured) and the cause library's `friction` (the one model of a
direction-dependent lag, learned by `train --measured` too), checked against closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from ctrplan.model.causes.base import make_effect
from ctrplan.model.motion import Motion
from ctrplan.model.robot import Robot
from tests.independent import lab


def test_play_lag_closed_form():
    """From rest a move of d gives a lag min(d, w); a reversal then takes 2 w of travel to cross."""
    w = 0.05
    up = np.linspace(0.0, 0.2, 41)                      # steps of 0.005
    lag = lab.play_lag(up, w)
    assert np.allclose(lag, np.minimum(up, w))
    down = np.concatenate([up, 0.2 - np.linspace(0.005, 0.2, 40)])
    lag = lab.play_lag(down, w)[41:]
    travel = np.linspace(0.005, 0.2, 40)
    assert np.allclose(lag, np.maximum(w - travel, -w))


def test_hysteresis_lag_closed_form():
    """A monotone move of d from rest: a (1 - exp(-d / rho)) whatever the steps; a reversal relaxes
    towards -a from where it was."""
    a, rho = 0.03, 0.05
    x = np.concatenate([[0.0], np.cumsum(np.random.default_rng(0).uniform(0.001, 0.02, 30))])
    assert np.allclose(lab.hysteresis_lag(x, a, rho), a * (1 - np.exp(-x / rho)))
    back = np.concatenate([x, x[-1] - np.array([0.01, 0.03])])
    h0 = a * (1 - math.exp(-x[-1] / rho))
    expected = -a + (h0 + a) * np.exp(-np.array([0.01, 0.03]) / rho)
    assert np.allclose(lab.hysteresis_lag(back, a, rho)[-2:], expected)


def test_walk_keeps_fixed_joints_and_limits():
    q = lab.walk(400, np.random.default_rng(3), {1: -30.0, 2: -5.0, 5: 0.3})
    assert (q[:, 1] == -30.0).all() and (q[:, 2] == -5.0).all() and (q[:, 5] == 0.3).all()
    assert (q[:, 0] >= -44.0).all() and (q[:, 0] <= -31.0).all()
    assert (np.abs(q[:, 3:5]) <= 2.8).all()
    steps = np.abs(np.diff(q, axis=0))
    assert steps[:, 3:5].max() <= 0.035 * 1.7 + 1e-12 and steps[:, 0].max() <= 0.35 * 1.7 + 1e-12
    reversals = (np.diff(np.sign(np.diff(q[:, 3]))) != 0).sum()
    assert 5 <= reversals <= 60                         # a realistic back and forth, not noise


@pytest.fixture(scope="module")
def real():
    return lab.real_like(n=120, seed=1)


def test_real_like_registration_lag_and_noise(real):
    reg = real.effects["registration"]
    assert math.isclose(np.linalg.norm(reg["translation_mm"]), lab.REAL_REGISTRATION[0])
    assert math.isclose(math.degrees(np.linalg.norm(reg["rotation_vector_rad"])), lab.REAL_REGISTRATION[1])
    noise = real.tips_mm - real.clean_mm
    assert 0.18 < noise.std() < 0.30                   # 0.24 mm per coordinate, 360 samples
    # after a long move in one direction the lag is the full one: play w plus hysteresis a (1 - e^-x)
    x = np.linspace(0.0, 0.5, 100)
    for total in np.radians(lab.REAL_LAG_DEG):
        lag = lab.play_lag(x, lab.PLAY_SHARE * total) + lab.hysteresis_lag(
            x, (1 - lab.PLAY_SHARE) * total, lab.HYSTERESIS_SCALE_RAD)
        assert math.isclose(lag[-1], total, rel_tol=1e-3)


def test_real_like_writes_only_tube1(real, tmp_path):
    path = tmp_path / "m.csv"
    real.write_csv(path, tubes=(0,))
    head = path.read_text().splitlines()[0].split(",")
    assert head == ["beta1", "beta2", "beta3", "alpha1", "alpha2", "alpha3", "tip1_x", "tip1_y", "tip1_z"]


def test_play_closed_form():
    """Radius 0 is the direction of motion; radius r ramps from +1 to -1 over 2 r after a reversal."""
    x = np.r_[0.0, 0.1, 0.2, 0.18, 0.16, 0.14, 0.12, 0.3]
    q = np.zeros((len(x), 2))
    q[:, 1] = x
    motion = Motion.of(q)
    assert np.array_equal(motion.play(1, 0.0), [0, 1, 1, -1, -1, -1, -1, 1])
    assert np.allclose(motion.play(1, 0.02), [0, 1, 1, 0, -1, -1, -1, 1])


def test_friction_joints_and_robot_file(tmp_path):
    """alpha_i reaches alpha_i - sum_k w_ik phi_ik; the robot file keeps the friction, not the
    fingerprint of the mechanics."""
    friction = make_effect("friction")
    r = friction.RADII_RAD
    w = np.zeros((6, 4))
    w[3] = [0.0, 0.01, 0.02, 0.0]
    q = np.zeros((5, 6))
    r = r[1:]                                                    # the 2- and 6-deg elements
    q[:, 3] = [0.0, 0.1, 0.2, 0.2 - r[0], 0.2 - 2 * r[0]]
    robot = friction.with_values(Robot.nominal(), w.ravel())
    qm = robot.calibration.mechanics_joints(q)
    phi1 = np.array([0.0, 1.0, 1.0, 0.0, -1.0])                 # the 2-deg element turns over 2 r
    phi2 = np.array([0.0, 0.1 / r[1], 1.0, 1.0 - r[0] / r[1], 1.0 - 2 * r[0] / r[1]])   # the 6-deg one
    expect = q[:, 3] - 0.01 * phi1 - 0.02 * phi2
    assert np.allclose(qm[:, 3], expect)
    assert np.array_equal(qm[:, [0, 1, 2, 4, 5]], q[:, [0, 1, 2, 4, 5]])
    path = tmp_path / "r.yaml"
    robot.save(path)
    stored = yaml.safe_load(path.read_text())["calibration"]["friction"]
    assert np.allclose(stored["rotation_lag_rad"][0], [0.0, 0.01, 0.02, 0.0])
    back = Robot.load(path)
    assert back.calibration == robot.calibration and back.fingerprint == Robot.nominal().fingerprint


def true_mechanics(data: lab.LabData) -> Robot:
    """The nominal robot with the lab's curvature and tracker registration (its lag left out)."""
    from dataclasses import replace

    nominal = Robot.nominal()
    kappa = data.effects["curvature"]["kappa_factor"]
    reg = data.effects["registration"]
    tubes = tuple(replace(t, curvature_per_mm=t.curvature_per_mm * k)
                  for t, k in zip(nominal.tubes, kappa, strict=True))
    frame = reg["rotation_vector_rad"] + reg["translation_mm"]
    return nominal.with_changes(tubes=tubes, calibration=nominal.calibration.with_term("registration", frame))


def test_friction_fitted_from_the_shots_recovers_the_lab_lag():
    """On real-like lab rows, with the true mechanics and registration, the friction fitted on the
    first rows (as `train --measured` learns it) recovers the total lag of alpha1 and alpha2 (the sum of
    its weights: the lag after a long move) and brings later rows near the noise, which backlash alone
    with the true total lag does not."""
    from ctrplan.calibration.predict import Evaluator
    from ctrplan.calibration.selection import unsupported
    from ctrplan.training.lag import fit_friction

    data = lab.real_like(n=360, seed=4)
    robot = true_mechanics(data)
    motion = Motion.of(data.q)
    fit, test = np.arange(240), np.arange(240, 360)
    tips = np.repeat(data.tips_mm[:, :1], 3, axis=1)
    fitted = fit_friction(robot, data.q[fit], motion.subset(fit), (0,), tips[fit])
    assert not unsupported(fitted)          # what the lab hid, the rows resolve: the few-shot stage keeps it
    learned = fitted.robot
    friction = make_effect("friction")
    w = friction.values(learned).reshape(6, -1)
    total = np.degrees(w.sum(axis=1))
    assert np.allclose(total[3:5], lab.REAL_LAG_DEG, atol=0.6) and total[5] == 0.0   # alpha3 never moves

    def mean_error(model: Robot) -> float:
        pred = Evaluator(data.q[test], motion.subset(test)).predict([model])[0]
        return float(np.linalg.norm(pred.tips_mm[:, 0] - data.tips_mm[test, 0], axis=1).mean())

    backlash = robot.with_changes(calibration=robot.calibration.with_term(
        "backlash", [*np.radians(lab.REAL_LAG_DEG), 0.0]))
    noise = 1.596 * lab.REAL_SIGMA_MM           # mean norm of 3-D Gaussian noise: 2 sqrt(2 / pi) sigma
    assert mean_error(learned) < 1.15 * noise < mean_error(backlash)


def test_a_lag_the_shots_do_not_resolve_is_not_kept(tmp_path):
    """Nineteen fit shots of the real-like lab move beta1 too little to resolve its friction elements:
    the few-shot stage does not keep the learned friction -- the rule `diagnose` names a cause by
    (`unsupported`) -- although the validation shots say it predicts better (the lab's alpha lag is
    real: the rule's price on so few rows; with 240 the lag is resolved and kept, above)."""
    from ctrplan.calibration import read_measured
    from ctrplan.training.fewshot import split_shots, validation_split
    from ctrplan.training.finetune import learn_lag

    data = lab.real_like(n=30, seed=1)
    path = tmp_path / "lab.csv"
    data.write_csv(path, tubes=(0,))
    robot = true_mechanics(data)
    fs = split_shots(read_measured(path, robot), heldout_fraction=0.2, heldout_last=True)
    fit, val = validation_split(fs)
    said: list[str] = []
    model, record = learn_lag(robot, fs, fit, val, said.append)
    assert model is robot and record["kept"] is False, record
    assert record["validation_mean_mm"]["with"] < 0.5 * record["validation_mean_mm"]["without"], record
    assert any(d.startswith("beta1_slip") and d.endswith("not resolved by the rows")
               for d in record["unsupported"]), record
    assert "the shots do not support it" in said[-1]
