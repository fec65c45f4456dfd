"""`diagnose` on generated data with a hidden cause: it must name the cause and bring the held-out
error down to the noise level; data without an effect must give `none`.

Magnitudes are drawn at random (lab-sized, see `synthetic.draw_truth`); set CTRPLAN_TEST_SEED to
draw others. ~0.1 mm tracker noise per coordinate.
"""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from ctrplan.calibration import CAUSES, DiagnoseOptions, diagnose, load_extended_robot, read_measured
from ctrplan.calibration.data import write_measured_csv
from ctrplan.calibration.synthetic import HIDDEN_CAUSES, generate
from ctrplan.cli import main
from ctrplan.robot import Robot

SEED = int(os.environ.get("CTRPLAN_TEST_SEED", "0"))
ROWS = 120
NOISE_FACTOR = 1.25   # "at the noise level": held-out mean tip error within 25 % of the noise's own


def _noise_level(syn, rows) -> float:
    """Mean norm of the noise that was added to the tube-1 tips of ``rows``."""
    return float(np.linalg.norm(syn.noise_mm[rows, 0], axis=-1).mean())


def _check_parameters(diag, truth: dict) -> None:
    params = diag.to_json()["parameters"]
    for name, true in truth.items():
        p = params[name]
        tol = 6.0 * (p["std"] or 0.0) + 1e-3 * abs(true) + 1e-9
        assert abs(p["value"] - true) <= tol, (name, p, true)


@pytest.mark.parametrize("cause", [c for c in HIDDEN_CAUSES if c != "none"])
def test_hidden_cause_named_and_error_down_to_noise(cause):
    seed = 1000 * SEED + HIDDEN_CAUSES.index(cause) + 1
    syn = generate(ROWS, cause, seed=seed, noise_mm=0.1)
    diag = diagnose(syn.data)
    report = diag.summary()
    assert diag.cause == cause, report
    noise = _noise_level(syn, diag.heldout)
    j = diag.to_json()
    # the effect was visible, and the extended model is at the noise level on held-out rows
    assert j["nominal"]["mean_mm"] > 1.5 * noise, report
    assert j["extended"]["mean_mm"] <= NOISE_FACTOR * noise, report
    assert j["gain_pct"] > 30.0
    _check_parameters(diag, syn.truth)
    # uncertainties are reported
    assert all(p["std"] is None or p["std"] > 0 for p in j["parameters"].values())
    if cause == "backlash":
        # the nominal residual against the direction of motion already shows the lag of every tube
        lags = [j["nominal"]["where"]["by_direction"][f"alpha{i}"]["lag"] for i in (1, 2, 3)]
        truth = [syn.truth[f"backlash{i}_rad"] for i in (1, 2, 3)]
        np.testing.assert_allclose(lags, truth, rtol=0.2)
        assert sum("lags" in f for f in j["nominal"]["where"]["findings"]) == 3


def test_no_effect_gives_none():
    syn = generate(ROWS, "none", seed=1000 * SEED + 99, noise_mm=0.1)
    diag = diagnose(syn.data)
    j = diag.to_json()
    assert j["cause"] == "none", diag.summary()
    assert j["parameters"] == {} and j["gain_pct"] == 0.0
    assert j["extended"]["mean_mm"] == j["nominal"]["mean_mm"]
    assert not any(c["significant"] for c in j["candidates"])
    assert len(j["candidates"]) == len(CAUSES)
    assert j["explained"] is True and j["noise_mm"] > 0
    assert j["nominal"]["mean_mm"] <= NOISE_FACTOR * _noise_level(syn, diag.heldout)


def test_two_hidden_causes_named_together():
    syn = generate(ROWS, "curvature+backlash", seed=1000 * SEED + 77, noise_mm=0.1)
    diag = diagnose(syn.data, options=DiagnoseOptions(pairs=2))
    assert set(diag.causes) == {"curvature", "backlash"}, diag.summary()
    assert diag.to_json()["extended"]["mean_mm"] <= NOISE_FACTOR * _noise_level(syn, diag.heldout)
    _check_parameters(diag, syn.truth)


def test_tip1_only_data():
    """A tracker on the robot's tip only (the measured-data CSV without tip2/tip3 columns); a file
    longer than ``max_rows`` is diagnosed on contiguous runs of it."""
    syn = generate(ROWS, "registration", seed=1000 * SEED + 44, noise_mm=0.1, tubes=(0,))
    diag = diagnose(syn.data, options=DiagnoseOptions(
        candidates=("registration", "curvature", "joint_offset"), pairs=0, max_rows=120))
    j = diag.to_json()
    assert j["rows"] == ROWS and j["rows_used"] == 120 == j["train_rows"] + j["heldout_rows"]
    assert j["tubes_measured"] == [1] and len(j["nominal"]["per_tube"]) == 1
    assert j["cause"] == "registration", diag.summary()
    used = diag.data.lines - 2          # generated rows: line = index + 2
    assert j["extended"]["mean_mm"] <= NOISE_FACTOR * _noise_level(syn, used[diag.heldout])


def test_outliers_reported_not_dropped():
    syn = generate(ROWS, "joint_offset", seed=1000 * SEED + 55, noise_mm=0.1)
    data = syn.data
    bad = np.array([10, 60, 100])
    tips = data.tips_mm.copy()
    tips[bad, 0] += np.array([6.0, -5.0, 4.0])
    data = type(data)(q=data.q, tips_mm=tips, tubes=data.tubes, lines=data.lines, source="bumped.csv")
    diag = diagnose(data, options=DiagnoseOptions(candidates=("joint_offset", "curvature"), pairs=0))
    j = diag.to_json()
    assert j["cause"] == "joint_offset"
    assert {o["row"] for o in j["outliers"]} == set(data.lines[bad].tolist())
    assert j["outliers_excluded_from_fit"] is True
    assert j["rows"] == ROWS and "outliers" in diag.summary()


def test_cli_json_out_dir_and_extended_robot_for_fk(tmp_path, capsys):
    syn = generate(120, "joint_offset", seed=1000 * SEED + 33, noise_mm=0.1)
    data = tmp_path / "measured.csv"
    write_measured_csv(data, syn.data.q, syn.data.tips_mm)
    out = tmp_path / "diag"
    rc = main(["diagnose", str(data), "--json", "--out", str(out),
               "--candidates", "joint_offset,registration,backlash", "--pairs", "1"])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    doc = json.loads(captured.out)   # stdout holds exactly one JSON document
    for key in ("rows", "train_rows", "heldout_rows", "nominal", "cause", "parameters", "extended",
                "gain_pct", "candidates"):
        assert key in doc
    for key in ("mean_mm", "median_mm", "p95_mm", "mean_pct_length"):
        assert doc["nominal"][key] > 0 and doc["extended"][key] > 0
    assert doc["rows"] == 120 and doc["train_rows"] + doc["heldout_rows"] == 120
    assert doc["cause"] == "joint_offset"
    assert doc["extended"]["mean_mm"] < doc["nominal"]["mean_mm"]
    assert {"cause", "parameters", "heldout_mean_mm", "bic"} <= set(doc["candidates"][0])
    for name in ("extended_robot.yaml", "report.json", "before_after.png", "residual_vs_joints.png",
                 "residual_vs_direction.png", "residual_direction.png"):
        assert (out / name).stat().st_size > 0, name
    robot, calib = load_extended_robot(out / "extended_robot.yaml")
    assert calib.is_identity
    np.testing.assert_allclose(robot.joint_offset, [doc["parameters"][k]["value"] for k in (
        "beta1_offset_mm", "beta2_offset_mm", "beta3_offset_mm",
        "alpha1_offset_rad", "alpha2_offset_rad", "alpha3_offset_rad")])
    # the extended robot is a plain robot file: `ctrplan fk --robot` accepts it and the extended
    # model predicts the measured tips to the noise level
    configs = tmp_path / "configs.csv"
    configs.write_text("beta1,beta2,beta3,alpha1,alpha2,alpha3\n"
                       + "\n".join(",".join(repr(float(v)) for v in q) for q in syn.data.q[:20]) + "\n")
    rc = main(["fk", str(configs), "--robot", str(out / "extended_robot.yaml"),
               "-o", str(tmp_path / "fk.csv"), "--allow-outside-domain"])
    assert rc == 0, capsys.readouterr().err
    fk = read_measured(tmp_path / "fk.csv", Robot.nominal(), min_rows=1)
    err = np.linalg.norm(fk.tips_mm[:, 0] - syn.clean_tips_mm[:20, 0], axis=-1)
    assert err.mean() < 0.1


def test_cli_bad_input_one_line_exit_2(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("beta1,beta2,beta3,alpha1,alpha2,alpha3,tip1_x,tip1_y\n0,0,0,0,0,0,1,2\n")
    out = tmp_path / "never"
    rc = main(["diagnose", str(bad), "--json", "--out", str(out)])
    captured = capsys.readouterr()
    assert rc == 2 and captured.out == ""
    assert captured.err.count("\n") == 1 and "missing column 'tip1_z'" in captured.err
    assert not out.exists()
    rc = main(["diagnose", str(bad), "--candidates", "curvature,friction"])
    assert rc == 2 and "unknown cause 'friction'" in capsys.readouterr().err
