"""Bad input through the real CLI: one line on stderr naming file/row/field, exit 2, nothing written."""

from __future__ import annotations

import subprocess
import sys
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from ctrplan.cli.app import main
from ctrplan.model.robot import JOINT_NAMES
from tests.paths import REPO

HEADER = ",".join(JOINT_NAMES)
GOOD_ROW = "-20,-10,-5,0.1,0.2,0.3"
EXAMPLE = REPO / "examples" / "configs.csv"
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
    "long row": (f"{HEADER}\n{GOOD_ROW}\n{GOOD_ROW},7\n", None, [],
                 ["configs.csv: row 3", "expected 6 fields (as the header), got 7"]),
    "non-numeric cell": (f"{HEADER}\n{GOOD_ROW}\n-20,-10,-5,0,abc,0\n", None, [],
                         ["configs.csv: row 3", "alpha2", "'abc'", "not a number"]),
    "nan cell": (f"{HEADER}\nnan,-10,-5,0,0,0\n", None, [],
                 ["configs.csv: row 2", "beta1", "not a finite number"]),
    "inf cell": (f"{HEADER}\n{GOOD_ROW}\n-20,-10,-5,0,0,-inf\n", None, [],
                 ["configs.csv: row 3", "alpha3", "not a finite number"]),
    "outside domain": (f"{HEADER}\n{GOOD_ROW}\n{GOOD_ROW}\n-40,-20,-5,0,0,0\n", None, [],
                       ["configs.csv: row 4", "snap-free domain", "0 <= beta2 - beta1 <= 15 violated"]),
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
    "robot not a Poisson ratio": (f"{HEADER}\n{GOOD_ROW}\n",  # E / (2 G) - 1 = 50 / 32 - 1 = 0.5625
                                  broken_robot("shear_modulus_gpa: 19.23", "shear_modulus_gpa: 16.0"), [],
                                  ["robot.yaml:5", "tubes[0].shear_modulus_gpa", "(-1, 0.5]"]),
    "robot tubes not nested": (f"{HEADER}\n{GOOD_ROW}\n",  # tube 1 OD 0.75 mm > tube 2 ID 0.70 mm
                               broken_robot("outer_diameter_mm: 0.50", "outer_diameter_mm: 0.75"), [],
                               ["robot.yaml:6", "tubes[1].inner_diameter_mm", "cannot hold tube 1"]),
    "robot domain past tube 1": (f"{HEADER}\n{GOOD_ROW}\n",  # L1 - L2 = 210 - 165 = 45 mm
                                 broken_robot("beta2_minus_beta1_mm: [0.0, 15.0]",
                                              "beta2_minus_beta1_mm: [30.0, 50.0]"), [],
                                 ["robot.yaml:14", "domain.beta2_minus_beta1_mm",
                                  "tube 2's tip past tube 1's", "L1 - L2 = 45 mm"]),
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


SCENE = str(REPO / "scenes" / "open.yaml")


@pytest.mark.parametrize(("args", "fragments"), [
    (["plan", SCENE, "--out", "/proc/ctrplan_out"], ["--out", "cannot create /proc/ctrplan_out"]),
    (["plan", "unread.yaml", "--out", "/proc/ctrplan_out"], ["--out"]),  # before the scene is read
    *[(command + ["--seed", "-1"], ["--seed", "greater than or equal to 0"]) for command in (
        ["plan", SCENE], ["stability"], ["train"], ["bench", "kinematics"], ["bench", "plan", SCENE],
        ["diagnose", "data.csv"])],
    *[(["train", "--time-limit", v], ["--time-limit", "must be a positive duration"])
      for v in ("0", "-1", "nan")],
    (["train", "--steps", "0"], ["--steps", "greater than or equal to 1"]),
    (["train", "--threads", "0"], ["--threads", "greater than or equal to 1"]),
])
def test_bad_option_fails_cleanly_and_writes_nothing(tmp_path, capsys, monkeypatch, args, fragments):
    """One line, exit 2, before any work: nothing in the working directory (where runs/ and models/
    would go) or at the given --out."""
    monkeypatch.chdir(tmp_path)
    rc = main(args)
    assert_one_line_error(rc, *capsys.readouterr(), fragments)
    assert list(tmp_path.iterdir()) == []
    assert not Path("/proc/ctrplan_out").exists()


def test_robot_domain_is_refused_at_load_so_sampling_stays_physical(tmp_path):
    """The domain box may only hold configurations `check_joints` accepts: then `sample_joints`
    never returns an impossible one. At the limit (beta2 - beta1 <= L1 - L2 = 45 mm) it loads."""
    from ctrplan.base.errors import InputError
    from ctrplan.model.robot import Robot

    path = tmp_path / "robot.yaml"
    for old, new, limit in (
            ("beta3_mm: [-10.0, 0.0]", "beta3_mm: [-10.0, 2.0]", "need beta3 <= 0"),
            ("beta3_mm: [-10.0, 0.0]", "beta3_mm: [-110.0, 0.0]", "need beta3 > -L3 = -110 mm"),
            ("beta3_minus_beta2_mm: [0.0, 55.0]", "beta3_minus_beta2_mm: [0.0, 56.0]",
             "need beta3 - beta2 <= L2 - L3 = 55 mm")):
        path.write_text(broken_robot(old, new))
        with pytest.raises(InputError) as info:
            Robot.load(str(path))
        assert str(info.value).endswith(limit)
    path.write_text(broken_robot("beta2_minus_beta1_mm: [0.0, 15.0]", "beta2_minus_beta1_mm: [30.0, 45.0]"))
    robot = Robot.load(str(path))
    q = robot.sample_joints(2000, rng=0)
    robot.check_joints(q)  # raises for an impossible configuration
    assert np.max(q[:, 1] - q[:, 0]) > 44.9


def test_missing_pinn_for_the_robot_in_use_says_so(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "robot.yaml").write_text(broken_robot("name: nominal", "name: mine")
                                         .replace("curvature_1_per_m: 28.0", "curvature_1_per_m: 30.0"))
    rc = main(["fk", str(EXAMPLE), "--backend", "pinn", "--robot", "robot.yaml", "-o", "out.csv"])
    assert_one_line_error(rc, *capsys.readouterr(), [
        "--backend pinn: no PINN model trained for robot 'mine'", f"in {tmp_path / 'models'} or among "
        "the shipped models", "ctrplan train --robot ROBOT.yaml --name mine_pinn"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["robot.yaml"]


def test_fk_rejects_underscore_cell(tmp_path, capsys):
    configs = tmp_path / "c.csv"
    configs.write_text(",".join(JOINT_NAMES) + "\n-2_0,-10,-5,0,0,0\n")
    out = tmp_path / "o.csv"
    assert main(["fk", str(configs), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "c.csv: row 2: beta1 = '-2_0' is not a number" in err[0]
    assert not out.exists()
