"""Physics of the Cosserat backend: independent reference, invariants, symmetries, closed forms."""

from __future__ import annotations

import numpy as np
import pytest

from ctrplan.kinematics import CosseratBackend, SolverSettings
from ctrplan.model.robot import Loads, Robot


def _case_backend(robot: Robot, case: dict) -> CosseratBackend:
    loads = Loads(gravity_m_s2=tuple(case.get("gravity_m_s2", (0, 0, 0))),
                  tip_force_n=tuple(case.get("tip_force_N", (0, 0, 0))))
    tubes = tuple(t.__class__(**{**t.__dict__, "density_kg_m3": case.get("rho_kg_m3", 6450.0)})
                  for t in robot.tubes)
    return CosseratBackend(robot.with_changes(loads=loads, tubes=tubes))


@pytest.mark.parametrize("group", ["nominal", "gravity", "tip_force"])
def test_tips_match_independent_reference(robot, reference, group):
    cases = [c for c in reference["cases"] if c["group"] == group]
    assert cases
    for case in cases:
        q = np.array(case["beta_mm"] + case["alpha_rad"])
        bb = _case_backend(robot, case).forward(q, points=2)
        assert bb.converged[0]
        err = np.abs(bb.tips_mm[0] - np.array(case["tips_mm"])).max()
        assert err <= 1e-3, f"{group} case q={q}: tip error {err:.2e} mm"
        uz0 = bb.initial_state[0, 2:5] * 1e3
        np.testing.assert_allclose(uz0, case["u_z0_1_per_m"], atol=1e-3)


def test_backbones_match_reference(robot, reference):
    cases = [c for c in reference["cases"] if "backbone" in c]
    assert len(cases) >= 10
    for case in cases:
        q = np.array(case["beta_mm"] + case["alpha_rad"])
        s = np.array(case["backbone"]["s_mm"])
        l1 = q[0] + robot.lengths_mm[0]
        bb = _case_backend(robot, case).forward(q, points=np.clip(s / l1, 0, 1))
        np.testing.assert_allclose(bb.s_mm[0], s, atol=1e-9)
        err = np.linalg.norm(bb.positions_mm[0] - np.array(case["backbone"]["p_mm"]), axis=1).max()
        assert err <= 1e-3, f"backbone error {err:.2e} mm"


def test_converges_cold_on_random_configurations(cosserat, robot):
    q = robot.sample_joints(300, rng=7)
    bb = cosserat.forward(q, points=16)
    assert bb.converged.all()
    assert bb.residual.max() <= 1e-9
    assert np.isfinite(bb.state).all()


def test_free_space_invariants_on_general_path(robot):
    """Shooting for all five unknowns without loads must find m_b,xy = 0 and sum GJ u_z = 0."""
    general = CosseratBackend(robot, SolverSettings(exploit_free_space=False))
    assert general.n_unknowns == 5
    q = robot.sample_joints(20, rng=3)
    bb = general.forward(q, points=50)
    assert bb.converged.all()
    gj = np.array([t.torsional_stiffness_nmm2 for t in robot.tubes])
    ei1 = robot.tubes[0].bending_stiffness_nmm2
    present = bb.s_mm[:, :, None] <= bb.tube_ends_mm[:, None, :] + 1e-9
    torque = (present * gj * bb.state[..., 2:5]).sum(-1)
    assert np.abs(bb.state[..., 0:2]).max() / ei1 < 1e-9  # m_b,xy / EI1 in 1/mm
    # just before a tube end the sum still includes that tube's vanishing u_z; compare as curvature
    assert np.abs(torque).max() / gj[0] < 1e-8
    fast = CosseratBackend(robot).forward(q, points=50)
    np.testing.assert_allclose(bb.positions_mm, fast.positions_mm, atol=1e-6)


def test_rotating_all_alphas_rotates_shape_about_z(cosserat, robot):
    q = robot.sample_joints(10, rng=11)
    q[:, 3:] = np.clip(q[:, 3:], -2.0, 2.0)
    c = 0.7
    q2 = q.copy()
    q2[:, 3:] += c
    a, b = cosserat.forward(q, 40), cosserat.forward(q2, 40)
    rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    np.testing.assert_allclose(b.positions_mm, a.positions_mm @ rz.T, atol=1e-8)


def _planar_arc(robot: Robot, q: np.ndarray, s_out: np.ndarray) -> np.ndarray:
    """Closed form for equal alphas: piecewise-constant composite curvature
    k = sum(EI_i kappa_i, curved) / sum(EI_i, present), bending towards -y before the Rz(alpha)."""
    beta, alpha = q[:3], q[3]
    ends = beta + robot.lengths_mm
    curved_from = beta + np.array([t.straight_length_mm for t in robot.tubes])
    ei = np.array([t.bending_stiffness_nmm2 for t in robot.tubes])
    kappa = np.array([t.curvature_per_mm for t in robot.tubes])
    breaks = np.unique(np.clip(np.r_[0.0, ends, curved_from], 0, ends[0]))
    segments = []
    for a, b in zip(breaks[:-1], breaks[1:], strict=True):
        mid = 0.5 * (a + b)
        present = ends > mid
        curved = present & (curved_from < mid)
        segments.append((a, b, (ei * kappa * curved).sum() / (ei * present).sum()))
    out = np.empty((s_out.size, 3))
    for n, s in enumerate(s_out):
        phi = y = z = 0.0
        for a, b, k in segments:
            d = min(b, s) - a
            if d <= 0:
                break
            if k == 0:
                y, z = y - np.sin(phi) * d, z + np.cos(phi) * d
            else:
                y -= (np.cos(phi) - np.cos(phi + k * d)) / k
                z += (np.sin(phi + k * d) - np.sin(phi)) / k
            phi += k * d
        out[n] = [-np.sin(alpha) * y, np.cos(alpha) * y, z]
    return out


@pytest.mark.parametrize("alpha", [0.0, 1.1, -2.5])
def test_equal_alphas_give_planar_composite_arcs(cosserat, robot, alpha):
    for q_beta in robot.sample_joints(5, rng=5)[:, :3]:
        q = np.r_[q_beta, alpha, alpha, alpha]
        bb = cosserat.forward(q, points=80)
        assert np.abs(bb.state[0, :, 2:8]).max() < 1e-12  # no torsion, no twist
        expected = _planar_arc(robot, q, bb.s_mm[0])
        np.testing.assert_allclose(bb.positions_mm[0], expected, atol=1e-4)


def test_warm_start_reaches_the_cold_solution(cosserat, robot):
    q = robot.sample_joints(50, rng=2)
    cold = cosserat.forward(q, 20)
    near = cosserat.forward(q + 0.3, 20, check=False)
    warm = cosserat.forward(q, 20, guess=near.initial_state)
    np.testing.assert_allclose(warm.positions_mm, cold.positions_mm, atol=1e-7)
    assert np.median(warm.iterations) < np.median(cold.iterations)


def test_single_and_batched_calls_agree(cosserat, robot):
    q = robot.sample_joints(4, rng=9)
    batch = cosserat.forward(q, 30)
    for i in range(4):
        one = cosserat.forward(q[i], 30)
        np.testing.assert_array_equal(one.state[0], batch.state[i])


def test_non_convergence_is_reported_not_returned_as_shape(robot):
    starved = CosseratBackend(robot, SolverSettings(max_iterations=1))
    bb = starved.forward(robot.sample_joints(8, rng=1), 10)
    assert not bb.converged.all()
    assert np.isnan(bb.positions_mm[~bb.converged]).all()
    assert np.isfinite(bb.positions_mm[bb.converged]).all()


def test_backbone_geometry(cosserat, robot):
    q = robot.sample_joints(5, rng=4)
    bb = cosserat.forward(q, 64)
    np.testing.assert_allclose(bb.positions_mm[:, 0], 0.0, atol=1e-12)
    np.testing.assert_allclose(bb.positions_mm[:, -1], bb.tips_mm[:, 0], atol=1e-9)
    step = np.linalg.norm(np.diff(bb.positions_mm, axis=1), axis=-1)
    ds = np.diff(bb.s_mm, axis=1)
    assert np.all(step <= ds + 1e-9) and np.all(step >= 0.99 * ds)  # inextensible, unit speed
    rot = bb.rotations
    np.testing.assert_allclose(rot @ np.swapaxes(rot, -1, -2), np.broadcast_to(np.eye(3), rot.shape),
                               atol=1e-9)
    outer = robot.outer_radii_mm
    assert bb.radius_mm[:, 0].tolist() == [outer[2]] * 5
    assert bb.radius_mm[:, -1].tolist() == [outer[0]] * 5


def test_each_kernel_compiles_once_per_tube_count(robot):
    """Read-only inputs (a broadcast view, a frozen guess, cached arc fractions), integer settings,
    single rows, batches, paths and warm starts all reach one compiled kernel per tube count: numba
    compiles one per argument type, ~20-30 s each on a cold cache."""
    import ctrplan.kinematics._shooting as kernel
    from ctrplan.kinematics.base import ArcFractions

    q = robot.sample_joints(3, rng=5)
    frozen = q.copy()
    frozen.flags.writeable = False
    backend = CosseratBackend(robot)
    solved = backend.forward(frozen, 10)
    guess = solved.initial_state.copy()
    guess.flags.writeable = False
    backend.forward(np.broadcast_to(q[0], (3, 6)), ArcFractions(12), guess=guess)
    backend.forward(frozen[0], 10, guess=guess[:1])
    backend.forward_path(frozen, 10)
    CosseratBackend(robot, SolverSettings(step_multi_mm=2, max_iterations=40)).forward(q, 10)
    for dispatcher, kappa_at in ((kernel.solve_chains, 7), (kernel.solve_one, 6)):
        three_tubes = [s for s in dispatcher.signatures if s[kappa_at].count == robot.n_tubes]
        assert len(three_tubes) == 1, three_tubes
