"""`ctrplan diagnose` and the extended robot at the command line: bad data (exit 2, one line naming
file/row/field, nothing written), --max-rows, and `fk` applying every part of an extended robot."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ctrplan.calibration import DiagnoseOptions, diagnose, load_extended_robot, read_measured
from ctrplan.calibration.diagnosis import Candidate, _Selection, offset_limits, write_outputs
from ctrplan.calibration.effects import make_effect
from ctrplan.calibration.fit import FitResult
from ctrplan.cli import main
from ctrplan.robot import Robot
from tests.independent.lab import make, test_seed

SEED = test_seed()
HEAD = "beta1,beta2,beta3,alpha1,alpha2,alpha3,tip1_x,tip1_y,tip1_z\n"
ROW = "-20,-10,-5,0.1,0.2,0.3,1,2,150\n"


def _crl_row(cols: int = 40) -> str:
    vals = [0.1, -20, 0.2, -10, 0.3, -5] + [0.0] * 6 + [0, 0, 0, 1, 0, 0, 0] + [1, 2, 150, 1, 0, 0, 0] * 3
    return ",".join(str(v) for v in vals[:cols]) + "\n"


@pytest.mark.parametrize("name,text,expect", [
    ("nan", HEAD + ROW * 40 + "-20,-10,-5,0,0,0,1,2,nan\n", ["row 42", "tip1_z"]),
    ("text", HEAD + ROW * 40 + "-20,-10,-5,0,0,0,1,abc,3\n", ["row 42", "tip1_y", "'abc'"]),
    ("empty_cell", HEAD + ROW * 40 + "-20,-10,,0,0,0,1,2,3\n", ["row 42", "beta3"]),
    ("few", HEAD + ROW * 5, ["only 5 data rows", "at least 30"]),
    ("crl_columns", _crl_row() * 40 + _crl_row(39), ["row 41", "40 columns"]),
    ("crl_text", _crl_row() * 40 + _crl_row().replace("150", "x1", 1), ["row 41"]),
    ("crl_few", _crl_row() * 3, ["only 3 data rows"]),
])
def test_bad_measured_data_exit_2_one_line_nothing_written(tmp_path, capsys, name, text, expect):
    path = tmp_path / f"{name}.csv"
    path.write_text(text)
    out = tmp_path / "never"
    rc = main(["diagnose", str(path), "--json", "--out", str(out)])
    captured = capsys.readouterr()
    assert rc == 2 and captured.out == "", captured
    assert captured.err.count("\n") == 1 and str(path) in captured.err, captured.err
    assert "Traceback" not in captured.err
    for e in expect:
        assert e in captured.err, captured.err
    assert not out.exists()


def test_max_rows_says_how_many_rows_it_dropped(tmp_path, capsys):
    lab = make(150, {"registration": 1.0}, seed=1000 * SEED + 11)
    path = tmp_path / "lab.csv"
    lab.write_csv(path)
    rc = main(["diagnose", str(path), "--json", "--max-rows", "120", "--candidates", "registration",
               "--pairs", "0"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    doc = json.loads(captured.out)
    assert doc["rows"] == 150 and doc["rows_used"] == 120 and doc["rows_dropped"] == 30
    assert "30 of 150 rows dropped" in captured.err
    assert doc["cause"] == "registration"


def test_fk_with_the_extended_robot_reproduces_diagnose(tmp_path, capsys):
    """Backlash (rows in order), sensor offset and registration all live in the extended robot file:
    `ctrplan fk --robot extended_robot.yaml` on the diagnosed rows gives diagnose's extended error."""
    lab = make(150, {"sensor_offset": 1.0, "backlash": 1.0, "registration": 1.0},
               seed=1000 * SEED + 12)
    path = tmp_path / "lab.csv"
    lab.write_csv(path)
    data = read_measured(path)
    diag = diagnose(data, options=DiagnoseOptions(
        candidates=("registration+sensor_offset+backlash",), pairs=0, resamples=0, bootstrap=0))
    write_outputs(diag, tmp_path / "diag", plots=False)
    robot, calib = load_extended_robot(tmp_path / "diag" / "extended_robot.yaml")
    assert any(calib.backlash_rad) and any(calib.sensor_offset_mm) and calib.has_registration, \
        diag.summary()
    configs = tmp_path / "configs.csv"
    configs.write_text("beta1,beta2,beta3,alpha1,alpha2,alpha3\n"
                       + "\n".join(",".join(repr(float(v)) for v in q) for q in data.q) + "\n")
    rc = main(["fk", str(configs), "--robot", str(tmp_path / "diag" / "extended_robot.yaml"),
               "-o", str(tmp_path / "fk.csv"), "--allow-outside-domain"])
    assert rc == 0, capsys.readouterr().err
    fk = read_measured(tmp_path / "fk.csv", Robot.nominal(), min_rows=1)
    err_fk = np.linalg.norm(data.tips_mm - fk.tips_mm, axis=-1)
    np.testing.assert_allclose(err_fk, diag.errors("extended"), atol=1e-4)
    assert diag.to_json()["explained"] is True, diag.summary()
    # the nominal robot file gives the nominal error: fk did not ignore the calibration before
    rc = main(["fk", str(configs), "-o", str(tmp_path / "fk0.csv"), "--allow-outside-domain"])
    fk0 = read_measured(tmp_path / "fk0.csv", Robot.nominal(), min_rows=1)
    np.testing.assert_allclose(np.linalg.norm(data.tips_mm - fk0.tips_mm, axis=-1), diag.errors("nominal"),
                               atol=1e-4)


def test_parameter_at_its_bound_is_flagged_and_never_significant():
    robot, calib = Robot.nominal(), Robot.nominal().calibration
    eff = make_effect("gravity")
    params = eff.params(robot, calib)
    x = np.array([params[0].upper, 0.0, 1.0])
    r2, c2 = eff.apply(robot, calib, x)
    fit = FitResult(effect=eff, params=params, x0=eff.x0(robot, calib), x=x, std=np.full(3, 0.1),
                    robot=r2, calibration=c2, rss=1.0, n_residuals=100, bic=-1e4, nfev=1, njev=1,
                    success=True, message="", identifiable=np.ones(3, dtype=bool))
    cand = Candidate(fit=fit, heldout=None, heldout_err=np.full((20, 3), 0.1))
    assert cand.off_limits() == ["gravity_x_m_s2"]
    p = fit.parameters()["gravity_x_m_s2"]
    assert p["at_bound"] is True and p["std"] is None
    sel = _Selection.__new__(_Selection)
    sel.opt = DiagnoseOptions()
    sel._judge(cand, np.full((20, 3), 5.0) + np.linspace(0, 1, 20)[:, None], 0.0)
    assert cand.gain > 0.9 and not cand.significant


def test_offset_limits_keep_every_row_physical():
    robot = Robot.nominal()
    rng = np.random.default_rng(SEED)
    q = robot.sample_joints(200, rng)
    lim = offset_limits(q, robot)
    for corner in range(8):
        off = np.zeros(6)
        for i in range(3):
            lo, hi = lim[f"beta{i + 1}_offset_mm"]
            assert lo <= 0.0 <= hi
            off[i] = hi if corner >> i & 1 else lo
        robot.with_changes(joint_offset=tuple(off)).check_joints(q, allow_outside_domain=True)


def _cand(causes: tuple[str, ...], bic: float, held: float, significant: bool = True):
    from types import SimpleNamespace

    return SimpleNamespace(causes=causes, cause="+".join(causes), significant=significant,
                           fit=SimpleNamespace(bic=bic), heldout_mean=lambda tube=0: held)


def test_only_stable_causes_are_named_and_disagreement_is_a_tie():
    from ctrplan.calibration.diagnosis import _stability, _stable_choice

    opt = DiagnoseOptions()
    a, b, c = _cand(("registration",), -500, 0.2), _cand(("backlash",), -100, 0.8), \
        _cand(("joint_offset",), -495, 0.205)
    ab = _cand(("registration", "backlash"), -520, 0.19)
    # the partner of a pair chosen on one split of three is not named
    st = _stability(["backlash+registration", "registration", "registration"], {}, opt)
    chosen, ties, unstable = _stable_choice({"chosen": ab, "singles": [a, b], "pairs": [ab]}, st, opt)
    assert chosen is a and ties == [] and unstable == ["backlash"]
    # the splits mostly chose nothing: nothing is named
    st = _stability(["registration", "none", "none"], {}, opt)
    assert _stable_choice({"chosen": a, "singles": [a], "pairs": []}, st, opt)[0] is None
    # the splits disagree: a tie
    st = _stability(["registration", "joint_offset", "none"], {}, opt)
    chosen, ties, _ = _stable_choice({"chosen": a, "singles": [a], "pairs": []}, st, opt)
    assert chosen is a and ties == ["joint_offset", "registration"]
    # stable on every split, but a near-tie on the main split is reported
    st = _stability(["registration"] * 3, {}, opt)
    chosen, ties, _ = _stable_choice({"chosen": a, "singles": [a, c], "pairs": []}, st, opt)
    assert ties == ["joint_offset", "registration"]
