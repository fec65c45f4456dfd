"""Stability advice and relative-rotation limits (issue 41, item 8): `ctrplan stability` names the
relative rotation where the robot snaps and the robot-file limit that keeps the safe part; a robot
file may limit ``alphaJ - alphaI`` as a box coordinate of the domain, which sampling (exact: uniform
in the limited set), planning, PINN training and the stability sweeps honour. Checked against the
two-tube closed form (fully overlapping curved tubes above the critical length snap near
alpha2 - alpha1 = pi, Dupont et al. 2010): the limit the advice gives makes that robot snap-free."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest
import torch
import yaml

from ctrplan.base.errors import InputError
from ctrplan.base.yamlio import load_yaml
from ctrplan.cli.app import main
from ctrplan.kinematics.stability import check_domain, critical_length_mm
from ctrplan.model.robot import JointDomain, Robot, robot_from_yaml
from ctrplan.planning.space import BoxSpace
from ctrplan.training.trainer import Sampler
from tests.model.test_any_robot import overlapping_pair
from tests.paths import REPO


def limited_nominal(tmp_path, domain: str) -> Robot:
    path = tmp_path / "limited.yaml"
    path.write_text((REPO / "ctrplan" / "data" / "nominal.yaml").read_text().replace(
        "  alpha_rad: [-3.141592653589793, 3.141592653589793]\n",
        "  alpha_rad: [-3.141592653589793, 3.141592653589793]\n" + domain))
    return robot_from_yaml(load_yaml(path))


def test_a_relative_rotation_limit_is_a_box_coordinate_sampled_exactly(tmp_path):
    robot = limited_nominal(tmp_path, "  alpha3_minus_alpha2_rad: [-2.0, 1.0]\n")
    assert robot.domain.names[3:] == ("alpha1", "alpha2", "alpha3 - alpha2")
    assert robot.fingerprint != Robot.nominal().fingerprint  # another domain, another robot
    q = robot.sample_joints(40_000, 0)
    d = q[:, 5] - q[:, 4]
    assert d.min() >= -2.0 and d.max() <= 1.0
    # uniform in the limited set: the difference uniform on [-2, 1], alpha2 uniform on [-pi, pi]
    shares = np.histogram(d, bins=6, range=(-2.0, 1.0))[0] / len(d)
    assert shares == pytest.approx(np.full(6, 1 / 6), abs=0.01)
    assert np.mean(q[:, 4]) == pytest.approx(0.0, abs=0.03)
    robot.check_joints(q[:100])
    bad = q[0].copy()
    bad[5] = bad[4] + 1.5
    with pytest.raises(InputError, match="alpha3 - alpha2 <= 1 violated"):
        robot.check_joints(bad)
    again = tmp_path / "again.yaml"
    robot.save(again)
    assert Robot.load(again).fingerprint == robot.fingerprint  # the file form keeps the key


def test_planning_and_training_honour_the_limit(tmp_path):
    robot = limited_nominal(tmp_path, "  alpha2_minus_alpha1_rad: [-1.5, 1.5]\n")
    space = BoxSpace.for_robot(robot)
    assert space.names[3:] == ("alpha1_mm", "alpha2_minus_alpha1_mm", "alpha3_mm")
    assert space.wraps.tolist() == [False, False, False, True, False, True]
    q = space.sample(2000, np.random.default_rng(1))
    assert np.all(np.abs(q[:, 4] - q[:, 3]) <= 1.5 + 1e-9) and np.all(space.contains(q))
    np.testing.assert_allclose(space.to_joints(space.to_coords(q)), q, atol=1e-9)
    # alpha1 one turn on is the same robot: alpha2 turns with it, the difference is kept
    turned = space.unwrap(np.stack([q[0], q[0] + [0, 0, 0, 2 * math.pi, 2 * math.pi, 0]]))
    np.testing.assert_allclose(turned[1], q[0], atol=1e-9)
    joints = Sampler(robot, seed=0, device=torch.device("cpu")).joints(5000, torch.Generator().manual_seed(0))
    joints = joints.numpy().astype(float)
    assert np.all(np.abs(joints[:, 4] - joints[:, 3]) <= 1.5 + 1e-5)
    assert np.abs(joints[:, 4] - joints[:, 3]).max() > 1.4  # the whole limited set, not less


@pytest.mark.parametrize(("fragment", "expect"), [
    ("  alpha2_minus_alpha1_rad: [-1.0, 1.0]\n  alpha2_rad: [-1, 1]\n", "tube 2's rotation is limited twice"),
    ("  alpha1_minus_alpha2_rad: [-1.0, 1.0]\n", "domain.alpha1_minus_alpha2_rad: unknown key"),
    ("  alpha3_minus_alpha1_rad: [1.0, -1.0]\n", "lower bound 1 exceeds upper bound -1"),
    ("  alpha3_minus_alpha1_rad: [-7.0, 1.0]\n", "rotations must lie within"),
])
def test_bad_relative_limits_are_one_error_naming_the_key(tmp_path, fragment, expect):
    with pytest.raises(InputError, match=expect):
        limited_nominal(tmp_path, fragment)


def test_stability_advice_names_the_snap_and_its_limit_makes_the_robot_snap_free():
    r = overlapping_pair(1.1 * critical_length_mm(overlapping_pair(50.0)))
    report = check_domain(r, n=6, steps=37, seed=1)
    advice = report.advice
    assert not report.snap_free and advice is not None
    assert advice.coordinate == "alpha2 - alpha1" and advice.key == "alpha2_minus_alpha1_rad"
    assert math.degrees(advice.near) > 150  # the closed form: near a half turn
    assert "snaps near alpha2 - alpha1 = +-" in advice.text and advice.kept_share > 0.8
    lo, hi = advice.interval
    assert -math.pi < lo < 0 < hi < math.pi and lo == -hi
    limited = replace(r, domain=JointDomain(r.domain.bounds[:3] + ((lo, hi),), (-1, 0)), name="limited")
    assert check_domain(limited, n=6, steps=37, seed=2).snap_free
    assert check_domain(overlapping_pair(0.9 * critical_length_mm(overlapping_pair(50.0))), n=4,
                        steps=19).advice is None


def test_stability_command_prints_the_advice(tmp_path, capsys):
    r = overlapping_pair(1.1 * critical_length_mm(overlapping_pair(50.0)))
    path = tmp_path / "pair.yaml"
    path.write_text(yaml.safe_dump(r.to_dict()))
    assert main(["stability", "--robot", str(path), "--n", "4", "--steps", "37", "--out",
                 str(tmp_path / "out"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["snap_free"] is False and doc["advice"]["key"] == "alpha2_minus_alpha1_rad"
    assert main(["stability", "--robot", str(path), "--n", "4", "--steps", "37", "--out",
                 str(tmp_path / "out")]) == 0
    err = capsys.readouterr().err
    assert "advice: snaps near alpha2 - alpha1" in err and "alpha2_minus_alpha1_rad: [" in err


def test_write_robot_writes_the_limited_robot_and_certifies_it(tmp_path, capsys):
    """`--write-robot`: the pair above its critical length (it snaps near a half turn, the closed form)
    is written with the advised limit and that robot is checked snap-free in the same run; a snap-free
    robot writes nothing."""
    r = overlapping_pair(1.1 * critical_length_mm(overlapping_pair(50.0)))
    path, written = tmp_path / "pair.yaml", tmp_path / "out" / "pair_snapfree.yaml"
    path.write_text(yaml.safe_dump(r.to_dict()))
    assert main(["stability", "--robot", str(path), "--n", "6", "--steps", "37", "--seed", "1", "--out",
                 str(tmp_path / "out"), "--write-robot", str(written), "--json"]) == 0
    limited = json.loads(capsys.readouterr().out)["limited_robot"]
    assert limited["snap_free"] is True and limited["file"] == str(written)
    robot = Robot.load(written)
    lo, hi = robot.domain.to_dict()["alpha2_minus_alpha1_rad"]
    assert -math.pi < lo < -math.pi / 2 and hi == -lo   # the safe part: short of the half turn
    assert robot.name == f"{r.name}_snapfree" and robot.fingerprint == limited["fingerprint"]
    assert robot.tubes == r.tubes
    safe = overlapping_pair(0.9 * critical_length_mm(overlapping_pair(50.0)))
    path.write_text(yaml.safe_dump(safe.to_dict()))
    other = tmp_path / "none.yaml"
    assert main(["stability", "--robot", str(path), "--n", "4", "--steps", "19", "--out",
                 str(tmp_path / "o2"), "--write-robot", str(other)]) == 0
    assert "nothing to limit; wrote nothing" in capsys.readouterr().err and not other.exists()
