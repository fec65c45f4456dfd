"""A timed trajectory from a validated path that a controller can take: within the robot's joint
speed and acceleration limits (`ctrplan.model.robot.JointLimits`), passing waypoints without
stopping where the exact model allows it, sampled at a fixed rate with velocities.

**Timing** (`time_parametrise`): linear segments with parabolic blends (LSPB through via points).
Segment k from waypoint ``q_k`` to ``q_k+1`` is crossed at the constant joint velocity
``v_k = (q_k+1 - q_k) / T_k``, every joint synchronised, ``T_k`` at least what the slowest joint
needs at its speed limit. At a waypoint the velocity changes from ``v_k-1`` to ``v_k`` at constant
acceleration over a blend of ``b_k = max_j |v_k,j - v_k-1,j| / a_j`` centred on the time the two
lines cross there: no joint exceeds its acceleration limit, and speeds in a blend lie between those of
its two segments, so none exceeds its speed limit. Blends must fit in their segments
(``T_k >= (b_k + b_k+1) / 2``): a segment where they would not is crossed more slowly. At a **stop**
(the first and last waypoints, and any the exact model requires) the velocity goes to 0 and back: the
robot reaches the waypoint at rest.

**On checked ground** (`executed_trajectory`): off its blends the robot moves on the straight
joint-space segments the exact validation checked; a blend cuts the corner at a waypoint (by at
most ``|v_k - v_k-1| b_k / 8`` per joint), so its states are checked with the exact model (collision
with every margin, stability, convergence) at the validation resolution; a waypoint whose blend
fails becomes a stop, and the blends are timed and checked again, until every one holds.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ctrplan.model.robot import JointLimits

#: Rounds of slowing down segments whose blends do not fit before the rest are slowed to the bound.
FIT_ROUNDS = 50


@dataclass(frozen=True)
class Trajectory:
    """Piecewise constant-acceleration motion of the joints (mm, rad): pieces starting at
    ``start_s`` (P,) s at joints ``q0`` (P, 2N) with velocities ``v0`` (P, 2N) (mm/s, rad/s) and
    accelerations ``acc`` (P, 2N); the waypoints (K, 2N), which are stops ``stops`` (K,) bool, when
    the robot is at (a stop) or nearest to (a pass) each, ``waypoint_s`` (K,), and each waypoint's
    blend, ``blend_s`` (K, 2): start and end (s) of the change of velocity there."""

    start_s: np.ndarray
    q0: np.ndarray
    v0: np.ndarray
    acc: np.ndarray
    duration_s: float
    waypoints: np.ndarray
    stops: np.ndarray
    waypoint_s: np.ndarray
    blend_s: np.ndarray

    def at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Joints (T, 2N) and joint velocities (T, 2N) (mm/s, rad/s) at times ``t`` (T,) s."""
        t = np.clip(np.asarray(t, dtype=float), 0.0, self.duration_s)
        k = np.clip(np.searchsorted(self.start_s, t, side="right") - 1, 0, len(self.start_s) - 1)
        tau = (t - self.start_s[k])[:, None]
        return (self.q0[k] + self.v0[k] * tau + 0.5 * self.acc[k] * tau**2,
                self.v0[k] + self.acc[k] * tau)


def time_parametrise(path_q: np.ndarray, limits: JointLimits, stops: np.ndarray | None = None) -> Trajectory:
    """The blended trajectory through ``path_q`` (K, 2N) within ``limits``, at rest at the waypoints
    ``stops`` (K,) bool (default: every one; the first and last always)."""
    path = np.atleast_2d(np.asarray(path_q, dtype=float))
    k_count, dims = path.shape
    stops = np.ones(k_count, dtype=bool) if stops is None else np.asarray(stops, dtype=bool).copy()
    stops[[0, -1]] = True
    vmax, amax = limits.per_joint(dims // 2)
    twice = stops.copy()
    twice[[0, -1]] = False  # a stop inside the path is a zero-length segment: velocity to 0 and back
    expanded = np.repeat(np.arange(k_count), np.where(twice, 2, 1))
    w = path[expanded]
    d = np.diff(w, axis=0)
    dur, b = _fit_blends(d, np.max(np.abs(d) / vmax, axis=1, initial=0.0), amax)
    v = _velocities(d, dur)
    vin, vout = np.vstack([np.zeros(dims), v]), np.vstack([v, np.zeros(dims)])
    t_w = b[0] / 2 + np.concatenate([[0.0], np.cumsum(dur)])  # times the lines cross at the waypoints
    starts, q0, v0, acc = [0.0], [w[0]], [np.zeros(dims)], [np.zeros(dims)]  # at rest until it moves
    for i in range(len(w)):
        if b[i] > 0:  # blend
            starts.append(t_w[i] - b[i] / 2)
            q0.append(w[i] - vin[i] * b[i] / 2)
            v0.append(vin[i])
            acc.append((vout[i] - vin[i]) / b[i])
        if i < len(w) - 1:  # the straight part of segment i
            starts.append(t_w[i] + b[i] / 2)
            q0.append(w[i] + vout[i] * b[i] / 2)
            v0.append(vout[i])
            acc.append(np.zeros(dims))
    first, last = np.searchsorted(expanded, np.arange(k_count), "left"), \
        np.searchsorted(expanded, np.arange(k_count), "right") - 1
    blend = np.column_stack([t_w[first] - b[first] / 2, t_w[last] + b[last] / 2])
    at = np.where(stops, t_w[first] + b[first] / 2, t_w[first])
    at[0] = 0.0  # at rest at the start until the first blend
    return Trajectory(np.array(starts), np.array(q0), np.array(v0), np.array(acc),
                      float(t_w[-1] + b[-1] / 2), path, stops, at, blend)


def _velocities(d: np.ndarray, dur: np.ndarray) -> np.ndarray:
    return np.where(dur[:, None] > 0, d / np.where(dur > 0, dur, 1.0)[:, None], 0.0)


def _blends(d: np.ndarray, dur: np.ndarray, amax: np.ndarray) -> np.ndarray:
    """Blend durations (M+1,) of segments ``d`` (M, 2N) crossed in ``dur`` (M,) s, at rest at both ends."""
    padded = np.vstack([np.zeros(d.shape[1]), _velocities(d, dur), np.zeros(d.shape[1])])
    return np.max(np.abs(np.diff(padded, axis=0)) / amax, axis=1)


def _fit_blends(d: np.ndarray, t_min: np.ndarray, amax: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Segment durations (M,) >= ``t_min`` and blend durations b (M+1,) with every pair of blends
    fitting in its segment, T_k >= (b_k + b_k+1) / 2: each segment where they would not is slowed to
    the shortest duration that fits (bisection, its neighbours held), round after round; after
    `FIT_ROUNDS` rounds to a bound that fits every blend (speeds only fall as segments slow, so no
    blend ever lasts longer than twice the longest speed-to-rest time)."""
    dur = t_min.copy()
    bound = 2.0 * float(np.max(np.abs(_velocities(d, dur)).max(axis=0, initial=0.0) / amax))
    for rounds in range(FIT_ROUNDS + len(d) + 1):
        b = _blends(d, dur, amax)
        short = np.flatnonzero(dur < 0.5 * (b[:-1] + b[1:]) * (1.0 - 1e-12))
        if not len(short):
            return dur, b
        for k in short:
            dur[k] = _shortest_fit(d, dur, k, amax) if rounds < FIT_ROUNDS else max(dur[k], bound)
    return dur, _blends(d, dur, amax)  # pragma: no cover - the bound fits every blend


def _shortest_fit(d: np.ndarray, dur: np.ndarray, k: int, amax: np.ndarray) -> float:
    """The shortest duration of segment k (its neighbours held) in which its two blends fit."""
    def fits(x: float) -> bool:
        trial = dur.copy()
        trial[k] = x
        b = _blends(d[max(k - 1, 0):k + 2], trial[max(k - 1, 0):k + 2], amax)
        i = min(k, 1)  # segment k's blends in the slice
        return x >= 0.5 * (b[i] + b[i + 1]) * (1.0 - 1e-12)

    lo, hi = dur[k], max(dur[k], 1e-9) * 2.0
    while not fits(hi):
        lo, hi = hi, 2.0 * hi
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if fits(mid) else (mid, hi)
    return hi


def blend_states(traj: Trajectory, waypoints: np.ndarray, spacing: Callable[[np.ndarray], np.ndarray],
                 resolution: float) -> tuple[np.ndarray, np.ndarray]:
    """The states (S, 2N) the trajectory passes in the blends of ``waypoints`` (indices), at most
    ``resolution`` apart by ``spacing`` (the planning metric of consecutive rows), and the waypoint
    each belongs to (S,)."""
    states, owner = [np.zeros((0, traj.waypoints.shape[1]))], [np.zeros(0, dtype=int)]
    for k in waypoints:
        t0, t1 = traj.blend_s[int(k)]
        if t1 <= t0:
            continue
        coarse, _ = traj.at(np.linspace(t0, t1, 9))
        n = max(2, int(np.ceil(spacing(coarse).sum() / resolution)) + 1)
        q, _ = traj.at(np.linspace(t0, t1, n))
        states.append(q)
        owner.append(np.full(n, int(k)))
    return np.concatenate(states), np.concatenate(owner)


def executed_trajectory(path_q: np.ndarray, limits: JointLimits, valid: Callable[[np.ndarray], np.ndarray],
                        spacing: Callable[[np.ndarray], np.ndarray], resolution: float) -> Trajectory:
    """The trajectory through ``path_q`` that stops only where it must: every blend's states
    (`blend_states`) pass ``valid`` (states (S, 2N) -> (S,) bool: the exact model's checks); a
    waypoint whose blend does not becomes a stop (see the module docstring)."""
    path = np.atleast_2d(np.asarray(path_q, dtype=float))
    stops = np.zeros(len(path), dtype=bool)
    while True:
        traj = time_parametrise(path, limits, stops)
        states, owner = blend_states(traj, np.flatnonzero(~traj.stops), spacing, resolution)
        bad = np.unique(owner[~valid(states)]) if len(states) else np.zeros(0, dtype=int)
        if not len(bad):
            return traj
        stops[bad] = True


def sample_times(duration_s: float, rate_hz: float) -> np.ndarray:
    """Times (s) at a fixed rate from 0, and the end (its own row when it falls between two)."""
    t = np.arange(0.0, duration_s, 1.0 / rate_hz) if duration_s > 0 else np.zeros(1)
    return np.append(t, duration_s) if duration_s - t[-1] > 1e-9 else t
