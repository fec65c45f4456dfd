"""A timed trajectory from a validated path: the robot stops at each waypoint and moves between
them on the straight joint-space segment the exact validation checked, every joint synchronised on
one trapezoidal (or, for short segments, triangular) speed profile within the robot's speed and
acceleration limits (`ctrplan.model.robot.JointLimits`).

Along a segment from ``q_a`` to ``q_b`` the joints are ``q_a + u(t) (q_b - q_a)``, ``u`` from 0 to 1.
Joint j then moves at ``|d_j| u'`` and accelerates at ``|d_j| u''``, so the limits on ``u`` are
``min_j v_j / |d_j|`` and ``min_j a_j / |d_j|``: the slowest joint sets the pace and no joint exceeds
its limit. Stopping at waypoints keeps the robot on the checked segments exactly (a blend would cut
corners the validation never saw).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ctrplan.model.robot import JointLimits


@dataclass(frozen=True)
class Trajectory:
    """Waypoints (K, 2N) (mm, rad) reached at ``times_s`` (K,), with the profile of each segment:
    peak path speed ``peak`` (K-1,) and acceleration ``accel`` (K-1,) of ``u`` (1/s, 1/s^2)."""

    waypoints: np.ndarray
    times_s: np.ndarray
    peak: np.ndarray
    accel: np.ndarray

    @property
    def duration_s(self) -> float:
        return float(self.times_s[-1])

    def at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Joints (T, 2N) and joint velocities (T, 2N) (mm/s, rad/s) at times ``t`` (T,) s."""
        t = np.clip(np.asarray(t, dtype=float), 0.0, self.duration_s)
        k = np.clip(np.searchsorted(self.times_s, t, side="right") - 1, 0, len(self.peak) - 1)
        start, end = self.times_s[k], self.times_s[k + 1]
        u, du = _profile(t - start, end - start, self.peak[k], self.accel[k])
        d = self.waypoints[k + 1] - self.waypoints[k]
        return self.waypoints[k] + u[:, None] * d, du[:, None] * d

    def time_of(self, segment: np.ndarray, fraction: np.ndarray) -> np.ndarray:
        """Times (s) at which the robot is ``fraction`` (0..1) of the way along ``segment``."""
        k = np.asarray(segment, dtype=int)
        f = np.clip(np.asarray(fraction, dtype=float), 0.0, 1.0)
        T, v, a = self.times_s[k + 1] - self.times_s[k], self.peak[k], self.accel[k]
        ramp = v * v / (2.0 * a)  # distance in u covered while speeding up
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(f <= ramp, np.sqrt(2.0 * f / a),
                         np.where(f <= 1.0 - ramp, v / a + (f - ramp) / v, T - np.sqrt(2.0 * (1.0 - f) / a)))
        return self.times_s[k] + np.where(T > 0, t, 0.0)


def _profile(tau: np.ndarray, T: np.ndarray, v: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Path fraction u and its rate at time ``tau`` into a segment of duration T (trapezoid)."""
    ta = np.where(a > 0, v / np.where(a > 0, a, 1.0), 0.0)
    up = tau < ta
    down = tau > T - ta
    u = np.where(up, 0.5 * a * tau**2,
                 np.where(down, 1.0 - 0.5 * a * (T - tau) ** 2, 0.5 * a * ta**2 + v * (tau - ta)))
    du = np.where(up, a * tau, np.where(down, a * (T - tau), v))
    return np.where(T > 0, u, 1.0), np.where(T > 0, du, 0.0)


def time_parametrise(path_q: np.ndarray, limits: JointLimits) -> Trajectory:
    """The fastest stop-at-every-waypoint trajectory through ``path_q`` (K, 2N) within ``limits``."""
    q = np.atleast_2d(np.asarray(path_q, dtype=float))
    speed, accel = limits.per_joint(q.shape[1] // 2)
    segments = [_segment(np.abs(d), speed, accel) for d in np.diff(q, axis=0)]
    T, v, a = (np.array([seg[i] for seg in segments], dtype=float).reshape(-1) for i in range(3))
    return Trajectory(waypoints=q, times_s=np.r_[0.0, np.cumsum(T)], peak=v, accel=a)


def _segment(d: np.ndarray, speed: np.ndarray, accel: np.ndarray) -> tuple[float, float, float]:
    """Duration (s), peak rate and acceleration of u over one segment of joint moves ``d`` (2N,) >= 0."""
    moving = d > 0
    if not moving.any():
        return 0.0, 0.0, 0.0
    v = float(np.min(speed[moving] / d[moving]))
    a = float(np.min(accel[moving] / d[moving]))
    if v * v / a >= 1.0:  # u never reaches v: accelerate half way, then brake
        return 2.0 / np.sqrt(a), float(np.sqrt(a)), a
    return 1.0 / v + v / a, v, a


def segment_positions(waypoints: np.ndarray, states: np.ndarray,
                      tol: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """Segment index and fraction (0..1) of each of ``states`` (S, 2N), points on the polyline
    ``waypoints`` (K, 2N) taken in order (a densified path: every state lies on the segment of its
    predecessor or a later one). Raises ValueError for a state off the polyline."""
    k = 0
    segment, fraction = np.zeros(len(states), dtype=int), np.zeros(len(states))
    for i, q in enumerate(states):
        while True:
            a, d = waypoints[k], waypoints[k + 1] - waypoints[k]
            dd = float(d @ d)
            f = float((q - a) @ d / dd) if dd > 0 else 0.0
            on = 0 <= f <= 1 + tol and np.linalg.norm(a + min(f, 1.0) * d - q) <= tol * (1 + np.sqrt(dd))
            if on or k == len(waypoints) - 2:
                break
            k += 1
        if not on:
            raise ValueError(f"state {i} is not on the path")
        segment[i], fraction[i] = k, min(max(f, 0.0), 1.0)
    return segment, fraction
