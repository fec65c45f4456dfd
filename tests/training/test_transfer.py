"""Transfer learning (issue 40): the distance between robots, the choice of the nearest model, and a
transferred network that keeps the source's layers and frame tube but takes the new robot's box,
lengths and output scales; the frame tube the trainer picks for a robot."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from ctrplan.kinematics.model_file import load_model, shipped_models_dir
from ctrplan.kinematics.pinn_net import PinnNet
from ctrplan.model.robot import Robot
from ctrplan.training.samples import frame_tube
from ctrplan.training.transfer import load_transfer, nearest_model, robot_distance, shape_of
from tests.paths import REPO


def bent(robot: Robot, tube: int, factor: float) -> Robot:
    """``robot`` with tube ``tube``'s pre-curvature times ``factor``."""
    tubes = list(robot.tubes)
    tubes[tube] = replace(tubes[tube], curvature_per_mm=tubes[tube].curvature_per_mm * factor)
    return replace(robot, tubes=tuple(tubes), name=f"{robot.name}_bent")


def test_robot_distance_is_zero_for_the_robot_and_grows_with_the_difference(robot):
    two = Robot.load(REPO / "examples" / "robots" / "two_tube.yaml")
    assert robot_distance(robot, robot) == 0.0
    assert math.isinf(robot_distance(robot, two))
    near, far = bent(robot, 0, 1.2), bent(robot, 0, 2.0)
    # one of 12 tube terms differs: |1.2 - 1| / 1.2 and |2 - 1| / 2, over 12 + 12 terms
    assert robot_distance(robot, near) == pytest.approx(robot_distance(near, robot))
    assert robot_distance(robot, near) == pytest.approx((0.2 / 1.2) / 24)
    assert robot_distance(robot, far) == pytest.approx(0.5 / 24)


def test_the_nearest_model_is_the_shipped_one_of_the_nearest_robot(robot):
    shape = shape_of(PinnNet(robot, harmonics=4))
    found = nearest_model(bent(robot, 0, 1.5), shape)
    assert found is not None and found.weights.parent == shipped_models_dir()
    assert found.card["robot_fingerprint"] == robot.fingerprint  # pinn_nominal or its older twin
    assert found.weights.stem == "pinn_nominal"                   # the more accurate of the two
    assert nearest_model(robot, {**shape, "hidden": 64}) is None


def test_a_transferred_network_keeps_the_layers_and_takes_the_new_robots_box_and_scales(robot):
    target = bent(robot, 2, 3.0)
    source = load_transfer("pinn_nominal", target)
    src_net, _ = load_model("pinn_nominal", robot)
    scales = np.linspace(0.5, 2.0, robot.n_states)
    net = source.apply(PinnNet(target, harmonics=4, scales=scales, frame=source.frame))
    assert source.frame == src_net.frame == 0 and 0 < source.distance < 1
    for k, v in src_net.state_dict().items():
        if k.startswith("mlp."):
            assert torch.equal(net.state_dict()[k], v), k
    torch.testing.assert_close(net.scales, torch.tensor(scales, dtype=torch.float32))
    # the same raw outputs: the state differs from the source's by the ratio of the scales
    q = torch.tensor(robot.sample_joints(4, rng=2), dtype=torch.float32)
    sigma = torch.rand(4)
    with torch.no_grad():
        a, b = src_net.mlp(src_net.features(sigma, q)), net.mlp(net.features(sigma, q))
    torch.testing.assert_close(a, b)


def test_the_frame_tube_is_the_one_whose_rotation_moves_the_tip_most():
    """two_tube: turning tube 2 (outer) moves the tip about three times as far as turning tube 1;
    with only tube 1 rotatable it is tube 1."""
    two = Robot.load(REPO / "examples" / "robots" / "two_tube.yaml")
    assert frame_tube(two, n=50) == 1
    lo, hi = list(two.domain.box_lower), list(two.domain.box_upper)
    hi[3] = lo[3] = 0.0  # alpha2 fixed
    fixed = replace(two, domain=replace(two.domain, bounds=tuple(zip(lo, hi, strict=True))))
    assert frame_tube(fixed, n=10) == 0
