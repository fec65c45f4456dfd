"""Cold starts that plain Newton cannot make: long transmissions and strongly curved overlaps (a
three-tube robot like a third-party one: two fixed translations, the outer tube curved from its base,
the inner tube 1/55 mm over 86 mm). The solver falls back to continuation in the relative rotations;
every solution it returns is checked with the independent integrator of `tests.independent`."""

from __future__ import annotations

import numpy as np
import pytest

from ctrplan.kinematics.cosserat import CosseratBackend, SolverSettings
from ctrplan.model.robot import Robot
from tests.independent.cosserat import Tubes, integrate, solve

ROBOT = """
name: hard_cold_start
tubes:
  - {inner_diameter_mm: 0.60, outer_diameter_mm: 0.80, straight_length_mm: 200.0, curved_length_mm: 86.0,
     curvature_1_per_m: 18.18}
  - {inner_diameter_mm: 0.95, outer_diameter_mm: 1.20, straight_length_mm: 120.0, curved_length_mm: 60.0,
     curvature_1_per_m: 8.0}
  - {inner_diameter_mm: 1.40, outer_diameter_mm: 1.80, straight_length_mm: 0.0, curved_length_mm: 50.0,
     curvature_1_per_m: 5.0}
domain:
  beta3_mm: [0.0, 0.0]
  beta3_minus_beta2_mm: [90.0, 90.0]
  beta2_minus_beta1_mm: [50.0, 100.0]
  alpha_rad: [-3.141592653589793, 3.141592653589793]
"""
TUBES = Tubes(inner_mm=np.array([0.60, 0.95, 1.40]), outer_mm=np.array([0.80, 1.20, 1.80]),
              straight_mm=np.array([200.0, 120.0, 0.0]), curved_mm=np.array([86.0, 60.0, 50.0]),
              kappa_per_mm=np.array([18.18, 8.0, 5.0]) * 1e-3, E=np.full(3, 50e3), G=np.full(3, 19.23e3))


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    path = tmp_path_factory.mktemp("robot") / "robot.yaml"
    path.write_text(ROBOT)
    robot = Robot.load(path)
    q = robot.sample_joints(400, rng=0)
    with np.errstate(all="ignore"):
        plain = solve(q, TUBES)  # Newton from zero torsion, no continuation
    bb = CosseratBackend(robot, SolverSettings(stability=True)).forward(q, points=2)
    return q, plain, bb


def test_plain_newton_fails_on_part_of_the_domain(case):
    """The premise: from zero torsion, Newton does not converge on a few per cent of this domain."""
    _, plain, _ = case
    assert (~plain["converged"]).sum() >= 8


def test_continuation_solves_where_plain_newton_fails_and_the_solution_is_right(case):
    q, plain, bb = case
    hard = ~plain["converged"]
    assert bb.converged[hard].mean() >= 0.95
    solved = hard & bb.converged
    # the independent integrator, started from the solver's u_z(0), meets every distal condition
    with np.errstate(all="ignore"):
        (uz, _, _, _), tips = integrate(q[solved], bb.initial_state[solved][:, 2:5], TUBES)
    assert np.abs(uz).max() < 1e-8                         # u_iz(l_1) = 0 for every tube (1/mm)
    np.testing.assert_allclose(bb.tips_mm[solved], tips, atol=1e-3)
    assert (bb.stability[solved] > 0).all()                # the equilibrium reached is stable


def test_a_diverging_trial_step_under_load_is_rejected_not_a_crash():
    """Under a lateral tip force and gravity, Newton's first full-load steps can leave the region where
    the integration stays finite; the quaternion's norm then overflows. That used to end in
    ZeroDivisionError inside the compiled kernel; the step must be rejected and the load continuation
    must reach the equilibrium where the load path has one, and report failure where it does not."""
    from test_rhs_agree import LOADS, robot_of

    robot = robot_of(2, LOADS)
    q = robot.sample_joints(3, rng=2)
    bb = CosseratBackend(robot).forward(q, points=2)
    assert bb.converged[:2].all() and np.isfinite(bb.tips_mm[:2]).all()
    # the third folds at about 58 % of the load (load continuation fails there however fine its
    # steps): no equilibrium on the branch of the unloaded robot -- reported, never a shape
    assert not bb.converged[2] and np.isnan(bb.tips_mm[2]).all()
