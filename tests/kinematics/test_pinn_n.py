"""PINN for N = 1…4 tubes: encoding and hard constraints, compiled inference against the torch net,
losses against exact solutions, training for a two-tube robot and a robot with fixed joints, and a
diverging run's one-line message."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from test_rhs_agree import LOADS, robot_of

from ctrplan.base.errors import InputError
from ctrplan.kinematics import CosseratBackend
from ctrplan.kinematics.pinn import PinnBackend
from ctrplan.kinematics.pinn_net import PinnNet
from ctrplan.model.robot import Loads, Robot
from ctrplan.training.losses import boundary_residual, tracked_tips
from ctrplan.training.physics import TubeTensors, quat_to_matrix
from ctrplan.training.recipes import get_recipe
from ctrplan.training.trainer import train
from tests.paths import REPO

TWO_TUBE = REPO / "examples" / "robots" / "two_tube.yaml"

#: A third-party style three-tube robot: an inner tube and a balanced pair whose outer tube is
#: curved from its base at the plate; beta3 and beta3 - beta2 fixed (zero-width intervals).
FIXED_JOINTS_YAML = """\
name: fixed_pair
tubes:
  - {inner_diameter_mm: 0.40, outer_diameter_mm: 0.50, straight_length_mm: 150.0, curved_length_mm: 40.0,
     curvature_1_per_m: 20.0}
  - {inner_diameter_mm: 0.80, outer_diameter_mm: 1.00, straight_length_mm: 60.0, curved_length_mm: 70.0,
     curvature_1_per_m: 8.0}
  - {inner_diameter_mm: 1.10, outer_diameter_mm: 1.25, straight_length_mm: 0.0, curved_length_mm: 120.0,
     curvature_1_per_m: 8.0}
domain:
  beta3_mm: [0.0, 0.0]
  beta3_minus_beta2_mm: [10.0, 10.0]
  beta2_minus_beta1_mm: [0.0, 20.0]
  alpha_rad: [-3.141592653589793, 3.141592653589793]
"""


def random_net(robot: Robot, seed: int, harmonics: int = 1, frame: int = 0) -> PinnNet:
    torch.manual_seed(seed)
    return PinnNet(robot, hidden=32, layers=3, scales=np.linspace(0.5, 1.5, robot.n_states),
                   harmonics=harmonics, frame=frame)


def test_three_tube_encoding_is_the_papers(robot):
    """N = 3 keeps today's inputs: beta box coordinates, then cos and sin of alpha2/3 - alpha1."""
    net = PinnNet(robot)
    q = torch.tensor(robot.sample_joints(7, rng=3), dtype=torch.float32)
    sigma = torch.rand(7)
    lo, hi = net.box_lower, net.box_upper
    box = torch.stack([q[:, 2], q[:, 2] - q[:, 1], q[:, 1] - q[:, 0]], -1)
    d = q[:, 4:6] - q[:, 3:4]
    expected = torch.cat([2 * sigma[:, None] - 1, 2 * (box - lo[:3]) / (hi[:3] - lo[:3]) - 1,
                          torch.cos(d), torch.sin(d)], -1)
    assert net.n_inputs == 8 and net.n_states == 15
    torch.testing.assert_close(net.features(sigma, q), expected)


def test_harmonic_encoding_adds_multiples_of_the_relative_rotations(robot):
    """harmonics K: cos(k d) for k = 1…K, then sin(k d), d = alpha2/3 - alpha1; still 2 pi-periodic."""
    net = PinnNet(robot, harmonics=3)
    q = torch.tensor(robot.sample_joints(7, rng=4), dtype=torch.float32)
    sigma = torch.rand(7)
    d = q[:, 4:6] - q[:, 3:4]
    plain = PinnNet(robot).features(sigma, q)
    expected = torch.cat([plain[:, :4], torch.cos(d), torch.cos(2 * d), torch.cos(3 * d),
                          torch.sin(d), torch.sin(2 * d), torch.sin(3 * d)], -1)
    assert net.n_inputs == 4 + 12
    torch.testing.assert_close(net.features(sigma, q), expected)
    turned = q.clone()
    turned[:, 4] += 2 * torch.pi
    torch.testing.assert_close(net.features(sigma, turned), expected, atol=2e-5, rtol=0)


@pytest.mark.parametrize(("n", "frame"), [(1, 0), (2, 0), (2, 1), (3, 0), (3, 2), (4, 1)])
def test_hard_constraints_and_equivariance_for_n_tubes(n, frame):
    """Whichever tube is the frame tube: p(0) = 0, p'(0) = e3, m_b = 0, theta_1 = 0, unit
    quaternions, and adding c to every alpha turns positions and tube 1's frame by Rz(c)."""
    robot = robot_of(n)
    net = random_net(robot, n, frame=frame).double()
    assert net.n_inputs == 3 * n - 1 and net.mlp[-1].out_features == 2 * n + 9
    q = torch.tensor(robot.sample_joints(5, rng=n))
    x, dx = torch.func.jvp(lambda sg: net(sg, q), (torch.zeros(5, dtype=torch.float64),),
                           (torch.ones(5, dtype=torch.float64),))
    ip = 2 * n + 2
    l1 = q[:, 0] + net.lengths[0]
    torch.testing.assert_close(x[:, ip:ip + 3], torch.zeros(5, 3, dtype=torch.float64))  # p(0) = 0
    tangent = dx[:, ip:ip + 3] / l1[:, None]
    torch.testing.assert_close(tangent, torch.tensor([[0.0, 0.0, 1.0]] * 5, dtype=torch.float64))
    with torch.no_grad():
        y = net(torch.rand(5, dtype=torch.float64), q)
    assert float(y[:, 0:2].abs().max()) == 0.0            # m_b = 0 in free space
    assert float(y[:, 2 + n].abs().max()) == 0.0          # theta_1 = 0
    torch.testing.assert_close(y[:, ip + 3:].norm(dim=-1), torch.ones(5, dtype=torch.float64))
    # adding c to every alpha rotates positions by Rz(c) and leaves twists and torsion unchanged
    c, sigma = 0.7, torch.rand(5, dtype=torch.float64)
    shifted = q.clone()
    shifted[:, n:] += c
    a, b = net(sigma, q), net(sigma, shifted)
    rz = torch.tensor([[math.cos(c), -math.sin(c), 0], [math.sin(c), math.cos(c), 0], [0, 0, 1]],
                      dtype=torch.float64)
    torch.testing.assert_close(b[:, ip:ip + 3], a[:, ip:ip + 3] @ rz.T)
    torch.testing.assert_close(b[:, 2:ip], a[:, 2:ip])
    torch.testing.assert_close(quat_to_matrix(b[:, ip + 3:]), rz @ quat_to_matrix(a[:, ip + 3:]))


def test_fixed_joints_give_constant_zero_features(tmp_path):
    path = tmp_path / "fixed.yaml"
    path.write_text(FIXED_JOINTS_YAML)
    robot = Robot.load(path)
    assert robot.domain.fixed.tolist() == [True, True, False, False, False, False]
    net = random_net(robot, 0)
    q = torch.tensor(robot.sample_joints(6, rng=1), dtype=torch.float32, requires_grad=True)
    z = net.features(torch.rand(6), q)
    assert torch.isfinite(z).all() and float(z[:, 1:3].detach().abs().max()) == 0.0
    net(torch.rand(6), q).sum().backward()
    assert torch.isfinite(q.grad).all()
    pinn = PinnBackend(robot, net, nodes=None)
    fast = pinn._evaluate(q.detach().numpy().astype(float), np.full((6, 1), 0.5))[:, 0]
    np.testing.assert_allclose(fast, net(torch.full((6,), 0.5), q).detach().numpy(), atol=2e-4)


@pytest.mark.parametrize(("n", "harmonics", "frame"), [(1, 1, 0), (2, 3, 1), (3, 1, 0), (3, 4, 2), (4, 2, 1)])
def test_compiled_inference_matches_torch_for_n_tubes(n, harmonics, frame):
    robot = robot_of(n, LOADS if n == 2 else Loads())
    net = random_net(robot, 10 + n, harmonics, frame)
    q = robot.sample_joints(40, rng=n)  # more than one cache-sized chunk of nodes
    frac = np.random.default_rng(n).uniform(0, 1, (40, 4))
    pinn = PinnBackend(robot, net, nodes=None)
    fast = pinn._evaluate(q, frac)
    with torch.no_grad():
        ref = net(torch.tensor(frac.reshape(-1), dtype=torch.float32),
                  torch.tensor(np.repeat(q, 4, axis=0), dtype=torch.float32)).numpy()
    np.testing.assert_allclose(fast.reshape(-1, 2 * n + 9), ref, atol=2e-4)
    # whole backbones: every point from the network; tips and s = 0 state are the network's too
    bb = pinn.forward(q, 10)
    ends = q[:, :n] + robot.lengths_mm
    with torch.no_grad():
        tips = tracked_tips(net, torch.tensor(q, dtype=torch.float32), TubeTensors.from_robot(robot)).numpy()
    np.testing.assert_allclose(bb.tips_mm, tips, atol=2e-4)
    np.testing.assert_allclose(bb.tube_ends_mm, ends)
    np.testing.assert_allclose(bb.initial_state, pinn._evaluate(q, np.zeros((40, 1)))[:, 0], atol=1e-6)
    # interpolated backbones (nodes) in parallel chunks agree with one configuration at a time
    interp = PinnBackend(robot, net)
    batch = interp.forward(q, 64)
    assert batch.state.shape == (40, 64, 2 * n + 9) and batch.converged.all()
    np.testing.assert_allclose(batch.tips_mm, bb.tips_mm, atol=1e-4)
    np.testing.assert_allclose(interp.forward(q[17], 64).state[0], batch.state[17], atol=1e-4)


def test_two_tube_losses_vanish_on_exact_solutions():
    robot = Robot.load(TWO_TUBE)
    q = robot.sample_joints(8, rng=2)
    solver = CosseratBackend(robot)
    exact = solver.forward(q, 3)
    scales = torch.ones(robot.n_states, dtype=torch.float64)

    class ExactNet:
        def __init__(self):
            self.scales = scales

        def __call__(self, sigma: torch.Tensor, qq: torch.Tensor) -> torch.Tensor:
            return torch.tensor(np.array([solver.forward(qi.numpy(), np.array([float(si)])).state[0, 0]
                                          for si, qi in zip(sigma, qq, strict=True)]))

    tt = TubeTensors.from_robot(robot, dtype=torch.float64)
    qt = torch.tensor(q)
    assert float(boundary_residual(ExactNet(), qt, tt).max()) < 1e-12
    np.testing.assert_allclose(tracked_tips(ExactNet(), qt, tt).numpy(), exact.tips_mm, atol=1e-9)
    with torch.no_grad():
        assert float(boundary_residual(random_net(robot, 0).double(), qt, tt).sum()) > 1e-6


def test_short_two_tube_training_lowers_the_loss(tmp_path):
    robot = Robot.load(TWO_TUBE)
    recipe = get_recipe("fast", steps=60, dense_configs=300, dense_batch=256, collocation=128, boundary=32)
    losses = []
    result = train(robot, recipe, tmp_path / "two", seed=3,
                   progress=lambda step, total, stats: losses.append(stats["loss"]))
    assert losses[-1] < 0.8 * losses[0]
    network = json.loads((tmp_path / "two.json").read_text())["network"]
    # s, beta2, beta2 - beta1, then cos and sin of k (alpha2 - alpha1) for k = 1…K
    assert result.steps == 60 and network["inputs"] == 3 + 2 * recipe.harmonics and network["outputs"] == 13
    bb = PinnBackend.load(tmp_path / "two", robot).forward(robot.sample_joints(3, rng=1), 30)
    assert bb.state.shape == (3, 30, 13) and bb.converged.all()


@pytest.mark.parametrize("n", [1, 4])
def test_training_runs_for_one_and_four_tubes(n, tmp_path):
    robot = robot_of(n, LOADS if n == 4 else None)  # (the shooting solver fails on one loaded tube)
    recipe = get_recipe("fast", steps=20, dense_configs=100, dense_batch=64, collocation=64, boundary=16)
    result = train(robot, recipe, tmp_path / "m", seed=0)
    assert result.steps == 20 and all(np.isfinite(h["loss"]) for h in result.history)
    bb = PinnBackend.load(tmp_path / "m", robot).forward(robot.sample_joints(2, rng=0), 30)
    assert bb.state.shape == (2, 30, 2 * n + 9) and bb.tips_mm.shape == (2, n, 3)


def test_train_cli_with_fixed_joints_and_a_tube_curved_from_its_base(tmp_path, capsys):
    from ctrplan.cli.app import main

    path = tmp_path / "fixed.yaml"
    path.write_text(FIXED_JOINTS_YAML)
    args = ["train", "--robot", str(path), "--out-dir", str(tmp_path), "--name", "m", "--steps", "20",
            "--set", "dense_configs=200", "--set", "dense_batch=128", "--set", "collocation=64",
            "--set", "boundary=16"]
    assert main(args) == 0
    robot = Robot.load(path)
    pinn = PinnBackend.load(tmp_path / "m", robot)
    assert pinn.forward(robot.sample_joints(2, rng=0)).converged.all()
    # the card carries the planner's calibrated margin: on configurations calibration never saw, the
    # tip region's largest error is within its 0.8-coverage bound for about 80 % of them
    from ctrplan.kinematics.error_bound import region_bounds_mm
    from ctrplan.training.evaluate import compare

    fresh = compare(pinn, robot, n=300, points=64, seed=2024)
    err = np.linalg.norm(fresh.predicted.positions_mm - fresh.exact.positions_mm, axis=-1)
    tip_region = fresh.exact.s_mm >= 0.75 * fresh.exact.s_mm[:, -1:]
    solved = fresh.exact.converged
    worst = np.where(tip_region, err, 0.0).max(axis=1)[solved]
    within = float(np.mean(worst <= region_bounds_mm(pinn.error_bound, 0.8)[-1]))
    assert solved.sum() > 250 and 0.7 <= within <= 0.9, within
    capsys.readouterr()
    # a diverging run stops with one line: the cause and an option that exists
    assert main([*args, "--set", "lr=1e30"]) == 2
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith("ctrplan:")]  # not the progress bar
    assert "Traceback" not in err and len(lines) == 1, err
    assert "diverged" in lines[0] and "--set lr=" in lines[0]


def test_robot_joint_domain_round_trip_for_sampler():
    """The trainer's on-device sampler draws joints inside the domain for every N."""
    from ctrplan.training.trainer import Sampler

    for n in (1, 2, 4):
        robot = robot_of(n)
        sampler = Sampler(robot, 0, torch.device("cpu"))
        q = sampler.joints(500, sampler.generator(0, 1)).double().numpy()
        assert q.shape == (500, 2 * n)
        assert not robot.domain.violations(q, tol=1e-4)


def test_shipped_two_tube_model_meets_accuracy_targets():
    """models/pinn_two_tube: 5 minutes of `--recipe fast` on one CPU thread (card: mean 0.21 %,
    max 0.95 % on 100 unseen configurations)."""
    from ctrplan.training.evaluate import compare

    robot = Robot.load(TWO_TUBE)
    pinn = PinnBackend.load("pinn_two_tube", robot)
    metrics = compare(pinn, robot, n=30, points=60).metrics()
    assert metrics["backbone_error_pct"]["mean"] <= 0.4
    assert metrics["backbone_error_pct"]["max"] <= 1.5
    assert metrics["orientation_error_deg"]["mean"] <= 5.0
    assert set(metrics["tip_error_mm"]) == {"tube1", "tube2"}
    with pytest.raises(InputError, match="trained for robot"):
        PinnBackend.load("pinn_two_tube", Robot.nominal())


def test_encoding_keeps_the_rotation_symmetry_only_where_the_loads_do():
    """Rotating every tube by c rotates the robot about z only when the loads are along z: the exact
    solver says so, and the default encoding adds absolute angles exactly when it does not."""
    axial, lateral = Loads(gravity_m_s2=(0.0, 0.0, -9.81)), Loads(gravity_m_s2=(0.0, -9.81, 0.0))
    q = robot_of(2).sample_joints(3, rng=2)
    turned = q.copy()
    turned[:, 2:] += 0.7
    rz = np.array([[math.cos(0.7), -math.sin(0.7), 0.0], [math.sin(0.7), math.cos(0.7), 0.0], [0, 0, 1]])
    for loads, symmetric in ((axial, True), (lateral, False)):
        robot = robot_of(2, loads)
        exact = CosseratBackend(robot)
        moved, before = exact.forward(turned, points=2), exact.forward(q, points=2)
        assert moved.converged.all() and before.converged.all()
        gap = np.abs(moved.tips_mm - before.tips_mm @ rz.T).max()
        assert (gap < 1e-6) == symmetric and (symmetric or gap > 1e-3)
        assert PinnNet(robot).absolute_angles == (not symmetric)
    assert not PinnNet(Robot.nominal()).absolute_angles


def test_absolute_angles_start_as_the_same_function():
    robot = robot_of(3)
    net = random_net(robot, 5, harmonics=2)
    wider = net.with_absolute_angles(robot)
    q = torch.tensor(robot.sample_joints(16, rng=6), dtype=torch.float32)
    sigma = torch.rand(16)
    assert wider.absolute_angles and wider.n_inputs == net.n_inputs + 6
    torch.testing.assert_close(wider(sigma, q), net(sigma, q))
