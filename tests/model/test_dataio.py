"""CSV reading with file line numbers, and atomic writing (ctrplan.base.dataio)."""

from __future__ import annotations

import os

import numpy as np
import pytest

from ctrplan.base.dataio import atomic_write, format_csv, read_table
from ctrplan.base.errors import DomainError, InputError
from ctrplan.model.robot import JOINT_NAMES, read_joints

HEADER = ",".join(JOINT_NAMES)


def test_read_table_picks_named_columns_in_any_order_and_ignores_others(tmp_path):
    path = tmp_path / "c.csv"
    path.write_text("\ufeffnote, alpha1 ,beta1\nfirst, 0.5 , -3\n\nsecond,-0.25,-7.5\n\n")
    table = read_table(path, ("beta1", "alpha1"))
    assert table.columns == ("beta1", "alpha1")
    np.testing.assert_array_equal(table.values, [[-3.0, 0.5], [-7.5, -0.25]])
    np.testing.assert_array_equal(table.lines, [2, 4])  # the blank line 3 is skipped, not renumbered
    np.testing.assert_array_equal(table.column("alpha1"), [0.5, -0.25])


def test_optional_columns_and_missing_values(tmp_path):
    path = tmp_path / "c.csv"
    path.write_text("\n\na,b,d\n1,,3\n4,NA,inf\n")
    table = read_table(path, ("a", "b"), optional=("c", "d"), allow_missing=True)
    assert table.columns == ("a", "b", "d")
    np.testing.assert_array_equal(table.values, [[1, np.nan, 3], [4, np.nan, np.inf]])
    np.testing.assert_array_equal(table.lines, [4, 5])  # header on line 3, after two blank lines
    with pytest.raises(InputError, match=r"c\.csv: row 4: b = '' is not a number"):
        read_table(path, ("a", "b"))
    with pytest.raises(InputError, match=r"c\.csv: row 5: d = 'inf' is not a finite number"):
        read_table(path, ("a", "d"))
    with pytest.raises(InputError, match=r"c\.csv: row 3: missing columns 'x', 'y' \(header has: a,b,d\)"):
        read_table(path, ("x", "a", "y"))


def test_joints_come_back_in_joint_order(tmp_path):
    path = tmp_path / "c.csv"
    path.write_text("alpha3,alpha2,alpha1,beta3,beta2,beta1\n6,5,4,3,2,1\n")
    np.testing.assert_array_equal(read_table(path, JOINT_NAMES).joints, [[1, 2, 3, 4, 5, 6]])


def test_repeated_column_is_rejected(tmp_path):
    path = tmp_path / "c.csv"
    path.write_text(HEADER + ",beta1\n" + "0,0,0,0,0,0,0\n")
    with pytest.raises(InputError, match=r"column 'beta1' appears 2 times"):
        read_table(path, JOINT_NAMES)


def test_domain_errors_name_file_lines_across_blank_lines(tmp_path, robot):
    path = tmp_path / "c.csv"
    path.write_text(f"{HEADER}\n0,0,0,0,0,0\n\n\n-5,-5,0,0,0,0\n-40,-20,0,0,0,0\n")
    with pytest.raises(DomainError, match=r"c\.csv: row 6: .*beta2 - beta1 <= 15 violated"):
        read_joints(path, robot)
    with pytest.warns(UserWarning, match=r"row 6"):
        table = read_joints(path, robot, allow_outside_domain=True)
    np.testing.assert_array_equal(table.lines, [2, 5, 6])


def test_format_csv_round_trips_joints_exactly(tmp_path, robot):
    q = robot.sample_joints(20, rng=7)
    path = tmp_path / "q.csv"
    path.write_text(format_csv(JOINT_NAMES, q, ["%r"] * 6))
    np.testing.assert_array_equal(read_table(path, JOINT_NAMES).joints, q)


def test_format_csv_without_header():
    assert format_csv(None, np.array([[1.5, 2.0]]), ["%r", "%.1f"]) == "1.5,2.0\n"


def test_atomic_write_replaces_target_with_usual_permissions(tmp_path):
    target = tmp_path / "out.csv"
    target.write_text("old\n")
    with atomic_write(target) as fh:
        fh.write("new\n")
    assert target.read_text() == "new\n"
    umask = os.umask(0)
    os.umask(umask)
    assert target.stat().st_mode & 0o777 == 0o666 & ~umask
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.csv"]


@pytest.mark.parametrize("umask", [None, 0o027, 0o077])
def test_atomic_write_gives_the_permissions_of_a_plain_open(tmp_path, umask):
    old = os.umask(umask) if umask is not None else None
    try:
        with open(tmp_path / "plain.csv", "w") as fh:
            fh.write("x\n")
        with atomic_write(tmp_path / "atomic.csv") as fh:
            fh.write("x\n")
        with atomic_write(tmp_path / "atomic.png", "wb") as fh:
            fh.write(b"x")
    finally:
        if old is not None:
            os.umask(old)
    plain = (tmp_path / "plain.csv").stat().st_mode & 0o777
    assert (tmp_path / "atomic.csv").stat().st_mode & 0o777 == plain
    assert (tmp_path / "atomic.png").stat().st_mode & 0o777 == plain


def test_atomic_write_leaves_nothing_when_the_block_fails(tmp_path):
    target = tmp_path / "out.csv"
    target.write_text("old\n")
    with pytest.raises(RuntimeError), atomic_write(target) as fh:
        fh.write("half")
        raise RuntimeError("solver crashed")
    assert target.read_text() == "old\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.csv"]


def test_atomic_write_into_missing_directory_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match="does not exist"), atomic_write(tmp_path / "no" / "x.csv"):
        pass


def test_ctrl_c_inside_an_atomic_write_leaves_the_old_file_and_no_temporary(tmp_path):
    """KeyboardInterrupt is not an Exception: the temporary file must go on it too, and the old file
    stays as it was."""
    target = tmp_path / "out.csv"
    target.write_text("old\n")
    with pytest.raises(KeyboardInterrupt), atomic_write(target) as fh:
        fh.write("half")
        raise KeyboardInterrupt
    assert [p.name for p in tmp_path.iterdir()] == ["out.csv"]
    assert target.read_text() == "old\n"
