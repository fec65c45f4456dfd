"""`Backbone`: what every kinematics backend returns -- the full shape, not just the tip."""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np


def state_names(n_tubes: int) -> tuple[str, ...]:
    """Names of the 2N + 9 state components (paper eq. 9), in storage order."""
    rng = range(1, n_tubes + 1)
    return (("m_bx", "m_by") + tuple(f"u{i}z" for i in rng) + tuple(f"theta{i}" for i in rng)
            + ("px", "py", "pz", "qw", "qx", "qy", "qz"))


def state_units(n_tubes: int) -> tuple[str, ...]:
    """Units of the state components of `state_names`."""
    return ("N*mm", "N*mm") + ("1/mm",) * n_tubes + ("rad",) * n_tubes + ("mm",) * 3 + ("-",) * 4


#: Names and units of the 15 states of a three-tube robot.
STATE_NAMES = state_names(3)
STATE_UNITS = state_units(3)


def quaternion_to_matrix(quat: np.ndarray) -> np.ndarray:
    """Scalar-first unit quaternions (..., 4) -> rotation matrices (..., 3, 3)."""
    w, x, y, z = np.moveaxis(np.asarray(quat, dtype=float), -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


@dataclass(frozen=True)
class Backbone:
    """Batched backbone of B configurations at P arc lengths each, for a robot of N tubes. Robot
    frame, mm and rad.

    Attributes:
        q: joints (B, 2N) [beta_1..N mm, alpha_1..N rad], as commanded.
        s_mm: arc lengths (B, P), from the front plate.
        state: the (2N + 9)-state (B, P, 2N + 9), see `state_names`/`state_units`.
        tube_ends_mm: distal ends l_i (B, N).
        tips_mm: tip positions of tubes 1..N (B, N, 3).
        radius_mm: outer radius of the outermost tube present at each point (B, P).
        converged: whether each configuration was solved (B,); unsolved rows hold NaN.
        initial_state: the state at s = 0 (B, 2N + 9) -- a warm start for the shooting solver.
        iterations: Newton iterations (B,) (0 for non-iterative backends).
        residual: distal boundary residual (B,), 1/m (moment over tube-1 stiffness).
        backend: name of the backend that produced it.
        stability: elastic-stability measure (B,): positive for a stable equilibrium, <= 0 for an
            unstable one (`ctrplan.kinematics._shooting.stability_det`); NaN where not computed.
    """

    q: np.ndarray
    s_mm: np.ndarray
    state: np.ndarray
    tube_ends_mm: np.ndarray
    tips_mm: np.ndarray
    radius_mm: np.ndarray
    converged: np.ndarray
    initial_state: np.ndarray
    iterations: np.ndarray
    residual: np.ndarray
    backend: str
    stability: np.ndarray | None = None

    def __len__(self) -> int:
        return self.q.shape[0]

    @property
    def n_tubes(self) -> int:
        return (self.state.shape[-1] - 9) // 2

    @property
    def state_names(self) -> tuple[str, ...]:
        """Names of the state components (`state_names`)."""
        return state_names(self.n_tubes)

    @property
    def positions_mm(self) -> np.ndarray:
        """Backbone points (B, P, 3), mm."""
        i = 2 * self.n_tubes + 2
        return self.state[..., i:i + 3]

    @property
    def quaternions(self) -> np.ndarray:
        """Orientation of tube 1 (B, P, 4), scalar-first."""
        return self.state[..., -4:]

    def with_radius(self, radius_mm: np.ndarray) -> Backbone:
        """The same backbones with another radius (B, P) mm, e.g. a planning margin added
        (a shallow copy: faster than `dataclasses.replace`, which re-runs the constructor)."""
        out = copy.copy(self)
        object.__setattr__(out, "radius_mm", radius_mm)
        return out

    @property
    def stable(self) -> np.ndarray:
        """Whether each equilibrium is elastically stable (B,): True where not computed and converged
        (see ``stability``), False where not converged."""
        if self.stability is None:
            return self.converged.copy()
        return self.converged & ~(self.stability <= 0.0)

    @property
    def rotations(self) -> np.ndarray:
        """Orientation of tube 1 (B, P, 3, 3)."""
        return quaternion_to_matrix(self.quaternions)

    @property
    def tip_mm(self) -> np.ndarray:
        """Tip of the robot (tube 1), (B, 3), mm."""
        return self.tips_mm[:, 0]
