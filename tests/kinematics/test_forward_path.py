"""Backbones along a path (`Backend.forward_path`): the shooting solver starts each state from its
predecessor's solution. On the nominal robot (certified snap-free) that reaches the same equilibria
as cold starts, checked against the independent integrator, in fewer iterations; on a robot that
snaps, continuation follows a branch the cold solve does not find -- why exact checks of an
uncertified robot start cold (`StabilityDecision.continuation`)."""

from __future__ import annotations

import math

import numpy as np

from ctrplan.kinematics import CosseratBackend
from ctrplan.kinematics.stability import critical_length_mm
from ctrplan.model.robot import Robot
from ctrplan.planning import StabilityDecision
from tests.independent.cosserat import Tubes, solve
from tests.planning.test_planning_model import _pair


def test_a_path_solved_by_continuation_reaches_the_independent_solution_in_fewer_iterations():
    robot = Robot.nominal()
    a, b = robot.sample_joints(2, rng=3)
    path = a + np.linspace(0.0, 1.0, 150)[:, None] * (b - a)      # 150 states, neighbours close
    solver = CosseratBackend(robot)
    cold = solver.forward(path, points=30)
    chained = solver.forward_path(path, points=30)
    assert chained.converged.all() and cold.converged.all()
    ref = solve(path, Tubes.paper())
    assert np.max(np.linalg.norm(chained.tips_mm[:, 0] - ref["tips_mm"][:, 0], axis=-1)) < 0.05
    assert np.max(np.abs(chained.positions_mm - cold.positions_mm)) < 1e-6
    assert chained.iterations.mean() < 0.8 * cold.iterations.mean()


def test_continuation_follows_a_snapping_robot_past_its_cold_solution_so_it_is_off_there(tmp_path,
                                                                                          monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))     # no certificate made elsewhere
    robot = _pair(1.1 * critical_length_mm(_pair(50.0)))
    turn = np.zeros((60, 4))
    turn[:, 3] = np.linspace(0.0, math.pi, 60)                    # alpha2: 0 -> a half turn
    solver = CosseratBackend(robot).checking_stability()
    cold = solver.forward(turn[-1:])
    chained = solver.forward_path(turn)
    assert not cold.stable[0]                                     # the cold solution snaps ...
    gap = np.linalg.norm(chained.tips_mm[-1, 0] - cold.tips_mm[0, 0])
    assert gap > 1.0                                              # ... continuation is elsewhere
    assert not StabilityDecision.for_robot(robot).continuation
    assert StabilityDecision.for_robot(Robot.nominal()).continuation     # shipped certificate
