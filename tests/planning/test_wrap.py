"""Rotations wrap where the interval is a full turn (issue 41, item 4): one turn on is the same robot,
and every move between two configurations turns such a tube the short way -- the planning metric,
interpolation, densified validation, the shortcut, the corridor planner and the domain check agree;
a narrower interval (an actuator's limit) stays flat."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ctrplan.base.errors import DomainError
from ctrplan.base.yamlio import YamlDoc
from ctrplan.kinematics import CosseratBackend
from ctrplan.model.robot import JointDomain, Robot
from ctrplan.planning import ConfigurationChecker, PlanningModel
from ctrplan.planning.planner import search
from ctrplan.planning.shortcut import shortcut_path
from ctrplan.planning.space import BoxSpace
from ctrplan.scene.loader import scene_from_yaml

BETAS = [-40.0, -30.0, -5.0]


def q_of(alpha: float) -> np.ndarray:
    return np.array(BETAS + [alpha] * 3)


def test_the_metric_and_interpolation_go_the_short_way():
    space = BoxSpace.for_robot(Robot.nominal(), mm_per_rad=40.0)
    a, b = q_of(3.0), q_of(-3.0)
    short = 2 * math.pi - 6.0  # rad per tube
    assert space.distance(a, b) == pytest.approx(40.0 * short * math.sqrt(3))
    mid = space.interpolate(a, b, np.array([0.5]))[0]
    np.testing.assert_allclose(mid[3:], 3.0 + short / 2)  # through pi, not through 0
    dense = space.densify(np.stack([a, b, a]), resolution=1.0)
    assert np.abs(np.diff(dense[:, 3:], axis=0)).max() < 0.05  # continuous, and short
    assert dense[:, 3].max() == pytest.approx(3.0 + short) and dense[-1, 3] == pytest.approx(3.0)
    path = space.unwrap(np.stack([a, b, q_of(-1.0)]))
    np.testing.assert_allclose(path[:, 3], [3.0, 2 * math.pi - 3.0, 2 * math.pi - 1.0])
    y = space.clip(space.to_coords(q_of(4.0)))
    assert np.all(y <= space.upper) and space.to_joints(y)[3] == pytest.approx(4.0 - 2 * math.pi)
    assert space.contains(q_of(4.0)) and space.contains(q_of(-7.0))


def test_a_narrower_interval_is_a_limit_and_does_not_wrap():
    robot = Robot.nominal()
    narrow = robot.with_changes(domain=JointDomain(robot.domain.bounds[:3] + ((-3.0, 3.0),) * 3))
    space = BoxSpace.for_robot(narrow)
    assert not space.wraps.any()
    assert space.distance(q_of(2.9), q_of(-2.9)) == pytest.approx(40.0 * 5.8 * math.sqrt(3))
    with pytest.raises(DomainError):
        narrow.check_joints(q_of(4.0))
    robot.check_joints(q_of(4.0))  # the full turn: 4 rad is -2.28 rad
    lo, hi = robot.domain.box_lower.copy(), robot.domain.box_upper.copy()
    lo[3], hi[3] = -1.0, 1.0  # a scene's joint_limits narrow alpha1 only
    scene_space = BoxSpace(robot.domain, 40.0, tuple(lo), tuple(hi))
    assert scene_space.wraps.tolist() == [False] * 3 + [False, True, True]


def test_the_shortcut_moves_the_short_way():
    space = BoxSpace.for_robot(Robot.nominal())
    y = space.to_coords(space.unwrap(np.stack([q_of(3.0), q_of(3.1), q_of(-3.1), q_of(-3.0)])))
    states = []

    def valid(batch):
        states.append(space.to_joints(batch))
        return np.ones(len(batch), dtype=bool)

    cut = shortcut_path(y, valid, 1.0, space.difference)
    assert cut.vertices.tolist() == [0, 3]
    assert np.all(np.concatenate(states)[:, 3] >= 3.0 - 1e-9)  # never through 0


@pytest.fixture(scope="module")
def ring_scene():
    """Base at the origin, no obstacle but a ball where the tip is when the whole robot is turned
    to alpha = 0: from alpha = 3 to alpha = -3 the long way (through 0) hits it, the short way
    (through pi) is free."""
    robot = Robot.nominal()
    tip = CosseratBackend(robot).forward(q_of(0.0), points=2).tip_mm[0]
    doc = YamlDoc(data={"robot": "nominal", "base_pose": {"position": [0.0, 0.0, 0.0]},
                        "obstacles": [{"name": "ball", "sphere": {"center": tip.tolist(), "radius": 6.0}}],
                        "target": {"point": tip.tolist(), "tolerance_mm": 2.0},
                        "start": q_of(3.0).tolist(), "planner": {"seed": 0}},
                  path=__import__("pathlib").Path("ring.yaml"), lines={})
    return scene_from_yaml(doc)


def test_the_corridor_planner_turns_the_short_way_round(ring_scene):
    checker = ConfigurationChecker(PlanningModel.build(ring_scene, CosseratBackend(ring_scene.robot)))
    assert not checker.is_valid(q_of(0.0)) and checker.is_valid(q_of(-3.0))
    out = search(checker, planner="corridor", goal_q=q_of(-3.0), seed=1, max_states=5_000, simplify=False)
    assert out.exact
    path = checker.space.unwrap(out.path_q)
    assert np.ptp(path[:, 3]) < 0.5  # 0.28 rad the short way; the long way is 6 rad and blocked
    assert checker.space.distance(path[-1], q_of(-3.0)) < 1e-6


def test_fk_takes_an_angle_one_turn_on_as_the_same_robot(tmp_path, capsys):
    """alpha2 = 4 rad lies outside [-pi, pi] as written but inside the full-turn domain: the same tip
    as 4 - 2 pi (the row was refused before rotations wrapped)."""
    from ctrplan.cli.app import main

    configs = tmp_path / "configs.csv"
    configs.write_text(f"beta1,beta2,beta3,alpha1,alpha2,alpha3\n-20,-10,-5,0,4,0\n"
                       f"-20,-10,-5,0,{4 - 2 * math.pi!r},0\n")
    capsys.readouterr()
    assert main(["fk", str(configs), "--backend", "cosserat"]) == 0
    rows = [line.split(",") for line in capsys.readouterr().out.strip().splitlines()[1:]]
    np.testing.assert_allclose(np.array(rows[0][6:9], dtype=float), np.array(rows[1][6:9], dtype=float),
                               atol=1e-9)
