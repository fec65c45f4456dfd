"""Robots of 1-4 tubes: closed forms, invariants, elastic stability, fixed joints, the robot loader."""

from __future__ import annotations

import json
import math
import textwrap

import numpy as np
import pytest

from ctrplan.base.errors import InputError
from ctrplan.kinematics import CosseratBackend, SolverSettings
from ctrplan.kinematics.stability import check_domain, critical_length_mm
from ctrplan.model.robot import JointDomain, Loads, Robot, Tube
from ctrplan.planning.space import BoxSpace
from tests.paths import REPO

NU = 0.3
E_MPA = 50e3
G_MPA = E_MPA / (2 * (1 + NU))


def tube(idm: float, odm: float, straight: float, curved: float, kappa_per_m: float) -> Tube:
    return Tube(idm, odm, straight, curved, kappa_per_m * 1e-3, E_MPA, G_MPA)


def robot_of(tubes: list[Tube], bounds: list[tuple[float, float]]) -> Robot:
    return Robot(tubes=tuple(tubes), domain=JointDomain(tuple(bounds)), name=f"{len(tubes)}-tube")


def overlapping_pair(length_mm: float, k1: float = 20.0, k2: float = 20.0) -> Robot:
    """Two fully overlapping curved tubes of one length, no straight parts, bases at the plate."""
    return robot_of([tube(0.4, 0.6, 0.0, length_mm, k1), tube(0.7, 0.9, 0.0, length_mm, k2)],
                    [(0.0, 0.0), (0.0, 0.0), (-math.pi, math.pi), (-math.pi, math.pi)])


def arc_point(kappa: float, s: float, phi: float) -> np.ndarray:
    """Point at arc length s (mm) of a planar circular arc of curvature kappa (1/mm) starting along z,
    bending towards the direction -y rotated by phi about z (pre-curvature about the tube's x axis)."""
    if kappa == 0:
        return np.array([0.0, 0.0, s])
    inplane = (1 - math.cos(kappa * s)) / kappa
    return np.array([inplane * math.sin(phi), -inplane * math.cos(phi), math.sin(kappa * s) / kappa])


def test_one_tube_is_a_circular_arc():
    r = robot_of([tube(0.4, 0.6, 30.0, 50.0, 25.0)], [(-20.0, 0.0), (-math.pi, math.pi)])
    be = CosseratBackend(r)
    beta, alpha = -12.0, 0.7
    bb = be.forward(np.array([beta, alpha]), points=np.linspace(0, 1, 41))
    assert bb.converged[0]
    l1 = beta + 80.0
    s = bb.s_mm[0]
    straight_end = beta + 30.0
    expected = []
    for si in s:
        if si <= straight_end:
            expected.append([0.0, 0.0, si])
        else:
            p = arc_point(25e-3, si - straight_end, alpha)
            expected.append(p + [0.0, 0.0, straight_end])
    np.testing.assert_allclose(bb.positions_mm[0], expected, atol=2e-5)  # Hermite between RK4 nodes
    np.testing.assert_allclose(bb.tip_mm[0], expected[-1], atol=2e-5)  # RK4, 4 mm steps
    assert s[-1] == pytest.approx(l1)


@pytest.mark.parametrize("relative", [0.0, math.pi])
def test_overlapping_pair_is_the_composite_curvature_arc(relative):
    """Delta alpha = 0 and pi give planar arcs of (EI1 k1 +- EI2 k2) / (EI1 + EI2) (below the snap
    threshold the straight-twist solution at pi is the stable one)."""
    r = overlapping_pair(0.8 * critical_length_mm(overlapping_pair(50.0)), k1=20.0, k2=14.0)
    be = CosseratBackend(r, SolverSettings(stability=True))
    alpha1 = 0.4
    bb = be.forward(np.array([0.0, 0.0, alpha1, alpha1 - relative]), points=np.linspace(0, 1, 30))
    assert bb.converged[0] and bb.stable[0]
    t1, t2 = r.tubes
    ei1, ei2 = t1.bending_stiffness_nmm2, t2.bending_stiffness_nmm2
    sign = 1.0 if relative == 0.0 else -1.0
    kappa = (ei1 * t1.curvature_per_mm + sign * ei2 * t2.curvature_per_mm) / (ei1 + ei2)
    expected = np.array([arc_point(kappa, si, alpha1) for si in bb.s_mm[0]])
    np.testing.assert_allclose(bb.positions_mm[0], expected, atol=1e-5)


@pytest.mark.parametrize("factor", [0.9, 1.1])
def test_stability_measure_at_half_turn_is_the_jacobi_closed_form(factor):
    """At Delta alpha = pi the straight-twist equilibrium has Jacobi field h' = cos(sqrt(c) s), c =
    (1 + nu) k1 k2: the measure is cos(sqrt(c) L) -- positive below the critical length, negative
    above (Dupont et al. 2010)."""
    r0 = overlapping_pair(50.0)
    length = factor * critical_length_mm(r0)
    r = overlapping_pair(length)
    bb = CosseratBackend(r, SolverSettings(stability=True)).forward(np.array([0.0, 0.0, 0.0, math.pi]),
                                                                     points=2)
    assert bb.converged[0]
    c = (1 + NU) * (20e-3) ** 2
    expected = math.cos(math.sqrt(c) * length)
    assert bb.stability[0] == pytest.approx(expected, abs=2e-3)
    assert bool(bb.stable[0]) is (factor < 1)


def test_critical_length_is_the_closed_form():
    r = overlapping_pair(50.0, k1=20.0, k2=14.0)
    assert critical_length_mm(r) == pytest.approx(math.pi / 2 / math.sqrt(1.3 * 20e-3 * 14e-3))


@pytest.mark.parametrize("factor, snap_free", [(0.9, True), (1.1, False)])
def test_domain_check_reproduces_the_two_tube_threshold(factor, snap_free):
    """Every sweep turns a tube through its whole rotation interval (the translations are fixed), so
    what it flags above the threshold is a configuration of the domain with the tubes near opposed
    (|alpha2 - alpha1| > pi / 2), where the closed form puts the snap -- a sweep that moved another
    joint would flag configurations outside the domain or none."""
    r = overlapping_pair(factor * critical_length_mm(overlapping_pair(50.0)))
    report = check_domain(r, n=6, steps=37, seed=1)
    assert report.snap_free is snap_free
    assert (report.example_q is None) is snap_free
    for s in report.sweeps:
        column = 2 + s.tube - 1
        assert s.q[0, column] == -math.pi and s.q[-1, column] == math.pi
        others = np.delete(s.q, column, axis=1)
        np.testing.assert_array_equal(others, np.repeat(others[:1], len(s.q), axis=0))
    if not snap_free:
        assert 0 < report.unstable_fraction < 1
        q = np.asarray(report.example_q)
        r.check_joints(q)  # a configuration of the domain
        assert abs(np.angle(np.exp(1j * (q[3] - q[2])))) > math.pi / 2


def four_tube_robot() -> Robot:
    tubes = [tube(0.3, 0.4, 150.0, 50.0, 30.0), tube(0.5, 0.7, 100.0, 60.0, 15.0),
             tube(0.8, 1.0, 60.0, 60.0, 8.0), tube(1.1, 1.3, 40.0, 40.0, 4.0)]
    return robot_of(tubes, [(-10.0, 0.0), (0.0, 20.0), (0.0, 20.0), (0.0, 20.0)] + [(-math.pi, math.pi)] * 4)


@pytest.mark.parametrize("n_tubes", [1, 2, 3, 4])
def test_free_space_invariants_for_every_tube_count(n_tubes):
    """Without loads the bundle carries no moment: m_b = 0 and sum GJ_i u_iz = 0 along the whole
    backbone, on the general (N + 2 unknowns) path too."""
    full = four_tube_robot()  # N tubes: the outermost N of the four
    r = robot_of(list(full.tubes[4 - n_tubes:]), [(-10.0, 0.0)] + [(0.0, 20.0)] * (n_tubes - 1)
                 + [(-math.pi, math.pi)] * n_tubes)
    q = r.sample_joints(8, rng=n_tubes)
    for settings in (SolverSettings(), SolverSettings(exploit_free_space=False)):
        bb = CosseratBackend(r, settings).forward(q, points=40)
        assert bb.converged.all()
        assert bb.state.shape == (8, 40, 2 * n_tubes + 9)
        gj = np.array([t.torsional_stiffness_nmm2 for t in r.tubes])
        uz = bb.state[..., 2:2 + n_tubes]
        present = bb.s_mm[..., None] <= bb.tube_ends_mm[:, None, :] + 1e-9
        total = (uz * gj * present).sum(axis=-1)
        assert np.abs(total).max() <= 1e-6 * gj[0] * 1e-3
        assert np.abs(bb.state[..., :2]).max() <= 1e-6


def test_rotating_every_tube_rotates_a_four_tube_robot_about_z():
    r = four_tube_robot()
    be = CosseratBackend(r)
    q = r.sample_joints(5, rng=4)
    turned = q.copy()
    turned[:, 4:] = np.angle(np.exp(1j * (turned[:, 4:] + 0.3)))
    a, b = be.forward(q, points=10), be.forward(turned, points=10)
    c, s = math.cos(0.3), math.sin(0.3)
    rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    np.testing.assert_allclose(b.positions_mm, a.positions_mm @ rz.T, atol=1e-6)


def test_fixed_joints_are_not_searched():
    r = robot_of([tube(0.4, 0.6, 100.0, 50.0, 20.0), tube(0.7, 0.9, 60.0, 40.0, 10.0)],
                 [(-5.0, -5.0), (0.0, 30.0), (-math.pi, math.pi), (0.5, 0.5)])
    space = BoxSpace.for_robot(r)
    assert space.dimension == 2
    q = space.sample(50, np.random.default_rng(0))
    assert np.allclose(q[:, 1], -5.0) and np.allclose(q[:, 3], 0.5)
    np.testing.assert_allclose(space.to_joints(space.to_coords(q)), q, atol=1e-12)
    samples = r.sample_joints(20, rng=1)
    assert np.allclose(samples[:, 1], -5.0)


ROBOT_YAML = """\
name: pair
tubes:
  - {inner_diameter_mm: 0.4, outer_diameter_mm: 0.6, straight_length_mm: 100, curved_length_mm: 50,
     curvature_1_per_m: KAPPA}
  - {inner_diameter_mm: 0.7, outer_diameter_mm: 0.9, straight_length_mm: 60, curved_length_mm: 40,
     curvature_1_per_m: 10}
domain:
  beta2_mm: [-10, 0]
  beta2_minus_beta1_mm: [0, 30]
  alpha_rad: [-3.14159, 3.14159]
"""


def test_two_tube_robot_file_loads_and_solves(tmp_path):
    path = tmp_path / "pair.yaml"
    path.write_text(ROBOT_YAML.replace("KAPPA", "20"))
    r = Robot.load(path)
    assert r.n_tubes == 2 and r.joint_names == ("beta1", "beta2", "alpha1", "alpha2")
    bb = CosseratBackend(r).forward(r.sample_joints(4, rng=0), points=8)
    assert bb.converged.all() and bb.tips_mm.shape == (4, 2, 3)


@pytest.mark.parametrize("replace, fragment", [
    (("KAPPA", "3000"), "outside the physical range"),
    (("KAPPA", "500"), "strain"),
    (("KAPPA", "20"), None),
    (("straight_length_mm: 100", "straight_length_mm: 1.0e308"), "physical range"),
    (("KAPPA", "-1"), "physical range"),
])
def test_loader_refuses_physically_impossible_robots(tmp_path, replace, fragment):
    path = tmp_path / "pair.yaml"
    text = ROBOT_YAML.replace(*replace) if replace[0] == "KAPPA" else ROBOT_YAML.replace("KAPPA", "20")
    path.write_text(text.replace(*replace))
    if fragment is None:
        assert Robot.load(path).n_tubes == 2
        return
    with pytest.raises(InputError, match=fragment) as err:
        Robot.load(path)
    assert "pair.yaml:" in str(err.value) and "tubes[0]" in str(err.value)


def test_other_tube_counts_need_a_domain(tmp_path):
    path = tmp_path / "pair.yaml"
    path.write_text(ROBOT_YAML.replace("KAPPA", "20").split("domain:")[0])
    with pytest.raises(InputError, match="needs a 'domain'"):
        Robot.load(path)


def test_converged_is_never_claimed_for_a_non_physical_shape():
    """A rod cannot reach farther from the plate than its arc length; such a 'solution' (here from
    steps far too long for the curvature) is reported as not converged."""
    r = robot_of([tube(0.4, 0.6, 0.0, 200.0, 99.0)], [(0.0, 0.0), (0.0, 0.0)])
    coarse = CosseratBackend(r, SolverSettings(step_single_mm=200.0))
    bb = coarse.forward(np.array([0.0, 0.0]), points=5)
    assert not bb.converged[0]
    assert np.isnan(bb.tips_mm).all()


def test_yaml_loader_roundtrip_keeps_fingerprint(tmp_path):
    r = four_tube_robot()
    import yaml

    path = tmp_path / "four.yaml"
    path.write_text(yaml.safe_dump(r.to_dict()))
    again = Robot.load(path)
    assert again.fingerprint == r.fingerprint and again.domain == r.domain


def test_nominal_fingerprint_is_unchanged():
    """Three-tube robot files and shipped models keep working: the nominal robot's fingerprint is
    the one the shipped model cards were trained for."""
    assert Robot.nominal().fingerprint == "43757632c8ab6554891b2359a75d181e6ab17ee781f27aa4c94e8630f8940a4c"


@pytest.mark.parametrize("text, fragment", [
    ("tubes: []", "1 to 4 tubes"),
    (textwrap.dedent("""\
        tubes:
          - {inner_diameter_mm: 0.4, outer_diameter_mm: 0.6, straight_length_mm: 0, curved_length_mm: 0,
             curvature_1_per_m: 0}
        domain: {beta1_mm: [-1, 0], alpha1_rad: [0, 1]}
        """), "no length"),
])
def test_loader_messages(tmp_path, text, fragment):
    path = tmp_path / "r.yaml"
    path.write_text(text)
    with pytest.raises(InputError, match=fragment):
        Robot.load(path)


def test_one_tube_under_load_solves_single_and_batched():
    r = Robot(tubes=(tube(0.4, 0.6, 30.0, 50.0, 25.0),),
              domain=JointDomain(((-20.0, 0.0), (-math.pi, math.pi))),
              loads=Loads(gravity_m_s2=(0.0, -9.81, 0.0)))
    be = CosseratBackend(r, SolverSettings(stability=True))
    q = r.sample_joints(6, rng=2)
    one, many = be.forward(q[0], points=5), be.forward(q, points=5)
    assert many.converged.all() and (many.stability > 0).all()
    np.testing.assert_allclose(one.tip_mm[0], many.tip_mm[0], atol=1e-9)
    assert many.tip_mm[0, 1] < 0  # it sags along gravity


def test_two_tube_scene_plans_with_its_own_pinn_by_default(capsys):
    """`ctrplan plan scenes/two_tube.yaml` picks the shipped PINN trained for that robot."""
    from ctrplan.cli.app import main

    repo = REPO
    assert main(["plan", str(repo / "scenes" / "two_tube.yaml"), "--json", "--seed", "0"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["backend"] == "pinn" and doc["model"].startswith("pinn_two_tube")
    assert doc["solved"] and doc["validated"]["collision_free"]
    assert all(len(q) == 4 for q in doc["path"])
