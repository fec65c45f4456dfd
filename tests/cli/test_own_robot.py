"""A researcher's own robot: `plan --robot` replaces the scene's robot, and every "no model for this
robot" message says where the robot came from (--robot or the scene's `robot:` key) and, for a model
written with its own robot file beside it, names that file."""

from __future__ import annotations

import shutil
from pathlib import Path

from ctrplan.cli.app import main
from tests.paths import REPO

SHIPPED = REPO / "ctrplan" / "data" / "models"


def own_robot(folder: Path) -> Path:
    """The nominal robot with a more curved inner tube: another robot, no PINN for it."""
    text = (REPO / "ctrplan" / "data" / "nominal.yaml").read_text()
    path = folder / "mine.yaml"
    path.write_text(text.replace("name: nominal", "name: mine").replace("curvature_1_per_m: 28.0",
                                                                        "curvature_1_per_m: 30.0", 1))
    return path


def one_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_plan_with_another_robot_uses_it_and_says_where_it_came_from(tmp_path, capsys):
    robot = own_robot(tmp_path)
    assert "curvature_1_per_m: 30.0" in robot.read_text()
    capsys.readouterr()
    assert main(["plan", str(REPO / "scenes" / "open.yaml"), "--robot", str(robot)]) == 2
    line = one_line(capsys)
    assert "no PINN model trained for robot 'mine'" in line and "--robot" in line and "`robot:`" in line


def test_a_robot_that_does_not_fit_the_scene_is_one_line_naming_the_key(tmp_path, capsys):
    """The two-tube example is 100 mm long: the open scene's target is out of its reach."""
    capsys.readouterr()
    assert main(["plan", str(REPO / "scenes" / "open.yaml"), "--robot",
                 str(REPO / "examples" / "robots" / "two_tube.yaml"), "--backend", "cosserat"]) == 2
    assert "open.yaml:19: target: out of reach" in one_line(capsys)


def test_a_model_with_its_own_robot_file_names_it(tmp_path, capsys):
    for suffix in (".safetensors", ".json"):
        shutil.copy(SHIPPED / f"pinn_nominal{suffix}", tmp_path / f"tuned{suffix}")
    (tmp_path / "tuned.robot.yaml").write_text((REPO / "ctrplan" / "data" / "nominal.yaml").read_text())
    configs = tmp_path / "q.csv"
    configs.write_text("beta1,beta2,beta3,alpha1,alpha2,alpha3\n-30,-20,-5,0,0,0\n")
    capsys.readouterr()
    code = main(["fk", str(configs), "--backend", "pinn", "--robot", str(own_robot(tmp_path)),
                 "--model", str(tmp_path / "tuned.safetensors")])
    line = one_line(capsys)
    assert code == 2 and f"--robot {tmp_path / 'tuned.robot.yaml'}" in line, line
