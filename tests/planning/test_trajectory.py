"""Timed trajectories: the robot's speed and acceleration limits hold for every joint (checked by
finite differences of the sampled motion, not by the profile's own numbers), waypoints are reached
at rest, a single-joint move takes the closed-form minimum time, and a robot file's ``limits:``
change the timing but not the robot's fingerprint (a PINN or certificate still applies)."""

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


def test_every_joint_stays_within_its_limits_and_stops_at_each_waypoint():
    rng = np.random.default_rng(3)
    path = np.cumsum(rng.normal(0.0, [5, 5, 2, 0.8, 0.8, 0.3], size=(7, 6)), axis=0)
    traj = time_parametrise(path, LIMITS)
    t = np.linspace(0.0, traj.duration_s, 40001)
    q, _ = traj.at(t)
    dt = t[1] - t[0]
    speed = np.abs(np.diff(q, axis=0)) / dt
    accel = np.abs(np.diff(q, 2, axis=0)) / dt**2
    vmax, amax = LIMITS.per_joint(3)
    assert np.all(speed.max(axis=0) <= vmax * (1 + 1e-3))
    assert np.all(np.percentile(accel, 99.9, axis=0) <= amax * (1 + 1e-2))  # kinks at profile switches
    assert np.any(speed.max(axis=0) >= 0.98 * vmax)  # and it is not needlessly slow
    at_waypoints, velocity = traj.at(traj.times_s)
    np.testing.assert_allclose(at_waypoints, path, atol=1e-9)
    np.testing.assert_allclose(velocity, 0.0, atol=1e-9)
    seg = np.repeat(np.arange(len(path) - 1), 5)
    frac = np.tile(np.linspace(0, 1, 5), len(path) - 1)
    q_frac, _ = traj.at(traj.time_of(seg, frac))
    np.testing.assert_allclose(q_frac, path[seg] + frac[:, None] * (path[seg + 1] - path[seg]), atol=1e-6)


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
