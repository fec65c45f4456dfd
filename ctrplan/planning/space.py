"""The planning state space: box coordinates of the snap-free domain with a length metric.

OMPL states are the box coordinates of `JointDomain` (``betaN``, ``betaN - betaN-1``, …, ``beta2 -
beta1`` in mm, ``alpha1..N``) with the rotations multiplied by ``mm_per_rad``, fixed joints left out.
The domain is then an axis-aligned box, uniform sampling in it is uniform in the domain, and OMPL's
Euclidean distance is a
length in mm in which turning a tube by 1 rad costs as much as translating it by ``mm_per_rad`` mm.
Everything stays in C++ (sampling, nearest neighbours, interpolation): no Python in the hot loops.

Use `BoxSpace` to go between joints ``q`` (mm, rad) and OMPL states.

**Rotations wrap where the interval is a full turn.** A tube rotation whose interval spans a full
turn (the paper's [-pi, pi]) is an angle: configurations one turn apart are the same robot. Between
two configurations such a coordinate turns the short way (less than half a turn: `difference`); the
planning metric (`distance`), interpolation (`interpolate`, `along`, `densify`), the path shortcut
and ctrplan's own planner (`ctrplan.planning.corridor`) measure and move that way, and a path is
continuous (`unwrap`: each state within half a turn of the one before, so trajectories never jump by
a turn). OMPL's own planners keep the flat box (their edges are shorter than half a turn, where both
agree); OMPL states hold the representative in the box (`clip` wraps). A narrower interval is an
actuator's limit and stays flat.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ctrplan.model.robot import TURN, JointDomain, Robot


@dataclass(frozen=True)
class BoxSpace:
    """Scaled box coordinates of the free joints: ``y = (scale * to_box(q))[free]``; ``scale`` is 1 for
    the translations (mm) and ``mm_per_rad`` for the rotations. Fixed box coordinates (zero-width
    intervals: joints the hardware keeps fixed) are not searched; they keep their value.

    ``box_lower``/``box_upper`` (unscaled box coordinates, mm and rad) optionally narrow the domain's
    box (a scene's joint limits); they default to the domain.
    """

    domain: JointDomain
    mm_per_rad: float = 40.0
    box_lower: tuple[float, ...] | None = None
    box_upper: tuple[float, ...] | None = None

    @classmethod
    def for_robot(cls, robot: Robot, mm_per_rad: float = 40.0) -> BoxSpace:
        return cls(robot.domain, float(mm_per_rad))

    @classmethod
    def for_scene(cls, scene) -> BoxSpace:
        lo, hi = scene.joint_box
        return cls(scene.robot.domain, float(scene.settings.mm_per_rad), tuple(lo), tuple(hi))

    @cached_property
    def full_scale(self) -> np.ndarray:
        """Scale of every box coordinate (2N,): 1 for translations, mm/rad for rotations."""
        n = self.domain.n_tubes
        return np.array([1.0] * n + [self.mm_per_rad] * n)

    @cached_property
    def _full_lower(self) -> np.ndarray:
        lo = self.domain.box_lower if self.box_lower is None else np.asarray(self.box_lower, dtype=float)
        return lo * self.full_scale

    @cached_property
    def _full_upper(self) -> np.ndarray:
        hi = self.domain.box_upper if self.box_upper is None else np.asarray(self.box_upper, dtype=float)
        return hi * self.full_scale

    @cached_property
    def free(self) -> np.ndarray:
        """Which box coordinates are searched (2N,) bool: those of non-zero width."""
        return self._full_upper > self._full_lower

    @cached_property
    def dimension(self) -> int:
        return int(self.free.sum())

    @cached_property
    def names(self) -> tuple[str, ...]:
        """Names of the searched coordinates (OMPL dimension names)."""
        n = self.domain.n_tubes
        full = [name.replace(" - ", "_minus_") for name in self.domain.names]
        full = full[:n] + [f"{name}_mm" for name in full[n:]]
        return tuple(name for name, f in zip(full, self.free, strict=True) if f)

    @property
    def scale(self) -> np.ndarray:
        return self.full_scale[self.free]

    @cached_property
    def is_rotation(self) -> np.ndarray:
        """Which searched coordinates are tube rotations (D,) bool."""
        n = self.domain.n_tubes
        return (np.arange(2 * n) >= n)[self.free]

    @property
    def lower(self) -> np.ndarray:
        return self._full_lower[self.free]

    @property
    def upper(self) -> np.ndarray:
        return self._full_upper[self.free]

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` joint vectors uniform in the box (n, 2N)."""
        return self.to_joints(rng.uniform(self.lower, self.upper, size=(n, self.dimension)))

    @cached_property
    def joint_from_coords(self) -> np.ndarray:
        """Linear part (2N, D) of ``q = J @ y + q_fixed`` (constant: dq/dy)."""
        return self.domain.joints_from_box[:, self.free] / self.scale[None, :]

    def to_coords(self, q: np.ndarray) -> np.ndarray:
        """Joints (..., 2N) -> scaled box coordinates of the free joints (..., D)."""
        return (self.domain.to_box(q) * self.full_scale)[..., self.free]

    def to_joints(self, y: np.ndarray) -> np.ndarray:
        """Scaled box coordinates of the free joints (..., D) -> joints (..., 2N)."""
        y = np.asarray(y, dtype=float)
        full = np.broadcast_to(self._full_lower, y.shape[:-1] + self._full_lower.shape).copy()
        full[..., self.free] = y
        return self.domain.from_box(full / self.full_scale)

    @cached_property
    def _full_period(self) -> np.ndarray:
        """One turn (2 pi mm_per_rad) for box coordinates that wrap (rotations whose interval spans
        a full turn), inf for the others (2N,)."""
        full = (np.arange(2 * self.domain.n_tubes) >= self.domain.n_tubes) & \
            (self._full_upper - self._full_lower >= TURN * self.mm_per_rad * (1.0 - 1e-12))
        return np.where(full, TURN * self.mm_per_rad, np.inf)

    @property
    def period(self) -> np.ndarray:
        """Period (D,) of each searched coordinate (mm of the metric): one turn, or inf."""
        return self._full_period[self.free]

    @cached_property
    def wraps(self) -> np.ndarray:
        """Which searched coordinates wrap (D,) bool."""
        return np.isfinite(self.period)

    def difference(self, y1: np.ndarray, y2: np.ndarray) -> np.ndarray:
        """The coordinate step (..., D) from y1 to y2, wrapping coordinates the short way."""
        d = np.asarray(y2, dtype=float) - np.asarray(y1, dtype=float)
        if self.wraps.any():
            p = self.period[self.wraps]
            d[..., self.wraps] -= p * np.round(d[..., self.wraps] / p)
        return d

    def clip(self, y: np.ndarray) -> np.ndarray:
        """Coordinates (..., D) into the box: clipped, wrapping ones taken to their representative
        in [lower, lower + one turn)."""
        y = np.clip(y, np.where(self.wraps, -np.inf, self.lower), np.where(self.wraps, np.inf, self.upper))
        if self.wraps.any():
            lo = self.lower[self.wraps]
            y[..., self.wraps] = lo + np.mod(y[..., self.wraps] - lo, self.period[self.wraps])
        return y

    def contains(self, q: np.ndarray, tol: float = 1e-9) -> np.ndarray:
        y = (self.domain.to_box(q) * self.full_scale)
        wrap = np.isfinite(self._full_period)
        y[..., wrap] = self._full_lower[wrap] + np.mod(y[..., wrap] - self._full_lower[wrap],
                                                        self._full_period[wrap])
        return np.all((y >= self._full_lower - tol) & (y <= self._full_upper + tol), axis=-1)

    def distance(self, q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
        """The planning metric between joint vectors (mm), wrapping rotations the short way."""
        return np.linalg.norm(self.difference(self.to_coords(q1), self.to_coords(q2)), axis=-1)

    def unwrap(self, path_q: np.ndarray) -> np.ndarray:
        """The path (K, 2N) continuous: each state's wrapping coordinates within half a turn of the
        previous state's (the same configurations, and the same moves)."""
        path_q = np.atleast_2d(np.asarray(path_q, dtype=float))
        if not self.wraps.any() or len(path_q) < 2:
            return path_q
        return self.to_joints(self._unwrapped(self.to_coords(path_q)))

    def _unwrapped(self, y: np.ndarray) -> np.ndarray:
        if not self.wraps.any():
            return y
        return np.concatenate([y[:1], y[:1] + np.cumsum(self.difference(y[:-1], y[1:]), axis=0)])

    def interpolate(self, q1: np.ndarray, q2: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Joints at fractions t (K,) of the coordinate line from q1 to q2 (the short way): (K, 2N)."""
        t = np.asarray(t, dtype=float)
        return self.along(np.stack([q1, q2]), np.zeros(len(t), dtype=int), t)

    def densify(self, path_q: np.ndarray, resolution: float) -> np.ndarray:
        """Path (K, 2N) with extra states so consecutive states are <= ``resolution`` apart; the
        result is continuous (`unwrap`)."""
        path_q = self.unwrap(path_q)
        y = self.to_coords(path_q)
        n = np.maximum(1, np.ceil(np.linalg.norm(np.diff(y, axis=0), axis=1) / resolution)).astype(int)
        return np.concatenate([path_q[:1], self.along(path_q, *split_segments(n, ends=True))])

    def along(self, path_q: np.ndarray, segment: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Joints (M, 2N) at fractions ``t`` (M,) of the coordinate lines (the short way) of the
        segments ``segment`` (M,) (index k: from row k to row k + 1) of a path (K, 2N), continuous
        from its first state."""
        y = self._unwrapped(self.to_coords(np.atleast_2d(path_q)))
        return self.to_joints(y[segment] + t[:, None] * (y[segment + 1] - y[segment]))

    # ---- OMPL ----------------------------------------------------------------------------------
    def make_ompl_space(self):
        """A fresh ``ob.RealVectorStateSpace(D)`` with these bounds (keep it function-scoped)."""
        from ompl import base as ob

        d = self.dimension
        space = ob.RealVectorStateSpace(d)
        bounds = ob.RealVectorBounds(d)
        for i in range(d):
            bounds.setLow(i, float(self.lower[i]))
            bounds.setHigh(i, float(self.upper[i]))
            space.setDimensionName(i, self.names[i])
        space.setBounds(bounds)
        return space

    def state_coords(self, state) -> np.ndarray:
        """OMPL state -> coordinates (D,)."""
        return np.array([state[i] for i in range(self.dimension)])

    @cached_property
    def _affine(self) -> tuple[np.ndarray, np.ndarray]:
        """``to_joints`` as ``q = A @ y + c``: A (2N, D), c (2N,) (the planner's hot path)."""
        c = self.to_joints(np.zeros(self.dimension))
        return self.to_joints(np.eye(self.dimension)).T - c[:, None], c

    def state_to_q(self, state) -> np.ndarray:
        """OMPL state -> joints (2N,) (mm, rad)."""
        A, c = self._affine
        return A @ self.state_coords(state) + c

    def set_state(self, state, q: np.ndarray) -> None:
        """Write joints q (2N,) into an allocated OMPL state."""
        y = self.clip(self.to_coords(q))
        for i in range(self.dimension):
            state[i] = float(y[i])


def split_segments(pieces: np.ndarray, ends: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The states that cut each segment k of a path into ``pieces[k]`` equal parts: their segment
    indices and fractions j / pieces[k], j = 1 .. pieces[k] - 1 (with ``ends``, up to pieces[k]: the
    segment's end too), in path order."""
    pieces = np.asarray(pieces, dtype=int)
    count = pieces if ends else pieces - 1
    segment = np.repeat(np.arange(len(pieces)), count)
    j = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count) + 1
    return segment, j / pieces[segment]
