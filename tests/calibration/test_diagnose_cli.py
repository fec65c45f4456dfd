"""`ctrplan diagnose` and the extended robot at the command line: bad data (exit 2, one line naming
file/row/field, nothing written), data of another tube count, the held-out split, --max-rows, `fk`
applying every part of an extended robot; and the rules that choose the named cause."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ctrplan.calibration import (
    DiagnoseOptions,
    diagnose,
    make_effect,
    read_measured,
    split_rows,
    write_measured_csv,
    write_outputs,
)
from ctrplan.calibration.fit import FitResult
from ctrplan.calibration.selection import Candidate, Selection, choose, judge, off_limits
from ctrplan.calibration.synthetic import generate
from ctrplan.cli.app import main
from ctrplan.model.causes.base import offset_limits
from ctrplan.model.robot import Robot
from tests.independent.lab import make, test_seed
from tests.paths import REPO

SEED = test_seed()
TWO_TUBE = REPO / "examples" / "robots" / "two_tube.yaml"
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
        candidates=("registration+sensor_offset+backlash",), pairs=0, resamples=0))
    write_outputs(diag, tmp_path / "diag")
    cal = Robot.load(tmp_path / "diag" / "extended_robot.yaml").calibration
    assert [name for name, _ in cal.terms] == ["backlash", "sensor_offset", "registration"], diag.summary()
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


def test_two_tube_extended_robot_with_backlash_reads_back_and_runs_fk(tmp_path, capsys):
    robot = Robot.load(TWO_TUBE)
    syn = generate(120, "backlash", seed=1000 * SEED + 13, noise_mm=0.05, robot=robot)
    data = tmp_path / "two.csv"
    write_measured_csv(data, syn.data.q, syn.data.tips_mm)
    out = tmp_path / "diag"
    rc = main(["diagnose", str(data), "--robot", str(TWO_TUBE), "--candidates", "backlash", "--pairs", "0",
               "--out", str(out), "--json"])
    assert rc == 0, capsys.readouterr().err
    doc = json.loads(capsys.readouterr().out)
    assert doc["cause"] == "backlash", doc["candidates"]
    ext = Robot.load(out / "extended_robot.yaml")
    assert ext.calibration.values("backlash", 2).tolist() == [doc["parameters"][f"backlash{i}_rad"]["value"]
                                                              for i in (1, 2)]
    configs = tmp_path / "configs.csv"
    rows = (",".join(repr(float(v)) for v in q) for q in syn.data.q)
    configs.write_text("beta1,beta2,alpha1,alpha2\n" + "\n".join(rows) + "\n")
    rc = main(["fk", str(configs), "--robot", str(out / "extended_robot.yaml")])
    assert rc == 0, capsys.readouterr().err


@pytest.mark.parametrize("command", [["diagnose", "{data}"], ["fk", "{configs}"], ["shape", "{configs}"]])
def test_data_with_more_tubes_than_the_robot_is_one_line_exit_2(tmp_path, capsys, command):
    lab = make(40, {}, seed=1000 * SEED + 14)
    data = tmp_path / "three.csv"
    lab.write_csv(data)
    configs = tmp_path / "configs.csv"
    configs.write_text("beta1,beta2,beta3,alpha1,alpha2,alpha3\n-30,-20,-10,0,0,0\n")
    out = tmp_path / "out.csv"
    args = [a.format(data=data, configs=configs) for a in command] + ["--robot", str(TWO_TUBE)]
    rc = main(args + (["-o", str(out)] if command[0] != "diagnose" else []))
    captured = capsys.readouterr()
    assert rc == 2 and captured.out == "" and captured.err.count("\n") == 1, captured
    assert "beta3" in captured.err and "alpha3" in captured.err and "has 2" in captured.err, captured.err
    assert not out.exists()


def test_heldout_options_hold_out_what_they_say(tmp_path, capsys):
    lab = make(120, {"registration": 1.0}, seed=1000 * SEED + 15)
    path = tmp_path / "lab.csv"
    lab.write_csv(path)
    common = ["diagnose", str(path), "--json", "--candidates", "registration", "--pairs", "0"]
    assert main(common + ["--heldout", "0.25"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["heldout_rows"] == 30 and doc["train_rows"] == 90 and doc["heldout"]["last"] is False
    assert main(common + ["--heldout-last", "0.3"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["heldout_rows"] == 36 and doc["heldout"]["last"] is True and doc["cause"] == "registration"
    assert main(common + ["--heldout", "0.2", "--heldout-last", "0.3"]) == 2
    assert "--heldout and --heldout-last" in capsys.readouterr().err
    assert main(common + ["--heldout-last", "1.5"]) == 2
    assert "--heldout-last: must be in (0, 1)" in capsys.readouterr().err


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


# ---- the rules that name a cause (on held-out errors made here) -----------------------------------
def _fit(causes: str, bic: float, implausible: dict | None = None) -> FitResult:
    robot = Robot.nominal()
    effect = make_effect(causes)
    x = effect.values(robot)
    return FitResult(effect=effect, params=effect.params(robot), lower=np.full(len(x), -np.inf),
                     upper=np.full(len(x), np.inf), x0=x, x=x, std=np.zeros(len(x)), robot=robot, rss=1.0,
                     n_residuals=1000, bic=bic, nfev=1, njev=1, success=True, message="",
                     identifiable=np.ones(len(x), dtype=bool), implausible=implausible or {})


NOMINAL_BIC = 0.0
ROWS = 100


def _nominal(split: int) -> np.ndarray:
    return np.full((ROWS, 1), 2.0) + np.random.default_rng(100 + split).normal(0, 0.05, (ROWS, 1))


def _candidate(causes: str, bic: float, heldout_mm: list[float], reference: str = "nominal",
               implausible: dict | None = None) -> Candidate:
    """A candidate whose held-out error on split k (main first) is ``heldout_mm[k]`` plus noise."""
    opt = DiagnoseOptions()
    fit = _fit(causes, bic, implausible)
    errs = [np.abs(m + np.random.default_rng(k).normal(0, 0.03, (ROWS, 1))) for k, m in enumerate(heldout_mm)]
    scores = [judge(fit, e, _nominal(k), NOMINAL_BIC, opt) for k, e in enumerate(errs)]
    return Candidate(fit=fit, main=scores[0], nominal=scores[0], reference=reference, resamples=scores[1:])


def _choose(*cands: Candidate) -> Selection:
    split = split_rows(4 * ROWS, 0.25)
    sel = Selection(split=split, resample_splits=[split, split], nominal_bic=NOMINAL_BIC,
                    nominal_err=_nominal(0), candidates=list(cands), not_fitted={})
    choose(sel, DiagnoseOptions())
    return sel


def test_a_single_cause_at_the_noise_beats_a_pair_and_never_a_subset_the_data_contradict():
    """The issue-19 case: joint_offset alone at the noise, + sensor_offset no better, sensor_offset
    alone six times worse: joint_offset is named, with no tie."""
    jo = _candidate("joint_offset", -13253, [0.16, 0.16, 0.16])
    pair = _candidate("joint_offset+sensor_offset", -13230, [0.158, 0.159, 0.16], reference="joint_offset")
    so = _candidate("sensor_offset", -3000, [1.02, 1.0, 1.05])
    sel = _choose(jo, pair, so)
    assert sel.chosen is jo and sel.ties == [] and sel.unstable == []


def test_a_pair_that_beats_its_single_on_every_split_is_named():
    a = _candidate("registration", -5000, [0.6, 0.6, 0.6])
    ab = _candidate("registration+backlash", -9000, [0.16, 0.17, 0.16], reference="registration")
    assert _choose(a, ab).chosen is ab


def test_equal_fits_are_ties_and_a_cause_on_one_split_only_is_unstable():
    a = _candidate("backlash", -9000, [0.2, 0.2, 0.2])
    b = _candidate("torsional_windup", -9004, [0.2, 0.2, 0.2])
    c = _candidate("curvature", -9000, [0.15, 1.99, 2.0])
    sel = _choose(a, b, c)
    assert {sel.chosen.name, *[t.name for t in sel.ties]} == {"backlash", "torsional_windup"}
    assert [u.name for u in sel.unstable] == ["curvature"]


def test_an_implausible_fit_is_reported_never_named():
    nu = _candidate("stiffness_ratio", -12000, [0.15, 0.15, 0.15],
                    implausible={"poisson_ratio": "-0.21 is outside [0, 0.5]"})
    reg = _candidate("registration", -5000, [0.9, 0.9, 0.9])
    sel = _choose(nu, reg)
    assert sel.chosen is reg and sel.implausible == [nu] and not nu.significant


def test_parameter_at_a_hard_bound_is_flagged_and_never_significant():
    robot = Robot.nominal()
    eff = make_effect("gravity")
    params = eff.params(robot)
    x = np.array([params[0].upper, 0.0, 1.0])
    fit = FitResult(effect=eff, params=params, lower=np.array([p.lower for p in params]),
                    upper=np.array([p.upper for p in params]), x0=eff.values(robot), x=x, std=np.full(3, 0.1),
                    robot=eff.with_values(robot, x), rss=1.0, n_residuals=100, bic=-1e4, nfev=1, njev=1,
                    success=True, message="", identifiable=np.ones(3, dtype=bool))
    assert off_limits(fit) == ["gravity_x_m_s2"]
    p = fit.parameters()["gravity_x_m_s2"]
    assert p["at_bound"] is True and p["std"] is None
    score = judge(fit, np.full((20, 3), 0.1), np.full((20, 3), 5.0) + np.linspace(0, 1, 20)[:, None], 0.0,
                  DiagnoseOptions())
    assert score.gain > 0.9 and score.beats and not score.significant


def test_cli_bad_options_one_line_exit_2(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("beta1,beta2,beta3,alpha1,alpha2,alpha3,tip1_x,tip1_y\n0,0,0,0,0,0,1,2\n")
    out = tmp_path / "never"
    rc = main(["diagnose", str(bad), "--json", "--out", str(out)])
    captured = capsys.readouterr()
    assert rc == 2 and captured.out == ""
    assert captured.err.count("\n") == 1 and "missing column 'tip1_z'" in captured.err
    assert not out.exists()
    rc = main(["diagnose", str(bad), "--candidates", "curvature,friction"])
    assert rc == 2 and "--candidates: unknown cause 'friction'" in capsys.readouterr().err


def test_among_fits_the_data_cannot_tell_apart_the_fewest_parameters_wins():
    """The issue's torsion case: stiffness_ratio (1 parameter) and transmission (3 lengths) fit alike --
    neither beats the other on the held-out rows, training BICs within the margin. The one parameter
    is named, the three lengths are its tie (before: the lower held-out error, transmission, was named)."""
    nu = _candidate("stiffness_ratio", -9000, [0.161, 0.161, 0.162])
    lengths = _candidate("transmission", -9005, [0.159, 0.160, 0.160])
    sel = _choose(lengths, nu)
    assert sel.chosen is nu and sel.ties == [lengths]
    # a fit the BIC tells apart (much worse in training) and the held-out rows too (3 % worse there,
    # short of a significant win) is neither named nor a tie
    worse = _candidate("curvature", -8000, [0.166, 0.166, 0.167])
    sel = _choose(nu, worse)
    assert sel.chosen is nu and sel.ties == []
    # ... but where the held-out rows do not repeat the training preference (as good there), the data
    # cannot tell them apart: a tie
    alike = _candidate("curvature", -8000, [0.160, 0.161, 0.161])
    sel = _choose(nu, alike)
    assert sel.chosen is nu and sel.ties == [alike]


def test_an_unresolved_or_past_bound_fit_is_never_significant():
    err, ref = np.full((20, 3), 0.1), np.full((20, 3), 5.0) + np.linspace(0, 1, 20)[:, None]
    for change in ({"identifiable": np.array([True, False, True])},
                   {"pushed": {"gravity_y_m_s2": "held at its bound; the data ask for more"}}):
        fit = _fit("gravity", -1e4)
        for k, v in change.items():
            setattr(fit, k, v)
        score = judge(fit, err, ref, 0.0, DiagnoseOptions())
        assert score.beats and not score.significant, change


def test_progress_is_a_plain_line_every_few_seconds_when_stderr_is_not_a_terminal(tmp_path, capsys,
                                                                                   monkeypatch):
    import ctrplan.cli.progress as progress

    monkeypatch.setattr(progress, "PROGRESS_EVERY_S", 0.01)
    lab = make(60, {"registration": 1.0}, seed=1000 * SEED + 12)
    path = tmp_path / "lab.csv"
    lab.write_csv(path)
    rc = main(["diagnose", str(path), "--json", "--candidates", "registration,curvature", "--pairs", "0"])
    assert rc == 0
    captured = capsys.readouterr()
    json.loads(captured.out)                      # stdout: the JSON document alone
    lines = [line for line in captured.err.splitlines() if line.startswith("diagnose: ")]
    assert lines and all(" s, " in line for line in lines), captured.err
    assert any("fitting curvature" in line for line in lines), captured.err
    assert "\x1b[" not in captured.err            # no terminal control sequences
