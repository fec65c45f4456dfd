"""One calibration model: every cause registered by its class, with plausible ranges and sources; one
`Robot` carries the mechanics and the measurement side (`Robot.calibration`), reads back equal from
its file for 1-4 tubes and every effect, and predicts what the tracker sees -- checked against
computations written here and the independent integrator of `tests/independent`."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ctrplan.base.errors import InputError
from ctrplan.calibration import CAUSES, EFFECTS, make_effect
from ctrplan.calibration.predict import Evaluator
from ctrplan.cli.diagnose import CandidatesOpt
from ctrplan.kinematics import CosseratBackend
from ctrplan.kinematics.cosserat import SolverSettings
from ctrplan.model.causes.base import SIDES
from ctrplan.model.causes.measurement_side import MeasurementEffect
from ctrplan.model.causes.mechanics import StiffnessRatio
from ctrplan.model.measurement import Calibration
from ctrplan.model.motion import Motion
from ctrplan.model.robot import JointDomain, Robot, Tube
from tests.independent.cosserat import Tubes, solve

FOUR = (Tube(0.3, 0.4, 150.0, 50.0, 30e-3), Tube(0.5, 0.7, 100.0, 60.0, 15e-3),
        Tube(0.8, 1.0, 60.0, 60.0, 8e-3), Tube(1.1, 1.3, 40.0, 40.0, 4e-3))


def robot_of(n: int) -> Robot:
    """A robot of the first ``n`` tubes of a four-tube set."""
    box = ((-10.0, 0.0),) + ((0.0, 20.0),) * (n - 1) + ((-math.pi, math.pi),) * n
    return Robot(tubes=FOUR[:n], domain=JointDomain(box), name=f"tubes{n}")


# ---- the registry ---------------------------------------------------------------------------------
def test_one_list_of_causes_derived_from_the_classes():
    assert tuple(EFFECTS) == CAUSES and len(set(CAUSES)) == len(CAUSES)
    for name, cls in EFFECTS.items():
        e = cls()
        assert e.name == name and e.side in SIDES and e.key and e.description
        assert isinstance(e, MeasurementEffect) == (e.side != "mechanics")
    # the command line offers the same list
    assert all(c in CandidatesOpt.__metadata__[0].help for c in CAUSES)
    with pytest.raises(InputError, match=r"unknown cause 'stiction' \(known: curvature, stiffness_ratio, "):
        make_effect("curvature+stiction")


@pytest.mark.parametrize("name", CAUSES)
def test_every_parameter_has_a_plausible_range_with_a_source(name):
    robot = Robot.nominal()
    e = make_effect(name)
    params = e.params(robot)
    x0 = e.values(robot)
    assert len(params) == len(x0)
    for p, v in zip(params, x0, strict=True):
        assert p.plausible is not None and len(p.plausible.source) > 20, p
        assert p.plausible.low < p.plausible.high and p.scale > 0 and p.unit
        assert v in p.plausible, (p, v)              # the nominal robot is plausible
        assert p.lower <= v <= p.upper
    assert e.implausible(robot, x0) == {}
    drawn = e.draw(robot, np.random.default_rng(3))   # what the generated data use is plausible too
    assert e.implausible(robot, drawn) == {} and not np.allclose(drawn, x0)


def test_poisson_ratio_is_a_physical_one():
    robot = Robot.nominal()
    e = StiffnessRatio()
    (p,) = e.params(robot)
    assert (p.plausible.low, p.plausible.high) == (0.0, 0.5)
    # nu = E / (2 G) - 1 of the nominal tubes
    t = robot.tubes[0]
    assert e.values(robot)[0] == pytest.approx(t.youngs_modulus_mpa / (2 * t.shear_modulus_mpa) - 1)
    bad = e.implausible(robot, np.array([-0.2]))
    assert list(bad) == ["poisson_ratio"]
    assert "-0.2" in bad["poisson_ratio"] and "[0, 0.5]" in bad["poisson_ratio"]
    stiff = e.with_values(robot, np.array([0.1]))
    assert all(tt.shear_modulus_mpa == pytest.approx(tt.youngs_modulus_mpa / 2.2) for tt in stiff.tubes)


def test_vector_limits_of_sensor_offset_gravity_and_tip_force():
    robot = Robot.nominal()
    side, sensor = robot.tubes[0].outer_radius_mm + 1.0, make_effect("sensor_offset")
    assert "sensor_offset_side_mm" in sensor.implausible(robot, np.array([1.0, 1.0, 3.0]))
    assert sensor.implausible(robot, np.array([0.6 * side, 0.0, 12.0])) == {}
    g = make_effect("gravity")
    assert g.implausible(robot, np.array([9.81, 0.0, 0.0])) == {}
    assert "gravity_magnitude_m_s2" in g.implausible(robot, np.array([15.0, 15.0, 0.0]))
    force = np.array([0.02, 0.02, 0.0])      # 28 mN: more than a cable's 20 mN and a 1.5 mm tool's 4 mN
    assert "tip_force_magnitude_n" in make_effect("tip_force").implausible(robot, force)


def _made_of(robot: Robot, youngs_gpa: float, density: float) -> Robot:
    return robot.with_changes(tubes=tuple(replace(t, youngs_modulus_mpa=youngs_gpa * 1e3,
                                                  shear_modulus_mpa=youngs_gpa * 1e3 / 2.7,
                                                  density_kg_m3=density) for t in robot.tubes))


def test_plausible_ranges_follow_the_material_of_the_robot_file():
    """A nylon robot (E 2 GPa, 1/25 of nitinol's 50) under gravity, with a tool on its 6 mm tip and a
    curvature relaxed by 55 %, is plausible; the same values for the nitinol file are not. Numbers
    from the material ranges (closed forms): |g| <= 9.81 (rho_max / E_min) / (rho / E)."""
    from ctrplan.model.causes.materials import NITINOL, POLYMER, material_of

    nitinol = Robot.nominal()
    nylon = _made_of(nitinol, 2.0, 1140.0)
    assert material_of(nylon.tubes[0]) is POLYMER and material_of(nitinol.tubes[0]) is NITINOL
    g = make_effect("gravity")
    assert math.isclose(g.max_magnitude(nylon), 9.81 * (2200 / 300) / (1140 / 2000))
    assert math.isclose(g.max_magnitude(nitinol), 9.81 * (6500 / 28e3) / (6450 / 50e3))
    down = np.array([0.0, -9.81, 0.0])
    assert g.implausible(nylon, down) == {} and g.implausible(nitinol, down) == {}
    assert "gravity_magnitude_m_s2" in g.implausible(nitinol, 25 * down)      # nitinol read as nylon
    kappa = make_effect("curvature")
    relaxed = kappa.values(nylon) * [1.0, 0.45, 1.0, 1.0, 1.0, 1.0]     # curvatures, then curved lengths
    assert kappa.implausible(nylon, relaxed) == {} and "kappa2_1_per_m" in kappa.implausible(nitinol, relaxed)
    wide = nylon.with_changes(tubes=tuple(replace(t, outer_diameter_mm=6.0, inner_diameter_mm=5.0)
                                          for t in nylon.tubes))
    force = make_effect("tip_force")
    tool = 9.81 * 7900 * math.pi / 4 * 0.006 ** 2 * 0.03             # a 6 mm steel tool, 30 mm long
    assert math.isclose(force.max_magnitude(wide), 0.02 + tool)
    weight = np.array([0.0, -0.04, 0.0])                               # 40 mN
    assert force.implausible(wide, weight) == {} and force.implausible(nitinol, weight) != {}
    assert "tool" in force.params(wide)[0].plausible.source


# ---- one robot, read back equal ---------------------------------------------------------------------
@pytest.mark.parametrize("n", [1, 2, 3, 4])
def test_every_effect_reads_back_equal_for_every_tube_count(tmp_path, n):
    base = robot_of(n)
    rng = np.random.default_rng(n)
    everything = base
    for name in CAUSES:
        e = make_effect(name)
        if not e.params(base):                      # bending_stiffness of one tube: nothing to set
            continue
        x = e.draw(base, rng)
        extended = e.with_values(base, x)
        path = tmp_path / f"{name}.yaml"
        extended.save(path, comment=f"{name} of {n} tubes")
        back = Robot.load(path)
        assert back.fingerprint == extended.fingerprint, (name, path.read_text())
        assert back.calibration == extended.calibration
        if isinstance(e, MeasurementEffect):
            np.testing.assert_array_equal(e.values(back), x)
        everything = e.with_values(everything, x)
    everything.save(tmp_path / "all.yaml")
    back = Robot.load(tmp_path / "all.yaml")
    assert back.fingerprint == everything.fingerprint and back.calibration == everything.calibration
    assert back.mechanics.calibration.is_identity and back.mechanics.joint_offset == everything.joint_offset


def test_two_tube_backlash_is_two_values(tmp_path):
    robot = make_effect("backlash").with_values(robot_of(2), np.array([0.02, 0.03]))
    path = tmp_path / "two.yaml"
    robot.save(path)
    assert "backlash_rad: [0.02, 0.03]" in path.read_text()
    assert Robot.load(path).calibration.values("backlash", 2).tolist() == [0.02, 0.03]
    path.write_text(path.read_text().replace("backlash_rad: [0.02, 0.03]", "backlash_rad: [0.02, 0.03, 0.0]"))
    with pytest.raises(InputError, match=r"two\.yaml:\d+: calibration\.backlash_rad: expected a list of 2 "):
        Robot.load(path)
    path.write_text(path.read_text().replace("backlash_rad: [0.02, 0.03, 0.0]", "stiction: [1]"))
    with pytest.raises(InputError, match=r"calibration\.stiction: unknown key \(allowed: backlash_rad, "):
        Robot.load(path)


def test_plain_robot_files_and_fingerprints_unchanged():
    """Keys at 0 that older files lack (transmission lengths, calibration) are not written."""
    d = Robot.nominal().to_dict()
    assert "calibration" not in d and all("transmission_length_mm" not in t for t in d["tubes"])


# ---- what a model predicts ------------------------------------------------------------------------
def test_measurement_side_maps_against_a_computation_written_here():
    rng = np.random.default_rng(0)
    q = np.column_stack([rng.uniform(-60, -20, 30), rng.uniform(-20, -5, 30), np.full(30, -3.0),
                         rng.uniform(-2, 2, (30, 3))])
    b, w = np.array([0.02, 0.0, 0.05]), np.array([1e-3, 2e-3, 0.0])
    d, rv, t = np.array([0.3, -0.2, 4.0]), np.array([0.01, -0.02, 0.03]), np.array([1.0, -2.0, 0.5])
    cal = Calibration().with_term("registration", np.r_[rv, t]).with_term("torsional_windup", w) \
        .with_term("sensor_offset", d).with_term("backlash", b)
    assert [name for name, _ in cal.terms] == ["backlash", "torsional_windup", "sensor_offset",
                                               "registration"]
    step = np.diff(q, axis=0, prepend=q[:1])
    step[:, 3:] = np.angle(np.exp(1j * step[:, 3:]))           # a rotation steps the short way round
    direction = np.sign(step)                                   # every joint moves in every row here
    reached = cal.mechanics_joints(q, Motion.of(q))
    np.testing.assert_allclose(reached[:, :3], q[:, :3])
    np.testing.assert_allclose(reached[:, 3:], q[:, 3:] - (b + w * -q[:, :3]) * direction[:, 3:])
    tips = rng.normal(size=(30, 3, 3)) * 50
    R_tip = Rotation.random(30, random_state=1).as_matrix()
    R = Rotation.from_rotvec(rv).as_matrix()
    expect = tips.copy()
    expect[:, 0] += np.einsum("nij,j->ni", R_tip, d)            # the sensor sits in the tip frame ...
    expect = expect @ R.T + t                                    # ... then the tracker frame
    np.testing.assert_allclose(cal.tracked_tips(tips, R_tip), expect, atol=1e-12)
    np.testing.assert_allclose(cal.to_robot_frame(cal.to_tracker_frame(tips)), tips, atol=1e-10)
    assert cal.needs_tip_rotation and not Calibration().with_term("backlash", b).needs_tip_rotation


def test_prediction_is_mechanics_joints_then_pure_mechanics_then_tracker(robot):
    ext = make_effect("joint_offset+backlash+sensor_offset+registration+curvature").with_values(
        robot, np.r_[0.5, -1.0, 0.3, 0.02, -0.01, 0.0, 0.03, 0.02, 0.01, 0.2, -0.1, 3.0,
                     0.01, 0.02, -0.01, 1.0, 0.5, -0.3, 30.0, 12.0, 4.0, 38.0, 100.0, 100.0])
    q = robot.sample_joints(25, rng=4)
    motion = Motion.of(q)
    pred = Evaluator(q, motion, SolverSettings()).predict([ext])[0]
    bb = CosseratBackend(ext.mechanics).forward(ext.calibration.mechanics_joints(q, motion), points=2,
                                                check=False)
    np.testing.assert_allclose(pred.tips_mm, ext.calibration.tracked_tips(bb.tips_mm, bb.rotations[:, -1]),
                               atol=1e-9)
    assert not np.allclose(pred.tips_mm, bb.tips_mm, atol=0.1)


def test_transmission_length_against_the_independent_integrator():
    robot = Robot.nominal()
    d = np.array([30.0, -4.0, 12.0])
    q = robot.sample_joints(20, rng=1)
    q[:, :3] -= 5.0                                  # every tube twists over at least 5 mm: -beta + d >= 0
    ext = make_effect("transmission").with_values(robot, d)
    ours = CosseratBackend(ext).forward(q, points=2, check=False).tips_mm
    theirs = solve(q, replace(Tubes.paper(), transmission_mm=d))["tips_mm"]
    np.testing.assert_allclose(ours, theirs, atol=1e-3)
    assert np.abs(ours - CosseratBackend(robot).forward(q, points=2, check=False).tips_mm).max() > 0.5


def test_the_pinn_boundary_loss_models_a_transmission():
    """theta_i(0) = alpha_i - (beta_i - d_i) u_iz(0): the boundary loss vanishes on the exact states of a
    robot whose tube 2 twists over 20 mm more than -beta_2, and not on those of the robot without."""
    import torch

    from ctrplan.training.losses import boundary_residual
    from ctrplan.training.physics import TubeTensors

    robot = Robot.nominal()
    ext = make_effect("transmission").with_values(robot, np.array([0.0, 20.0, 0.0]))
    q = robot.sample_joints(6, rng=3)
    solver = CosseratBackend(ext)

    class Exact:
        scales = torch.ones(robot.n_states, dtype=torch.float64)

        def __call__(self, sigma, qq):
            return torch.tensor(np.array([solver.forward(qi.numpy(), np.array([float(si)])).state[0, 0]
                                          for si, qi in zip(sigma, qq, strict=True)]))

    qt = torch.tensor(q)
    with_d, without = (TubeTensors.from_robot(r, dtype=torch.float64) for r in (ext, robot))
    assert float(boundary_residual(Exact(), qt, with_d).max()) < 1e-12
    assert float(boundary_residual(Exact(), qt, without).sum()) > 1e-6
