"""Timed trajectories: the robot's speed and acceleration limits hold for every joint (checked by
finite differences of the sampled motion, not by the profile's own numbers), stops are reached at
rest, passed waypoints are cut only inside their blends and by the closed-form bound, a blend the
exact model refuses becomes a stop, a single-joint move takes the closed-form minimum time, and a
robot file's ``limits:`` and ``actuators:`` change the timing and the units but not the robot's
fingerprint (a PINN or certificate still applies)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import ctrplan
from ctrplan.base.errors import InputError
from ctrplan.base.yamlio import load_yaml
from ctrplan.model.robot import JointLimits, Robot, robot_from_yaml
from ctrplan.planning.trajectory import time_parametrise

LIMITS = JointLimits(speed_mm_per_s=4.0, speed_rad_per_s=0.5, acceleration_mm_per_s2=8.0,
                     acceleration_rad_per_s2=2.0)


def test_a_single_translation_takes_the_closed_form_minimum_time():
    d, v, a = 20.0, 4.0, 8.0  # long enough to cruise: d > v^2 / a
    path = np.zeros((2, 6))
    path[1, 0] = d
    assert time_parametrise(path, LIMITS).duration_s == pytest.approx(d / v + v / a)
    path[1, 0] = 1.0  # too short to cruise: accelerate half way, brake half way
    assert time_parametrise(path, LIMITS).duration_s == pytest.approx(2.0 * np.sqrt(1.0 / a))


def sampled_limits_hold(traj, n_joints: int = 6) -> np.ndarray:
    """Finite differences of the sampled motion against the limits; returns the peak speeds."""
    t = np.linspace(0.0, traj.duration_s, 40001)
    q, qd = traj.at(t)
    dt = t[1] - t[0]
    speed = np.abs(np.diff(q, axis=0)) / dt
    accel = np.abs(np.diff(q, 2, axis=0)) / dt**2
    vmax, amax = LIMITS.per_joint(n_joints // 2)
    assert np.all(speed.max(axis=0) <= vmax * (1 + 1e-3))
    assert np.all(np.abs(qd).max(axis=0) <= vmax * (1 + 1e-9))  # the profile's own velocities too
    assert np.all(np.percentile(accel, 99.9, axis=0) <= amax * (1 + 1e-2))  # kinks at profile switches
    assert np.all(np.abs(np.diff(qd, axis=0)).max(axis=0) / dt <= amax * (1 + 1e-6))  # velocity is continuous
    return speed.max(axis=0)


@pytest.fixture
def path() -> np.ndarray:
    rng = np.random.default_rng(3)
    return np.cumsum(rng.normal(0.0, [5, 5, 2, 0.8, 0.8, 0.3], size=(7, 6)), axis=0)


def test_stopping_at_each_waypoint_keeps_every_limit_and_the_segments(path):
    traj = time_parametrise(path, LIMITS)
    peaks = sampled_limits_hold(traj)
    vmax, _ = LIMITS.per_joint(3)
    assert np.any(peaks >= 0.98 * vmax)  # and it is not needlessly slow
    at_waypoints, velocity = traj.at(traj.waypoint_s)
    np.testing.assert_allclose(at_waypoints, path, atol=1e-9)
    np.testing.assert_allclose(velocity, 0.0, atol=1e-9)
    q, _ = traj.at(np.linspace(0.0, traj.duration_s, 2001))  # every state on the polyline
    assert polyline_distance(path, q).max() < 1e-9


def polyline_distance(path: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Distance (joint units) of states q (S, 2N) from the polyline ``path`` (K, 2N)."""
    a, d = path[:-1], np.diff(path, axis=0)
    f = np.clip(np.einsum("skj,kj->sk", q[:, None, :] - a[None], d) / np.einsum("kj,kj->k", d, d), 0, 1)
    return np.linalg.norm(q[:, None, :] - (a[None] + f[..., None] * d[None]), axis=2).min(axis=1)


def test_passing_waypoints_keeps_every_limit_and_only_cuts_corners_in_blends(path):
    """Without stops the robot keeps moving at the waypoints, every limit holds, it is faster, and
    it leaves the checked segments only inside a blend, by at most |v_k - v_k-1| b_k / 8."""
    stop_all = time_parametrise(path, LIMITS)
    passing = time_parametrise(path, LIMITS, np.zeros(len(path), dtype=bool))
    sampled_limits_hold(passing)
    assert passing.duration_s < stop_all.duration_s
    _, v = passing.at(passing.waypoint_s[1:-1])
    assert np.all(np.abs(v).max(axis=1) > 0)  # moving through the inner waypoints
    np.testing.assert_allclose(passing.at(np.array([0.0, passing.duration_s]))[0], path[[0, -1]], atol=1e-9)
    t = np.linspace(0.0, passing.duration_s, 20001)
    q, _ = passing.at(t)
    in_blend = np.zeros(len(t), dtype=bool)
    for k in range(1, len(path) - 1):
        lo, hi = passing.blend_s[k]
        in_blend |= (t > lo) & (t < hi)
    off = polyline_distance(path, q)
    assert off[~in_blend].max() < 1e-9  # on the segments outside the blends
    for k in range(1, len(path) - 1):
        lo, hi = passing.blend_s[k]
        (_, vin), (_, vout) = (passing.at(np.array([x])) for x in (lo, hi))
        corner, _ = passing.at(np.array([0.5 * (lo + hi)]))
        bound = np.abs(vout - vin)[0] * (hi - lo) / 8
        assert np.all(np.abs(corner[0] - path[k]) <= bound + 1e-9)


def test_a_blend_the_exact_model_refuses_becomes_a_stop(path):
    """`executed_trajectory` checks every blend's states; where they fail (here: a forbidden
    neighbourhood of waypoint 3 off the segments), that waypoint becomes a stop and nothing else."""
    from ctrplan.planning.trajectory import executed_trajectory

    def valid(q):  # states off the polyline near waypoint 3 are "in collision"
        near = np.linalg.norm(q - path[3], axis=1) < 2.0
        return ~(near & (polyline_distance(path, q) > 1e-6))

    def spacing(q):
        return np.linalg.norm(np.diff(q, axis=0), axis=1)

    traj = executed_trajectory(path, LIMITS, valid, spacing, 0.05)
    assert traj.stops.tolist() == [True, False, False, True, False, False, True]
    sampled_limits_hold(traj)


def test_robot_file_limits_time_the_motion_but_keep_the_fingerprint(tmp_path):
    nominal = Robot.nominal()
    source = (Path(ctrplan.__file__).parent / "data" / "nominal.yaml").read_text()
    path = tmp_path / "slow.yaml"
    path.write_text(source + "limits: {speed_mm_per_s: 1.0, acceleration_rad_per_s2: 1.0}\n")
    slow = robot_from_yaml(load_yaml(path))
    assert slow.limits.speed_mm_per_s == 1.0 and slow.limits.speed_rad_per_s == JointLimits().speed_rad_per_s
    assert slow.fingerprint == nominal.fingerprint
    move = np.zeros((2, 6))
    move[1, 0] = 30.0
    slow_s = time_parametrise(move, slow.limits).duration_s
    assert slow_s > 5 * time_parametrise(move, nominal.limits).duration_s
    path.write_text(source + "limits: {speed_mm_per_s: -1.0}\n")
    with pytest.raises(InputError, match="limits.speed_mm_per_s"):
        robot_from_yaml(load_yaml(path))


@pytest.mark.parametrize(("text", "where"), [
    ("actuators: {beta4: {counts_per_mm: 1}}", "actuators.beta4: not a joint of this robot"),
    ("actuators: {beta1: {counts_per_rad: 1}}", "actuators.beta1.counts_per_rad: unknown key"),
    ("actuators: {alpha1: {counts_per_rad: -3}}", "alpha1.counts_per_rad: expected a finite number > 0"),
    ("actuators: {alpha1: {counts_per_rad: 3, sign: 0}}", "actuators.alpha1.sign: expected 1 or -1"),
    ("actuators: {alpha1: {counts_per_rad: 3, name: beta1}}", "alpha1.name: expected a column name"),
    ("actuators: {beta2: {offset: 3}}", "actuators.beta2: missing required key 'counts_per_mm'"),
])
def test_bad_actuators_are_one_error_naming_the_key(tmp_path, text, where):
    source = (Path(ctrplan.__file__).parent / "data" / "nominal.yaml").read_text()
    path = tmp_path / "r.yaml"
    path.write_text(source + text + "\n")
    with pytest.raises(InputError, match=where.replace(".", r"\.").replace("'", ".")):
        robot_from_yaml(load_yaml(path))


def test_actuators_map_joints_to_counts_and_keep_the_fingerprint(tmp_path):
    source = (Path(ctrplan.__file__).parent / "data" / "nominal.yaml").read_text()
    path = tmp_path / "driven.yaml"
    path.write_text(source + "actuators:\n  alpha2: {counts_per_rad: 100, offset: 7, sign: -1}\n"
                             "  beta3: {counts_per_mm: 2000, name: outer}\n")
    robot = robot_from_yaml(load_yaml(path))
    assert robot.fingerprint == Robot.nominal().fingerprint
    outer, alpha2 = robot.actuators  # in joint order
    q = np.array([[-80.0, -60.0, -5.0, 0.1, 0.5, -0.2]])
    assert (outer.name, alpha2.name) == ("outer", "alpha2_counts")
    assert outer.position(q)[0] == pytest.approx(-10_000.0) and alpha2.position(q)[0] == pytest.approx(-43.0)
    assert alpha2.rate(np.ones((1, 6)))[0] == pytest.approx(-100.0)
    robot.save(tmp_path / "again.yaml")  # the file form round-trips
    assert Robot.load(tmp_path / "again.yaml").actuators == robot.actuators
