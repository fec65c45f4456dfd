"""A follower force at the tip (fixed in the tip frame of tube 1: a lead or tether pulling on the
tip): the Cosserat backend against an independent planar elastica (`tests/independent/elastica.py`),
its robot-file form, and `diagnose` telling it from a force fixed in the robot frame."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from ctrplan.base.errors import InputError
from ctrplan.calibration import DiagnoseOptions, diagnose, read_measured
from ctrplan.calibration.data import write_measured_csv
from ctrplan.kinematics import CosseratBackend, SolverSettings
from ctrplan.kinematics.backbone import quaternion_to_matrix
from ctrplan.model.robot import JointDomain, Loads, Robot, Tube
from tests.independent import elastica

E_MPA = 50e3
TUBE = Tube(0.4, 0.6, 30.0, 50.0, 25e-3, E_MPA, E_MPA / 2.6)
DOMAIN = JointDomain(((-20.0, 0.0), (-math.pi, math.pi)))
FOLLOWER_N = (0.0, 0.01, 0.006)          # across the tube in its bending plane, and along it


def one_tube(**loads) -> Robot:
    return Robot(tubes=(TUBE,), domain=DOMAIN, loads=Loads(**loads), name="one_tube")


def lab_tip(beta: float, alpha: float, follower=FOLLOWER_N) -> np.ndarray:
    return elastica.tip(beta, alpha, length_mm=TUBE.length_mm, curved_mm=TUBE.curved_length_mm,
                        kappa_per_mm=TUBE.curvature_per_mm, ei_nmm2=TUBE.bending_stiffness_nmm2,
                        follower_n=follower)


@pytest.mark.parametrize("beta, alpha", [(-12.0, 0.0), (-5.0, 0.7), (0.0, -2.0)])
def test_follower_force_matches_the_independent_elastica(beta, alpha):
    """About 2 mm of tip deflection, solved by the fixed point on the tip frame, to 1e-7 mm of the
    independent solution (its own integrator, its own root finder); a force of the same components
    fixed in the robot frame lands elsewhere."""
    backend = CosseratBackend(one_tube(tip_follower_force_n=FOLLOWER_N), SolverSettings(step_single_mm=0.5))
    bb = backend.forward(np.array([beta, alpha]))
    assert bb.converged[0]
    want = lab_tip(beta, alpha)
    np.testing.assert_allclose(bb.tip_mm[0], want, atol=1e-7)
    free = CosseratBackend(one_tube()).forward(np.array([beta, alpha])).tip_mm[0]
    assert np.linalg.norm(free - want) > 1.0
    dead = CosseratBackend(one_tube(tip_force_n=FOLLOWER_N)).forward(np.array([beta, alpha])).tip_mm[0]
    assert np.linalg.norm(dead - want) > 0.5


def test_follower_force_is_the_dead_force_of_its_solved_direction_batched_and_along_a_path():
    """Three tubes: the follower solution is the dead-load solution of the force turned to its own
    tip frame, the same batched, alone, along a path and from a warm start."""
    robot = Robot.nominal()
    follower = np.array([0.0, 0.05, 0.03])
    loaded = robot.with_changes(loads=replace(robot.loads, tip_follower_force_n=tuple(follower)))
    q = np.array([[-30.0, -20.0, -5.0, 0.1, 0.2, 0.3], [-25.0, -20.0, -5.0, 0.5, 0.2, 0.3],
                  [-28.0, -18.0, -5.0, -1.5, 1.2, 0.3]])
    backend = CosseratBackend(loaded)
    bb = backend.forward(q, points=5)
    assert bb.converged.all()
    tip_frame = quaternion_to_matrix(bb.state[:, -1, -4:])
    for i in range(len(q)):
        dead = robot.with_changes(loads=replace(robot.loads, tip_force_n=tuple(tip_frame[i] @ follower)))
        np.testing.assert_allclose(CosseratBackend(dead).forward(q[i], points=5).state[0], bb.state[i],
                                   atol=1e-6)
    np.testing.assert_allclose(backend.forward(q[1], points=5).state[0], bb.state[1], atol=1e-6)
    np.testing.assert_allclose(backend.forward_path(q, points=5).state, bb.state, atol=1e-6)
    warm = backend.forward(q, points=5, guess=bb.initial_state)
    np.testing.assert_allclose(warm.state, bb.state, atol=1e-6)


def test_robot_file_form(tmp_path):
    """`loads.tip_follower_force_n` in a robot file: read, written back, part of the fingerprint; absent
    when zero (older files and fingerprints unchanged); a magnitude beyond a CTR's range is refused."""
    robot = one_tube(tip_follower_force_n=FOLLOWER_N)
    path = tmp_path / "r.yaml"
    robot.save(path)
    again = Robot.load(path)
    assert again.loads.tip_follower_force_n == FOLLOWER_N and again.fingerprint == robot.fingerprint
    assert again.fingerprint != one_tube().fingerprint
    assert "tip_follower_force_n" not in one_tube().to_dict()["loads"]
    assert again.loads.axisymmetric and not again.loads.is_free
    path.write_text(path.read_text().replace("tip_follower_force_n: [0.0, 0.01, 0.006]",
                                             "tip_follower_force_n: [0.0, 500.0, 0.0]"))
    with pytest.raises(InputError, match="tip_follower_force_n"):
        Robot.load(path)


def test_diagnose_tells_a_follower_force_from_a_robot_frame_force(tmp_path):
    """Tips of the independent elastica under a follower force (plus tracker noise): `diagnose`, given
    both loads as candidates, names the follower force and finds its value."""
    rng = np.random.default_rng(3)
    q = np.column_stack([rng.uniform(-20.0, 0.0, 60), rng.uniform(-math.pi, math.pi, 60)])
    tips = np.array([lab_tip(b, a) for b, a in q]) + rng.normal(0.0, 0.05, (len(q), 3))
    path = tmp_path / "lab.csv"
    write_measured_csv(path, q, tips[:, None, :])
    robot = one_tube()
    diag = diagnose(read_measured(path, robot), robot,
                    DiagnoseOptions(candidates=("tip_force", "follower_force"), resamples=1))
    assert diag.selection.chosen is not None and diag.selection.chosen.causes == ("follower_force",), \
        diag.summary()
    found = diag.extended_robot.loads.tip_follower_force_n
    np.testing.assert_allclose(found, FOLLOWER_N, atol=1e-3)


def test_pinn_backend_turns_the_follower_force_with_its_own_tip_frame():
    """Between its nodes the PINN backend integrates the Cosserat right-hand side (Hermite slopes):
    with a follower force each row's slopes use the force turned to the network's tip frame, i.e. row
    b equals the same network on the robot with the dead force R_tip(b) F (and differs from F fixed)."""
    import torch

    from ctrplan.kinematics.pinn import PinnBackend
    from ctrplan.kinematics.pinn_net import PinnNet

    robot = Robot.nominal()
    follower = np.array([0.2, -0.5, 0.3])
    loaded = robot.with_changes(loads=replace(robot.loads, tip_follower_force_n=tuple(follower)))
    torch.manual_seed(0)
    net = PinnNet(loaded)
    q = robot.sample_joints(4, rng=1)
    points = np.linspace(0.0, 1.0, 7)
    got = PinnBackend(loaded, net, nodes=9).forward(q, points=points)
    tip_frame = quaternion_to_matrix(got.state[:, -1, -4:] / np.linalg.norm(got.state[:, -1, -4:], axis=1,
                                                                             keepdims=True))
    for i in range(len(q)):
        dead = loaded.with_changes(loads=Loads(tip_force_n=tuple(tip_frame[i] @ follower)))
        want = PinnBackend(dead, net, nodes=9).forward(q[i], points=points).state[0]
        np.testing.assert_allclose(got.state[i], want, rtol=1e-6, atol=1e-6)
    fixed = loaded.with_changes(loads=Loads(tip_force_n=tuple(follower)))
    assert np.abs(PinnBackend(fixed, net, nodes=9).forward(q, points=points).state - got.state).max() > 1e-4


def test_follower_force_is_tried_when_asked_for():
    """In the library and named on request (`--candidates ...,follower_force`), not among the causes
    `diagnose` tries by default: each of its solves iterates on the tip frame."""
    from ctrplan.calibration import CAUSES, DEFAULT_CAUSES

    assert "follower_force" in CAUSES and "follower_force" not in DEFAULT_CAUSES
    assert DiagnoseOptions().candidates == DEFAULT_CAUSES and "tip_force" in DEFAULT_CAUSES
