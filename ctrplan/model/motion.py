"""How measured rows got where they are: the motion history of joints acquired in sequence.

Direction-dependent effects (backlash, friction, a tracker's latency) need more than a row's joints:
the step from the row before, the direction of the latest motion, the travel since a reversal. They
come from the whole acquisition, in its order; a fit on some of its rows (training rows, held-out
blocks) must see the same history as the file. `Motion` keeps it: built once from the whole sequence
(`Motion.of`), cut to rows with `subset` (the history stays the file's).

Rotations are reported in any range: a step of more than pi between two rows is the angle wrapping
around, not a reversal (`joint_steps`), and the travel of a rotation is its unwrapped angle.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


def joint_steps(q: np.ndarray) -> np.ndarray:
    """Steps between consecutive rows (R - 1, 2N) of joints q (R, 2N) in acquisition order, mm and rad.

    A rotation step is taken the short way round, in (-pi, pi]: rows are acquired fast enough that a
    rotation turns less than half a turn between two of them, so a step of more than pi is the reported
    angle wrapping around (3.10 -> -3.13 rad is a step of +0.05 rad, not a reversal of -6.23 rad)."""
    q = np.asarray(q, dtype=float)
    step = np.diff(q, axis=0)
    n = q.shape[1] // 2
    step[:, n:] = np.pi - np.mod(np.pi - step[:, n:], 2.0 * np.pi)
    return step


def continuous_joints(q: np.ndarray) -> np.ndarray:
    """Joints q (R, 2N) in acquisition order with every rotation unwrapped (`joint_steps` summed from
    the first row): how far each drive has travelled, for operators with a memory of the travel."""
    q = np.asarray(q, dtype=float)
    if len(q) < 2:
        return q.copy()
    return np.concatenate([q[:1], q[:1] + np.cumsum(joint_steps(q), axis=0)])


def motion_direction(q: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """Direction of the latest motion of every joint (R, 2N) in {-1, 0, +1}, from consecutive rows
    (`joint_steps`: a rotation wrapping around at +-pi keeps its direction).

    A joint that did not move keeps the direction of its last move (a backlash gap stays taken up on
    the side it was last driven); before its first move the direction is 0.
    """
    q = np.asarray(q, dtype=float)
    d = np.zeros_like(q)
    step = joint_steps(q)
    cur = np.zeros(q.shape[1])
    for r in range(1, len(q)):
        s = step[r - 1]
        moved = np.abs(s) > tol
        cur = np.where(moved, np.sign(s), cur)
        d[r] = cur
    return d


def play_lag(travel: np.ndarray, radius: float) -> np.ndarray:
    """Normalised lag (S,) in [-1, 1] of a play operator of half-width ``radius`` behind the travel
    (S,) of one joint in acquisition order: its output y follows the travel x only when x is more than
    ``radius`` away, y_k = clip(y_(k-1), x_k - r, x_k + r), y_0 = x_0 (no lag before the first move);
    the value is (x - y) / r. After a reversal it ramps from +-1 to -+1 over 2 r of travel: a spring
    that takes up the slack before a Coulomb slider gives (a Maxwell-slip element)."""
    x = np.asarray(travel, dtype=float)
    out = np.zeros_like(x)
    if not len(x) or radius <= 0.0:
        return out
    y = x[0]
    for k, xk in enumerate(x):
        y = min(max(y, xk - radius), xk + radius)
        out[k] = (xk - y) / radius
    return out


@dataclass(frozen=True, eq=False)
class Motion:
    """The motion history of some rows of an acquisition: ``travel`` (S, 2N) are the continuous joints
    of the whole sequence (`continuous_joints`), ``rows`` (R,) the rows of it these are, ``session``
    (S,) the measurement session of every row of the sequence (None: one session). Each run of rows of
    one session is a sequence of its own: its first row has no step, no direction, no play. Per row:
    `step` from the row before, `direction` of the latest motion, `play` of a joint's travel.

    ``independent``: rows that are not a sequence (each configuration on its own, e.g. random
    samples): no steps, no direction, no play."""

    travel: np.ndarray
    rows: np.ndarray
    session: np.ndarray | None = None
    independent: bool = False
    _cache: dict = field(default_factory=dict, repr=False)

    @classmethod
    def of(cls, q: np.ndarray, session: np.ndarray | None = None, independent: bool = False) -> Motion:
        """The motion of joints q (R, 2N) in acquisition order, ``session`` (R,) naming each row's
        measurement session (or, ``independent``, of rows that are not a sequence)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        session = None if session is None else np.asarray(session)
        travel = np.concatenate([continuous_joints(q[run]) for run in _runs(session, len(q))]) if len(q) \
            else q.copy()
        return cls(travel, np.arange(len(q)), session, independent)

    def subset(self, idx) -> Motion:
        """The motion of rows ``idx`` of these (their history is still the whole sequence's)."""
        return Motion(self.travel, self.rows[np.asarray(idx)], self.session, self.independent, self._cache)

    def __len__(self) -> int:
        return len(self.rows)

    @property
    def sessions(self) -> np.ndarray | None:
        """The session of each of these rows (R,), or None (one session)."""
        return None if self.session is None else self.session[self.rows]

    def _whole(self, key, make) -> np.ndarray:
        """A per-row quantity of the whole sequence, made run by run (``make(travel of a run)``)."""
        if key not in self._cache:
            self._cache[key] = np.concatenate([make(self.travel[run])
                                               for run in _runs(self.session, len(self.travel))])
        return self._cache[key]

    @property
    def step(self) -> np.ndarray:
        """Step of every joint from the row before (R, 2N), mm and rad (0 for the first row of a run)."""
        if self.independent:
            return np.zeros((len(self), self.travel.shape[1]))
        return self._whole("step", lambda t: np.diff(t, axis=0, prepend=t[:1]))[self.rows]

    @property
    def direction(self) -> np.ndarray:
        """Direction of the latest motion of every joint (R, 2N) in {-1, 0, +1} (`motion_direction`)."""
        if self.independent:
            return np.zeros((len(self), self.travel.shape[1]))
        return self._whole("direction", motion_direction)[self.rows]

    def play(self, joint: int, radius: float) -> np.ndarray:
        """`play_lag` (R,) of joint ``joint``'s travel for a play of half-width ``radius`` (mm or rad);
        radius 0 is the direction of motion (an instant flip: backlash)."""
        if self.independent:
            return np.zeros(len(self))
        if radius <= 0.0:
            return self.direction[:, joint]
        return self._whole(("play", joint, float(radius)),
                           lambda t: play_lag(t[:, joint], radius))[self.rows]


def _runs(session: np.ndarray | None, n: int) -> list[slice]:
    """The runs of consecutive rows of one session (one run without sessions)."""
    if session is None or n == 0:
        return [slice(0, n)]
    cuts = np.flatnonzero(session[1:] != session[:-1]) + 1
    edges = [0, *cuts.tolist(), n]
    return [slice(a, b) for a, b in zip(edges[:-1], edges[1:], strict=True)]
