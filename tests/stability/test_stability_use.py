"""Elastic stability where users meet it: certificates, planning validity, `fk`'s stable column and
the `ctrplan stability` command."""

from __future__ import annotations

import json
import math

import numpy as np

from ctrplan.cli.app import main
from ctrplan.kinematics import CosseratBackend
from ctrplan.kinematics.stability import critical_length_mm, is_certified, user_certificate_dir
from ctrplan.model.robot import Robot
from ctrplan.planning import plan, validate_path
from ctrplan.planning.model import PlanningModel
from ctrplan.planning.validity import ConfigurationChecker
from ctrplan.scene.loader import load_scene
from tests.model.test_any_robot import overlapping_pair
from tests.paths import REPO

HALF_TURN = np.array([0.0, 0.0, 0.0, math.pi])


def snapping_pair_file(tmp_path) -> str:
    """A robot file of two overlapping curved tubes 10 % longer than the critical length."""
    import yaml

    r = overlapping_pair(1.1 * critical_length_mm(overlapping_pair(50.0)))
    path = tmp_path / "snapping_pair.yaml"
    path.write_text(yaml.safe_dump(r.to_dict()))
    return str(path)


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
    # without the stability test
    assert ConfigurationChecker(PlanningModel.of(scene, plain)).is_valid(HALF_TURN)
    checked = ConfigurationChecker(PlanningModel.of(scene, plain.checking_stability()))
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


#: Overlap 1.3 times the critical length: at half a turn the straight-twist equilibrium has the
#: Jacobi measure cos(1.3 pi / 2) = -0.45 < 0 (Dupont et al. 2010; tests/model/test_any_robot.py checks the
#: solver against it), and cold solves from 2.8 rad to pi end on that unstable branch.
SNAP_FACTOR = 1.3


def snapper_scene(tmp_path, alpha2_target: float):
    """A scene for two overlapping curved tubes that snap near half a turn, only alpha2 free
    (0 .. pi), start at alpha2 = 0, target (3 mm) where the exact tip is at ``alpha2_target``."""
    import yaml

    robot = overlapping_pair(SNAP_FACTOR * critical_length_mm(overlapping_pair(50.0)))
    doc = {**robot.to_dict(), "name": "snapper",
           "domain": {"beta2_mm": [0.0, 0.0], "beta2_minus_beta1_mm": [0.0, 0.0], "alpha1_rad": [0.0, 0.0],
                      "alpha2_rad": [0.0, math.pi]}}
    (tmp_path / "snapper.yaml").write_text(yaml.safe_dump(doc))
    tip = CosseratBackend(robot).forward(np.array([0.0, 0.0, 0.0, alpha2_target]), points=2).tip_mm[0]
    path = tmp_path / "snap_scene.yaml"
    path.write_text(f"name: snap\nrobot: snapper.yaml\nbase_pose: {{position: [0, 0, 0]}}\nobstacles: []\n"
                    f"target: {{point: {tip.tolist()}, tolerance_mm: 3.0}}\nstart: [0, 0, 0, 0]\n")
    scene = load_scene(path)
    assert not is_certified(scene.robot)
    return scene


def test_plan_never_uses_a_configuration_that_snaps(tmp_path, private_cache):
    """The target is where the tip is at half a turn: every configuration that gets the tip there is
    unstable, so the planner finds no goal (it never hands exact validation an unstable path);
    the same robot reaches a target on the stable side."""
    assert math.cos(SNAP_FACTOR * math.pi / 2) < 0
    res = plan(snapper_scene(tmp_path, math.pi), "cosserat", seed=0, time_limit_s=3.0)
    assert not res.solved and res.validated is None, res.message
    assert "elastically unstable" in res.message
    stable = plan(snapper_scene(tmp_path, 1.0), "cosserat", seed=0, time_limit_s=3.0)
    assert stable.solved and stable.validated.stable, stable.message


def test_exact_validation_fails_every_unstable_state(tmp_path, private_cache):
    """From 2.9 rad to half a turn every state converges, is collision-free (no obstacles) and is
    unstable: each must fail, and the path with them."""
    scene = snapper_scene(tmp_path, math.pi)
    rep = validate_path(scene, np.array([[0.0, 0.0, 0.0, 2.9], [0.0, 0.0, 0.0, math.pi]])).report
    assert rep.converged and rep.tip_in_target
    assert not rep.stable and not rep.ok
    assert rep.colliding_states == list(range(rep.states))
    assert not rep.collision_free and "unstable" in rep.first_collision.why
    control = validate_path(scene, np.array([[0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])).report
    assert control.stable and control.collision_free and control.colliding_states == []


def test_a_certificate_counts_only_for_its_robot_and_a_snap_free_verdict(tmp_path, private_cache):
    robot = Robot.load(snapping_pair_file(tmp_path))
    path = user_certificate_dir() / f"{robot.fingerprint}.json"
    path.parent.mkdir(parents=True)
    for doc, certified in (({"fingerprint": robot.fingerprint, "snap_free": True}, True),
                           ({"fingerprint": Robot.nominal().fingerprint, "snap_free": True}, False),
                           ({"fingerprint": robot.fingerprint, "snap_free": False}, False),
                           ({"fingerprint": robot.fingerprint}, False)):
        path.write_text(json.dumps(doc))
        assert is_certified(robot) is certified, doc
    path.unlink()
    assert not is_certified(robot)
