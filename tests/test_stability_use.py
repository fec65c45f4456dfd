"""Elastic stability where users meet it: certificates, planning validity, `fk`'s stable column and
the `ctrplan stability` command."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from test_any_robot import overlapping_pair

from ctrplan.cli import main
from ctrplan.kinematics import CosseratBackend
from ctrplan.planning.validity import ConfigurationChecker
from ctrplan.robot import Robot
from ctrplan.scene import load_scene
from ctrplan.stability import critical_length_mm, is_certified

REPO = __import__("pathlib").Path(__file__).resolve().parents[1]
HALF_TURN = np.array([0.0, 0.0, 0.0, math.pi])


def snapping_pair_file(tmp_path) -> str:
    """A robot file of two overlapping curved tubes 10 % longer than the critical length."""
    import yaml

    r = overlapping_pair(1.1 * critical_length_mm(overlapping_pair(50.0)))
    path = tmp_path / "snapping_pair.yaml"
    path.write_text(yaml.safe_dump(r.to_dict()))
    return str(path)


@pytest.fixture()
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    return tmp_path / "cache"


def test_shipped_robots_are_certified_and_others_are_not(private_cache):
    assert is_certified(Robot.nominal())
    assert is_certified(Robot.load(REPO / "examples" / "robots" / "two_tube.yaml"))
    nominal = Robot.nominal()
    stiffer = nominal.with_changes(tubes=tuple(
        t.__class__(**{**t.__dict__, "curvature_per_mm": t.curvature_per_mm * 1.5}) for t in nominal.tubes))
    assert not is_certified(stiffer)


def test_planning_validity_rejects_an_unstable_configuration(tmp_path, private_cache):
    robot_file = snapping_pair_file(tmp_path)
    scene_file = tmp_path / "scene.yaml"
    scene_file.write_text(f"name: pair\nrobot: {robot_file}\nbase_pose: {{position: [0, 0, 0]}}\n"
                          "obstacles: []\ntarget: {point: [0.0, 30.0, 70.0], tolerance_mm: 3.0}\n"
                          "start: [0, 0, 0, 0]\n")
    scene = load_scene(scene_file)
    assert not is_certified(scene.robot)
    plain = CosseratBackend(scene.robot)
    assert ConfigurationChecker(scene, plain).is_valid(HALF_TURN)  # without the stability test
    checked = ConfigurationChecker(scene, plain.checking_stability())
    assert not checked.is_valid(HALF_TURN)
    assert checked.is_valid(np.array([0.0, 0.0, 0.0, 1.0]))


def test_fk_reports_stability(tmp_path, capsys, private_cache):
    configs = tmp_path / "configs.csv"
    configs.write_text("beta1,beta2,alpha1,alpha2\n0,0,0,3.14159265\n0,0,0,1.0\n")
    assert main(["fk", str(configs), "--robot", snapping_pair_file(tmp_path)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0].endswith("converged,stable")
    assert [line.split(",")[-2:] for line in lines[1:]] == [["1", "0"], ["1", "1"]]


def test_stability_command_finds_the_snap_and_certifies_a_snap_free_robot(tmp_path, capsys, private_cache):
    rc = main(["stability", "--robot", snapping_pair_file(tmp_path), "--n", "4", "--steps", "37",
               "--out", str(tmp_path / "out"), "--json"])
    doc = json.loads(capsys.readouterr().out)
    assert rc == 0
    assert doc["snap_free"] is False and doc["example_q"] is not None and doc["checked"] == 4 * 37
    assert 0 < doc["unstable_fraction"] < 1
    assert (tmp_path / "out" / "stability.png").stat().st_size > 10_000
    assert "certificate" not in doc

    safe = Robot.nominal().with_changes(name="nominal_copy", joint_offset=(0.0, 0.0, 0.0, 0.0, 0.0, 0.01))
    import yaml

    path = tmp_path / "nominal_copy.yaml"
    path.write_text(yaml.safe_dump(safe.to_dict()))
    assert not is_certified(safe)
    assert main(["stability", "--robot", str(path), "--n", "3", "--steps", "9", "--out",
                 str(tmp_path / "out2"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["snap_free"] is True
    assert is_certified(safe)


def test_stability_command_bad_input(tmp_path, capsys):
    assert main(["stability", "--n", "0", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--n" in err[0]
    assert not (tmp_path / "x").exists()
