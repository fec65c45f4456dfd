"""Measured-data readers (measured-data CSV, CRL 40 columns), the row split and the direction of
motion -- on files generated here."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ctrplan.base.errors import InputError
from ctrplan.calibration import (
    motion_direction,
    read_measured,
    split_rows,
    write_crl_csv,
    write_measured_csv,
)
from ctrplan.calibration.data import matrix_quaternion, quaternion_matrix
from ctrplan.calibration.synthetic import generate
from ctrplan.kinematics import CosseratBackend
from ctrplan.model.motion import Motion
from ctrplan.model.robot import Robot
from tests.independent.lab import make


@pytest.fixture(scope="module")
def syn():
    return generate(60, "none", seed=11)


def _lines(path):
    return path.read_text().splitlines()


def _write_lines(path, lines):
    path.write_text("\n".join(lines) + "\n")


def _set_cell(lines, line_no, col, value):
    """Replace field ``col`` (0-based) of file line ``line_no`` (1-based) in ``lines``."""
    cells = lines[line_no - 1].split(",")
    cells[col] = value
    lines[line_no - 1] = ",".join(cells)


# ---- measured-data CSV ----------------------------------------------------------------------------
def test_csv_round_trip_ignores_other_columns(tmp_path, syn):
    p = tmp_path / "data.csv"
    extra = {"timestamp": np.arange(len(syn.data)) * 0.1}
    write_measured_csv(p, syn.data.q, syn.data.tips_mm, extra=extra)
    # shuffle the column order: columns are found by name
    rows = [r.split(",") for r in _lines(p)]
    order = [len(rows[0]) - 1] + list(range(len(rows[0]) - 1))[::-1]
    _write_lines(p, [",".join(r[i] for i in order) for r in rows])
    d = read_measured(p)
    assert d.format == "csv" and d.tubes == (0, 1, 2)
    np.testing.assert_allclose(d.q, syn.data.q)
    np.testing.assert_allclose(d.tips_mm, syn.data.tips_mm)
    assert d.lines[0] == 2 and d.lines[-1] == len(syn.data) + 1
    assert not d.outside_domain.any()


def test_csv_tube1_only(tmp_path, syn):
    p = tmp_path / "tip1.csv"
    write_measured_csv(p, syn.data.q, syn.data.tips_mm, tubes=(0,))
    d = read_measured(p)
    assert d.tubes == (0,)
    assert np.isnan(d.tips_mm[:, 1:]).all() and np.isfinite(d.tips_mm[:, 0]).all()


def test_csv_missing_columns_named(tmp_path, syn):
    p = tmp_path / "d.csv"
    write_measured_csv(p, syn.data.q, syn.data.tips_mm)
    lines = _lines(p)
    _write_lines(p, [lines[0].replace("tip1_y", "tipY")] + lines[1:])
    with pytest.raises(InputError, match=r"d\.csv: row 1: missing column 'tip1_y'"):
        read_measured(p)
    _write_lines(p, [lines[0].replace("tip2_z", "t2z")] + lines[1:])
    with pytest.raises(InputError, match=r"tube 2 tip is incomplete: missing column 'tip2_z'"):
        read_measured(p)


def test_csv_nan_rows_named(tmp_path, syn):
    p = tmp_path / "nan.csv"
    write_measured_csv(p, syn.data.q, syn.data.tips_mm)
    lines = _lines(p)
    for line_no, col, val in ((6, 7, "nan"), (10, 8, ""), (31, 2, "NaN")):
        _set_cell(lines, line_no, col, val)
    _write_lines(p, lines)
    with pytest.raises(InputError) as exc:
        read_measured(p)
    msg = str(exc.value)
    assert "rows 6, 10, 31" in msg and "tip1_y" in msg and "\n" not in msg


def test_csv_text_cell_named(tmp_path, syn):
    p = tmp_path / "txt.csv"
    write_measured_csv(p, syn.data.q, syn.data.tips_mm)
    lines = _lines(p)
    _set_cell(lines, 5, 3, "ten")
    _write_lines(p, lines)
    with pytest.raises(InputError, match=r"txt\.csv: row 5: alpha1 = 'ten' is not a number"):
        read_measured(p)
    # blank lines before the header count too: "row N" stays line N of the file
    _write_lines(p, ["", ""] + lines)
    with pytest.raises(InputError, match=r"txt\.csv: row 7: alpha1 = 'ten' is not a number"):
        read_measured(p)


def test_written_files_get_the_permissions_of_a_plain_open(tmp_path, syn):
    (tmp_path / "plain.csv").write_text("x\n")
    plain = (tmp_path / "plain.csv").stat().st_mode & 0o777
    write_measured_csv(tmp_path / "m.csv", syn.data.q, syn.data.tips_mm)
    write_crl_csv(tmp_path / "crl.csv", syn.data.q, syn.data.tips_mm)
    Robot.nominal().save(tmp_path / "robot.yaml")
    for name in ("m.csv", "crl.csv", "robot.yaml"):
        assert (tmp_path / name).stat().st_mode & 0o777 == plain, name


def test_impossible_joints_rejected_with_row(tmp_path, syn):
    q = syn.data.q.copy()
    q[7, 0] = q[7, 1] + 4.0          # tube 1 base in front of tube 2's: impossible
    p = tmp_path / "imp.csv"
    write_measured_csv(p, q, syn.data.tips_mm)
    with pytest.raises(InputError, match=r"imp\.csv: row 9: tube order violated"):
        read_measured(p)


def test_too_few_rows(tmp_path, syn):
    p = tmp_path / "few.csv"
    write_measured_csv(p, syn.data.q[:12], syn.data.tips_mm[:12])
    with pytest.raises(InputError, match=r"only 12 data rows"):
        read_measured(p)


def test_outside_domain_accepted_and_flagged(tmp_path):
    """CRL-like configurations (beta1 down to -128 mm, alpha up to +-60 deg, beta2 - beta1 > 15 mm)
    leave the snap-free planning domain: accepted, flagged."""
    rng = np.random.default_rng(3)
    robot = Robot.nominal()
    q = robot.sample_joints(40, rng)
    q[:5, 0] = -128.0 + rng.uniform(0, 5, 5)   # CRL-like extension: beta up to -128 mm
    q[:5, 1] = -100.0
    q[:5, 2] = -50.0
    q[:, 3:] = rng.uniform(-math.pi / 3, math.pi / 3, (40, 3))
    tips = CosseratBackend(robot).forward(q, points=2, check=False).tips_mm
    p = tmp_path / "wide.csv"
    write_measured_csv(p, q, tips)
    d = read_measured(p)
    assert d.outside_domain.sum() == 5 and d.outside_domain[:5].all()


def test_not_a_data_file(tmp_path):
    p = tmp_path / "x.csv"
    p.write_text("a,b,c\n1,2,3\n")
    with pytest.raises(InputError, match=r"row 1: header lacks the joint columns"):
        read_measured(p)
    p.write_text("1,2,3\n4,5,6\n")
    with pytest.raises(InputError, match=r"3 numeric columns"):
        read_measured(p)
    p.write_text("")
    with pytest.raises(InputError, match=r"empty file"):
        read_measured(p)
    with pytest.raises(InputError, match=r"file not found"):
        read_measured(tmp_path / "missing.csv")


# ---- CRL 40-column format -------------------------------------------------------------------------
def _random_pose(rng):
    axis = rng.normal(size=3)
    angle = rng.uniform(0.3, 2.5)
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle).as_matrix()
    T[:3, 3] = rng.uniform(-200, 200, 3)
    return T


def test_crl_reader_relative_to_base_sensor(tmp_path, syn):
    rng = np.random.default_rng(5)
    T = _random_pose(rng)
    p = tmp_path / "crl.csv"
    write_crl_csv(p, syn.data.q, syn.data.tips_mm, base_pose=T, rng=rng)
    raw = np.loadtxt(p, delimiter=",")
    assert raw.shape == (len(syn.data), 40)
    # the file is in the tracker frame: the raw sensor positions are far from the robot-frame tips
    assert np.abs(raw[:, 33:36] - syn.data.tips_mm[:, 0]).max() > 10
    # alpha1 beta1 alpha2 beta2 alpha3 beta3 order
    np.testing.assert_allclose(raw[:, 0], syn.data.q[:, 3])
    np.testing.assert_allclose(raw[:, 1], syn.data.q[:, 0])
    d = read_measured(p)
    assert d.format == "crl" and d.tubes == (0, 1, 2)
    np.testing.assert_allclose(d.q, syn.data.q)
    # inv(T_base) T_sensor: inner -> tube 1, middle -> tube 2, outer -> tube 3
    np.testing.assert_allclose(d.tips_mm, syn.data.tips_mm, atol=1e-9)
    np.testing.assert_allclose(d.increments[1:], np.diff(syn.data.q, axis=0), atol=1e-12)
    assert d.lines[0] == 1


def test_crl_bad_rows(tmp_path, syn):
    p = tmp_path / "crl.csv"
    write_crl_csv(p, syn.data.q, syn.data.tips_mm)
    lines = _lines(p)
    bad = lines.copy()
    bad[3] = ",".join(bad[3].split(",")[:39])
    _write_lines(p, bad)
    with pytest.raises(InputError, match=r"crl\.csv: row 4: expected 40 columns \(CRL format\), got 39"):
        read_measured(p)
    bad = lines.copy()
    _set_cell(bad, 9, 14, "nan")   # base_z
    _write_lines(p, bad)
    with pytest.raises(InputError, match=r"row 9: missing or non-finite values \(first: base_z"):
        read_measured(p)
    bad = lines.copy()
    for line_no, col, val in ((10, 0, "NA"), (20, 33, "")):
        _set_cell(bad, line_no, col, val)
    _write_lines(p, bad)
    with pytest.raises(InputError) as exc:
        read_measured(p)
    assert "rows 10, 20: missing or non-finite values (first: alpha1 in row 10)" in str(exc.value)
    _set_cell(bad, 30, 5, "x")
    _write_lines(p, bad)
    with pytest.raises(InputError, match=r"row 30: column 6 \(beta3\) = 'x' is not a number"):
        read_measured(p)


def test_quaternion_round_trip():
    rng = np.random.default_rng(0)
    for _ in range(5):
        R = _random_pose(rng)[:3, :3]
        np.testing.assert_allclose(quaternion_matrix(matrix_quaternion(R)), R, atol=1e-12)


# ---- split and direction --------------------------------------------------------------------------
@pytest.mark.parametrize("n,fraction", [(400, 0.25), (200, 0.25), (157, 0.3), (1307, 0.3), (60, 0.1)])
def test_split_holds_out_the_fraction_asked_for_in_contiguous_blocks(n, fraction):
    s = split_rows(n, fraction, seed=4)
    assert len(s.heldout) == round(fraction * n)          # 0.25 of 400 is 100 rows, not 80
    assert len(np.intersect1d(s.train, s.heldout)) == 0 and len(s.train) + len(s.heldout) == n
    # held-out rows come as few contiguous runs (blocks of n/10 rows), not scattered rows
    runs = np.split(s.heldout, np.flatnonzero(np.diff(s.heldout) != 1) + 1)
    assert len(runs) <= int(np.ceil(fraction * 10)) and min(len(r) for r in runs) >= 1
    again, other = split_rows(n, fraction, seed=4), split_rows(n, fraction, seed=5)
    np.testing.assert_array_equal(s.heldout, again.heldout)
    assert not np.array_equal(s.heldout, other.heldout)


def test_split_last_holds_out_the_last_rows_and_resamples_only_the_training_rows():
    s = split_rows(200, 0.3, last=True)
    np.testing.assert_array_equal(s.heldout, np.arange(140, 200))
    np.testing.assert_array_equal(s.train, np.arange(140))
    r = s.resample(7)
    assert set(r.train) | set(r.heldout) == set(range(140)) and len(r.heldout) == 42
    with pytest.raises(InputError, match=r"heldout fraction must be in \(0, 1\)"):
        split_rows(100, 1.5)


def test_motion_direction_persists_when_joint_rests():
    a = np.array([0.0, 0.1, 0.1, 0.05, 0.05, 0.2])
    q = np.zeros((6, 6))
    q[:, 3] = a
    d = motion_direction(q)
    np.testing.assert_array_equal(d[:, 3], [0, 1, 1, -1, -1, 1])
    assert not d[:, [0, 1, 2, 4, 5]].any()


def test_a_rotation_wrapping_around_keeps_its_direction():
    """Reported angles wrap at +-pi (3.10 -> -3.13 rad is a step of +0.053 rad): the real data's
    alpha1 and alpha2 wrapped 26 times, each read as a reversal before."""
    a = np.array([3.0, 3.1, -3.13, -3.0, -3.1, 3.1])
    q = np.zeros((6, 6))
    q[:, 4] = a
    d = motion_direction(q)
    np.testing.assert_array_equal(d[:, 4], [0, 1, 1, 1, -1, -1])
    travel = Motion.of(q).travel[:, 4]
    np.testing.assert_allclose(np.diff(travel), [0.1, 2 * np.pi - 6.23, 0.13, -0.1, 6.2 - 2 * np.pi])


def test_session_column_is_read_and_each_session_is_its_own_sequence(tmp_path):
    lab = make(60, {}, seed=3)
    lab.session = np.array(["2024-05-01"] * 30 + ["7"] * 30)
    path = tmp_path / "m.csv"
    lab.write_csv(path)
    data = read_measured(path)
    assert data.sessions == ("2024-05-01", "7")
    assert data.subset(np.arange(25, 35)).sessions == ("2024-05-01", "7")
    motion = data.motion()
    assert not motion.step[30].any() and motion.step[29].any()     # no step across the session change
    assert not motion.direction[30].any()
    text = path.read_text().replace(",7\n", ",\n", 1)
    path.write_text(text)
    with pytest.raises(InputError, match=r"row 32: session is empty"):
        read_measured(path)
