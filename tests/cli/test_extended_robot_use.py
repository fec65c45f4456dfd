"""An extended robot (with a `calibration:` section from `ctrplan diagnose`) is applied or refused with
one line -- never silently ignored -- by `plan` and `train` (`fk`/`shape` apply it: see
test_calibration_*)."""

from __future__ import annotations

from pathlib import Path

import yaml

from ctrplan.cli.app import main
from ctrplan.model.robot import Robot
from tests.paths import REPO


def extended_robot(tmp_path: Path) -> Path:
    d = Robot.nominal().to_dict()
    d["name"] = "extended"
    d["calibration"] = {"registration": {"rotation_vector_rad": [0.0, 0.0, 0.1],
                                         "translation_mm": [1.0, 0.0, 0.0]},
                        "backlash_rad": [0.01, 0.0, 0.0]}
    path = tmp_path / "extended.yaml"
    path.write_text(yaml.safe_dump(d))
    return path


def one_line_error(capsys, fragment: str) -> None:
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert out == "" and len(lines) == 1 and lines[0].startswith("ctrplan: error: "), err
    assert fragment in lines[0]


def test_plan_refuses_a_robot_with_a_calibration(tmp_path, capsys):
    scene = (REPO / "scenes" / "open.yaml").read_text().replace("robot: nominal",
                                                               f"robot: {extended_robot(tmp_path)}")
    path = tmp_path / "scene.yaml"
    path.write_text(scene)
    assert main(["plan", str(path), "--backend", "cosserat", "--out", str(tmp_path / "out")]) == 2
    one_line_error(capsys, "calibration section")
    assert not (tmp_path / "out").exists()


def test_train_refuses_a_robot_with_a_calibration(tmp_path, capsys):
    assert main(["train", "--robot", str(extended_robot(tmp_path)), "--steps", "1",
                 "--out-dir", str(tmp_path / "models")]) == 2
    one_line_error(capsys, "cannot be used to train")
    models = tmp_path / "models"
    assert not models.exists() or not any(models.iterdir())
