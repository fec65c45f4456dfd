"""The two right-hand sides of the Cosserat-rod equations agree for N = 1…4 tubes: the numba kernel
of the shooting solver (`_shooting.rhs`) and the torch one of the PINN losses (`training.physics.rhs`),
on random states at random arc lengths, with loads and in free space."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from ctrplan.kinematics import _shooting
from ctrplan.kinematics.backbone import quaternion_to_matrix
from ctrplan.kinematics.cosserat import RodArrays
from ctrplan.model.robot import JointDomain, Loads, Robot, Tube
from ctrplan.training.physics import TubeTensors, rhs

LOADS = Loads(gravity_m_s2=(0.0, -9.81, 3.0), tip_force_n=(0.2, -0.1, 0.05))


def robot_of(n: int, loads: Loads | None = None) -> Robot:
    """An N-tube robot of distinct tubes, lengths 200, 170, 140, 110 mm; with N >= 3 the outermost
    tube is curved from its base."""
    tubes = []
    for i in range(n):
        length, curved = 200.0 - 30.0 * i, 50.0 if i < n - 1 or n < 3 else 200.0 - 30.0 * i
        tubes.append(Tube(inner_diameter_mm=0.4 + 0.4 * i, outer_diameter_mm=0.6 + 0.4 * i,
                          straight_length_mm=length - curved, curved_length_mm=curved,
                          curvature_per_mm=(20.0 - 4.0 * i) * 1e-3, shear_modulus_mpa=19.23e3 + 1e3 * i))
    bounds = ((-10.0, 0.0),) + ((0.0, 20.0),) * (n - 1) + ((-math.pi, math.pi),) * n
    return Robot(tubes=tuple(tubes), domain=JointDomain(bounds), loads=loads or Loads(), name=f"r{n}")


def random_states(robot: Robot, count: int, rng: np.random.Generator, free: bool
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Joints (B, 2N), arc lengths s (B,) mm away from transition points, states (B, 2N + 9); with
    ``free`` the states lie where free-space solutions live: m_b = 0 and sum GJ_i u_iz = 0 over the
    tubes present."""
    n = robot.n_tubes
    rod = RodArrays.of(robot)
    q = robot.sample_joints(count, rng)
    ends = q[:, :n] + rod.lengths
    s = rng.uniform(0.0, 1.0, count) * ends[:, 0]
    breaks = np.concatenate([ends, q[:, :n] + rod.straight], axis=1)
    s = np.maximum(np.where(np.abs(s[:, None] - breaks).min(1) < 1e-3, s - 2e-3, s), 1e-3)
    y = np.zeros((count, 2 * n + 9))
    y[:, 0:2] = rng.normal(0.0, 5.0, (count, 2))
    y[:, 2:2 + n] = rng.normal(0.0, 0.01, (count, n))
    y[:, 3 + n:2 + 2 * n] = rng.uniform(-math.pi, math.pi, (count, n - 1))
    y[:, 2 + 2 * n:5 + 2 * n] = rng.normal(0.0, 50.0, (count, 3))
    h = rng.normal(size=(count, 4))
    y[:, 5 + 2 * n:] = h / np.linalg.norm(h, axis=1, keepdims=True)
    if free:
        present = s[:, None] < ends
        y[:, 0:2] = 0.0
        y[:, 2:2 + n] *= present
        y[:, 2] = -(rod.GJ[1:] * y[:, 3:2 + n]).sum(1) / rod.GJ[0]
    return q, s, y


def numba_rhs(robot: Robot, q: np.ndarray, s: np.ndarray, y: np.ndarray, loaded: bool,
              forces: np.ndarray | None = None) -> np.ndarray:
    """`_shooting.rhs` at each (q, s, y), with the solver's arguments (`RodArrays.shooting_arrays`;
    ``forces`` (B, 3): each row's robot-frame tip force instead of the fixed one)."""
    n = robot.n_tubes
    lengths, straight, kappa, EI, GJ, force, weight = RodArrays.of(robot).shooting_arrays()
    forces = np.broadcast_to(force, (len(q), 3)) if forces is None else forces
    out = np.empty_like(y)
    for b in range(len(q)):
        beta = q[b, :n].copy()
        breaks, present, kc, bend, _ = _shooting.segments(beta, lengths, straight, EI)
        k = min(int(np.searchsorted(breaks, s[b])) - 1, len(bend) - 1)
        _shooting.rhs(s[b], y[b], present[k], kc[k], kappa, bend[k], EI, GJ, beta + lengths,
                      np.ascontiguousarray(forces[b]), weight, loaded, True, out[b])
    return out


def torch_rhs(robot: Robot, q: np.ndarray, s: np.ndarray, y: np.ndarray,
              tt: TubeTensors | None = None) -> np.ndarray:
    tt = tt or TubeTensors.from_robot(robot, dtype=torch.float64)
    return rhs(torch.tensor(y), torch.tensor(s), torch.tensor(q), tt).numpy()


@pytest.mark.parametrize("n", [1, 2, 3, 4])
def test_rhs_agree_under_loads(n):
    robot = robot_of(n, LOADS)
    q, s, y = random_states(robot, 200, np.random.default_rng(n), free=False)
    ref = numba_rhs(robot, q, s, y, loaded=True)
    assert np.abs(ref[:, 0:2]).max() > 1e-3  # the loads act
    np.testing.assert_allclose(torch_rhs(robot, q, s, y), ref, rtol=1e-9, atol=1e-12)
    if n > 1:  # a wrong robot (tubes' curvatures swapped) is caught by the same comparison
        tt = TubeTensors.from_robot(robot, dtype=torch.float64)
        wrong = TubeTensors(**{**tt.__dict__, "kappa": tt.kappa.flip(0)})
        assert np.abs(torch_rhs(robot, q, s, y, wrong) - ref).max() > 1e-4


@pytest.mark.parametrize("n", [1, 2, 3, 4])
def test_rhs_agree_in_free_space(n):
    robot = robot_of(n)
    q, s, y = random_states(robot, 200, np.random.default_rng(10 + n), free=True)
    ref = numba_rhs(robot, q, s, y, loaded=False)
    got = torch_rhs(robot, q, s, y)
    np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-12)
    assert np.abs(got[:, 0:2]).max() < 1e-12  # m_b stays 0 where the total moment vanishes
    if n > 1:
        assert np.abs(ref[:, 2:2 + n]).max() > 1e-6  # torsion is generated (the test has content)


def test_rhs_agree_with_a_follower_force():
    """A follower force turns with the tip frame: the torch rhs given the tip rotations and the kernel
    given each row's robot-frame force (`RodArrays.tip_forces`) agree, and the follower acts."""
    robot = robot_of(3, Loads(tip_force_n=(0.02, 0.0, -0.01), tip_follower_force_n=(0.05, -0.03, 0.1)))
    rng = np.random.default_rng(7)
    q, s, y = random_states(robot, 200, rng, free=False)
    h = rng.normal(size=(len(q), 4))
    tip_rotation = quaternion_to_matrix(h / np.linalg.norm(h, axis=1, keepdims=True))
    ref = numba_rhs(robot, q, s, y, True, RodArrays.of(robot).tip_forces(tip_rotation))
    tt = TubeTensors.from_robot(robot, dtype=torch.float64)
    got = rhs(torch.tensor(y), torch.tensor(s), torch.tensor(q), tt, torch.tensor(tip_rotation)).numpy()
    np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-12)
    fixed = numba_rhs(robot, q, s, y, True)                  # the follower left out: m_b' differs
    assert np.abs(fixed[:, 0:2] - ref[:, 0:2]).max() > 1e-3
