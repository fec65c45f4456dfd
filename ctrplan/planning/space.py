"""The planning state space: box coordinates of the snap-free domain with a length metric.

OMPL states are the box coordinates of `JointDomain` (``beta3``, ``beta3 - beta2``, ``beta2 - beta1``
in mm, ``alpha1..3``) with the rotations multiplied by ``mm_per_rad``. The snap-free domain is then an
axis-aligned box, uniform sampling in it is uniform in the domain, and OMPL's Euclidean distance is a
length in mm in which turning a tube by 1 rad costs as much as translating it by ``mm_per_rad`` mm.
Everything stays in C++ (sampling, nearest neighbours, interpolation): no Python in the hot loops.

Use `BoxSpace` to go between joints ``q`` (mm, rad) and OMPL states.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ctrplan.robot import JointDomain, Robot

DIMENSION_NAMES = ("beta3", "beta3_minus_beta2", "beta2_minus_beta1", "alpha1_mm", "alpha2_mm",
                   "alpha3_mm")

#: d q / d x for x = box coordinates (unscaled): q = M @ x.
_M = np.array([
    [1.0, -1.0, -1.0, 0, 0, 0],
    [1.0, -1.0, 0, 0, 0, 0],
    [1.0, 0, 0, 0, 0, 0],
    [0, 0, 0, 1.0, 0, 0],
    [0, 0, 0, 0, 1.0, 0],
    [0, 0, 0, 0, 0, 1.0],
])


@dataclass(frozen=True)
class BoxSpace:
    """Scaled box coordinates ``y = scale * to_box(q)``; ``scale = (1, 1, 1, w, w, w)``, w = mm/rad.

    ``box_lower``/``box_upper`` (unscaled box coordinates, mm and rad) optionally narrow the domain's
    box (a scene's joint limits); they default to the snap-free domain.
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

    @property
    def scale(self) -> np.ndarray:
        w = self.mm_per_rad
        return np.array([1.0, 1.0, 1.0, w, w, w])

    @property
    def lower(self) -> np.ndarray:
        lo = self.domain.box_lower if self.box_lower is None else np.asarray(self.box_lower)
        return lo * self.scale

    @property
    def upper(self) -> np.ndarray:
        hi = self.domain.box_upper if self.box_upper is None else np.asarray(self.box_upper)
        return hi * self.scale

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` joint vectors uniform in the box (n, 6)."""
        return self.to_joints(rng.uniform(self.lower, self.upper, size=(n, 6)))

    @property
    def joint_from_coords(self) -> np.ndarray:
        """Linear map (6, 6) with ``q = J @ y`` (constant: dq/dy)."""
        return _M / self.scale[None, :]

    def to_coords(self, q: np.ndarray) -> np.ndarray:
        """Joints (..., 6) -> scaled box coordinates (..., 6)."""
        return JointDomain.to_box(q) * self.scale

    def to_joints(self, y: np.ndarray) -> np.ndarray:
        """Scaled box coordinates (..., 6) -> joints (..., 6)."""
        return JointDomain.from_box(np.asarray(y, dtype=float) / self.scale)

    def clip(self, y: np.ndarray) -> np.ndarray:
        return np.clip(y, self.lower, self.upper)

    def contains(self, q: np.ndarray, tol: float = 1e-9) -> np.ndarray:
        y = self.to_coords(q)
        return np.all((y >= self.lower - tol) & (y <= self.upper + tol), axis=-1)

    def distance(self, q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
        """The planning metric between joint vectors (mm)."""
        return np.linalg.norm(self.to_coords(q1) - self.to_coords(q2), axis=-1)

    def interpolate(self, q1: np.ndarray, q2: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Joints at fractions t (K,) of the straight coordinate line from q1 to q2: (K, 6)."""
        y1, y2 = self.to_coords(q1), self.to_coords(q2)
        t = np.asarray(t, dtype=float)[:, None]
        return self.to_joints(y1 + t * (y2 - y1))

    def densify(self, path_q: np.ndarray, resolution: float) -> np.ndarray:
        """Path (K, 6) with extra states so consecutive states are <= ``resolution`` apart."""
        path_q = np.atleast_2d(np.asarray(path_q, dtype=float))
        out = [path_q[:1]]
        for a, b in zip(path_q[:-1], path_q[1:], strict=True):
            n = max(1, int(np.ceil(float(self.distance(a, b)) / resolution)))
            out.append(self.interpolate(a, b, np.arange(1, n + 1) / n))
        return np.concatenate(out)

    # ---- OMPL ----------------------------------------------------------------------------------
    def make_ompl_space(self):
        """A fresh ``ob.RealVectorStateSpace(6)`` with these bounds (keep it function-scoped)."""
        from ompl import base as ob

        space = ob.RealVectorStateSpace(6)
        bounds = ob.RealVectorBounds(6)
        for i in range(6):
            bounds.setLow(i, float(self.lower[i]))
            bounds.setHigh(i, float(self.upper[i]))
            space.setDimensionName(i, DIMENSION_NAMES[i])
        space.setBounds(bounds)
        return space

    @staticmethod
    def state_coords(state) -> np.ndarray:
        """OMPL state -> coordinates (6,)."""
        return np.array([state[0], state[1], state[2], state[3], state[4], state[5]])

    def state_to_q(self, state) -> np.ndarray:
        return self.to_joints(self.state_coords(state))

    def set_state(self, state, q: np.ndarray) -> None:
        """Write joints q (6,) into an allocated OMPL state."""
        y = self.clip(self.to_coords(q))
        for i in range(6):
            state[i] = float(y[i])
