"""New-user input pitfalls (issue 10): YAML 1.2 floats and underscores in CSV numbers (a CSV
cell with an underscore at the command line: `tests/cli/test_bad_input.py`)."""

from __future__ import annotations

from importlib import resources

import pytest

from ctrplan.base.dataio import parse_number
from ctrplan.base.errors import InputError
from ctrplan.base.yamlio import load_yaml
from ctrplan.model.robot import Robot

NOMINAL_YAML = resources.files("ctrplan.data").joinpath("nominal.yaml").read_text()


@pytest.mark.parametrize(("text", "value"), [("5e1", 50.0), ("1.0e308", 1.0e308), ("1e-3", 1e-3),
                                             ("-2.5E+3", -2500.0), ("'5e1'", "5e1")])
def test_yaml_reads_yaml12_floats(tmp_path, text, value):
    path = tmp_path / "x.yaml"
    path.write_text(f"a: {text}\n")
    assert load_yaml(path).data["a"] == value


def test_robot_file_with_exponent_numbers_loads(tmp_path):
    path = tmp_path / "robot.yaml"
    path.write_text(NOMINAL_YAML.replace("youngs_modulus_gpa: 50.0", "youngs_modulus_gpa: 5e1")
                    .replace("straight_length_mm: 169.0", "straight_length_mm: 1.69e2"))
    assert Robot.load(str(path)).fingerprint == Robot.nominal().fingerprint


def test_csv_cell_with_underscore_is_rejected():
    with pytest.raises(InputError, match=r"f\.csv: row 3: beta1 = '1_0' is not a number"):
        parse_number("1_0", "f.csv", 3, "beta1")
    assert parse_number(" 1e1 ", "f.csv", 3, "beta1") == 10.0
