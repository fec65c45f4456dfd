"""Bad input through the real CLI: one line on stderr naming file/row/field, exit 2, nothing written."""

from __future__ import annotations

import subprocess
import sys
from importlib import resources
from pathlib import Path

import pytest

from ctrplan.cli import main
from ctrplan.robot import JOINT_NAMES

HEADER = ",".join(JOINT_NAMES)
GOOD_ROW = "-20,-10,-5,0.1,0.2,0.3"
EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "configs.csv"
NOMINAL_YAML = resources.files("ctrplan.data").joinpath("nominal.yaml").read_text()


def broken_robot(old: str, new: str) -> str:
    """The nominal robot file with the first ``old`` replaced by ``new``."""
    assert old in NOMINAL_YAML
    return NOMINAL_YAML.replace(old, new, 1)


# name: (configs text or None for no file, robot text or None, extra args, fragments of the message)
CONFIG_CASES = {
    "missing file": (None, None, [], ["configs.csv", "file not found"]),
    "empty file": ("", None, [], ["configs.csv", "empty file"]),
    "header only": (HEADER + "\n", None, [], ["configs.csv", "no data rows"]),
    "missing column": ("beta1,beta2,beta3,alpha1,alpha3\n0,0,0,0,0\n", None, [],
                       ["configs.csv: row 1", "missing column 'alpha2'"]),
    "short row": (f"{HEADER}\n{GOOD_ROW}\n-20,-10,-5\n", None, [], ["configs.csv: row 3", "fields"]),
    "non-numeric cell": (f"{HEADER}\n{GOOD_ROW}\n-20,-10,-5,0,abc,0\n", None, [],
                         ["configs.csv: row 3", "alpha2", "'abc'", "not a number"]),
    "nan cell": (f"{HEADER}\nnan,-10,-5,0,0,0\n", None, [],
                 ["configs.csv: row 2", "beta1", "not a finite number"]),
    "inf cell": (f"{HEADER}\n{GOOD_ROW}\n-20,-10,-5,0,0,-inf\n", None, [],
                 ["configs.csv: row 3", "alpha3", "not a finite number"]),
    "outside domain": (f"{HEADER}\n{GOOD_ROW}\n{GOOD_ROW}\n-40,-20,-5,0,0,0\n", None, [],
                       ["configs.csv: row 4", "snap-free domain", "0 <= beta2 - beta1 <= 15 violated"]),
    "alpha outside domain": (f"{HEADER}\n-20,-10,-5,0,4,0\n", None, [],
                             ["configs.csv: row 2", "alpha2 <= 3.14159 violated"]),
    "tube order": (f"{HEADER}\n{GOOD_ROW}\n-5,-10,-5,0,0,0\n", None, ["--allow-outside-domain"],
                   ["configs.csv: row 3", "tube order violated: need beta1 <= beta2"]),
    "robot unknown key": (f"{HEADER}\n{GOOD_ROW}\n", broken_robot("name: nominal", "name: x\ncolour: red"),
                          [], ["robot.yaml:3", "colour", "unknown key"]),
    "robot negative length": (f"{HEADER}\n{GOOD_ROW}\n",
                              broken_robot("curved_length_mm: 41.0", "curved_length_mm: -41.0"), [],
                              ["robot.yaml:4", "tubes[0].curved_length_mm",
                               "outside the physical range [0, 2000]"]),
    "robot ID >= OD": (f"{HEADER}\n{GOOD_ROW}\n",
                       broken_robot("inner_diameter_mm: 0.70", "inner_diameter_mm: 0.95"), [],
                       ["robot.yaml:6", "tubes[1].inner_diameter_mm", "must be < outer diameter"]),
    "robot malformed": (f"{HEADER}\n{GOOD_ROW}\n", "name: x\ntubes: [\n  - {a: 1\n", [],
                        ["robot.yaml", "malformed YAML"]),
    "robot missing": (f"{HEADER}\n{GOOD_ROW}\n", None, ["--robot", "nowhere.yaml"],
                      ["nowhere.yaml", "file not found"]),
    "unknown backend": (f"{HEADER}\n{GOOD_ROW}\n", None, ["--backend", "nonsense"],
                        ["--backend", "'nonsense'", "cosserat"]),
}


def assert_one_line_error(rc: int, out: str, err: str, fragments: list[str]) -> None:
    assert rc == 2, err
    assert out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("ctrplan: error: ")
    for fragment in fragments:
        assert fragment in lines[0]


@pytest.mark.parametrize("command", ["fk", "shape"])
@pytest.mark.parametrize("case", list(CONFIG_CASES))
def test_bad_input_fails_cleanly_and_writes_nothing(tmp_path, capsys, command, case):
    configs_text, robot_text, extra, fragments = CONFIG_CASES[case]
    configs = tmp_path / "configs.csv"
    if configs_text is not None:
        configs.write_text(configs_text)
    args = [command, str(configs), "-o", str(tmp_path / "out.csv"), *extra]
    if robot_text is not None:
        (tmp_path / "robot.yaml").write_text(robot_text)
        args += ["--robot", str(tmp_path / "robot.yaml")]
    before = sorted(tmp_path.iterdir())
    rc = main(args)
    out, err = capsys.readouterr()
    assert_one_line_error(rc, out, err, fragments)
    assert sorted(tmp_path.iterdir()) == before  # no output, no temporary file


def test_shape_needs_two_points(tmp_path, capsys):
    rc = main(["shape", str(EXAMPLE), "--points", "1", "-o", str(tmp_path / "out.csv")])
    assert_one_line_error(rc, *capsys.readouterr(), ["points", "at least 2"])
    assert not (tmp_path / "out.csv").exists()


def test_missing_output_directory_is_reported_before_any_work(tmp_path, capsys):
    rc = main(["fk", str(EXAMPLE), "-o", str(tmp_path / "no" / "out.csv")])
    assert_one_line_error(rc, *capsys.readouterr(), ["out.csv", "does not exist"])


@pytest.mark.parametrize(("args", "fragments"), [
    (["--backend", "cosserat,nonsense"], ["--backend", "'nonsense'"]),
    (["--backend", "cosserat,"], ["--backend", "comma-separated"]),
    (["--points", "30,abc"], ["--points", "'abc'", "not an integer"]),
    (["--points", "1"], ["--points", "below the minimum 2"]),
    (["--n", "0"], ["--n", "at least 1"]),
])
def test_bench_kinematics_bad_options(tmp_path, capsys, args, fragments):
    rc = main(["bench", "kinematics", "--out", str(tmp_path / "bench"), *args])
    assert_one_line_error(rc, *capsys.readouterr(), fragments)
    assert not (tmp_path / "bench").exists()


def test_bench_out_that_is_a_file(tmp_path, capsys):
    (tmp_path / "taken").write_text("x")
    rc = main(["bench", "kinematics", "--n", "1", "--out", str(tmp_path / "taken")])
    assert_one_line_error(rc, *capsys.readouterr(), ["--out", "not a directory"])


def test_console_script_exit_code_and_single_line(tmp_path):
    """The installed `ctrplan` executable itself: exit 2, one line, no traceback."""
    script = Path(sys.executable).with_name("ctrplan")
    assert script.exists(), f"console script not installed next to {sys.executable}"
    configs = tmp_path / "configs.csv"
    configs.write_text(f"{HEADER}\n{GOOD_ROW}\n-20,-10,-5,0,zero,0\n")
    result = subprocess.run([str(script), "fk", str(configs)], capture_output=True, text=True,
                            timeout=300, check=False)
    assert_one_line_error(result.returncode, result.stdout, result.stderr,
                          ["configs.csv: row 3", "alpha2", "'zero'"])
    assert "Traceback" not in result.stderr


@pytest.mark.parametrize(("args", "option"), [
    (["fk", str(EXAMPLE), "--bogus"], "--bogus"),
    (["shape", str(EXAMPLE), "--points", "many"], "--points"),
    (["bench", "kinematics", "--n", "lots"], "--n"),
])
def test_usage_errors_exit_2_without_traceback(capsys, args, option):
    rc = main(args)
    out, err = capsys.readouterr()
    assert rc == 2 and out == ""
    assert option in err and "Traceback" not in err


def test_no_arguments_prints_help_without_traceback(capsys):
    rc = main([])
    out, err = capsys.readouterr()
    assert rc in (0, 2)
    assert "fk" in out and "Traceback" not in err
