"""`Backbone`: what every kinematics backend returns -- the full shape, not just the tip."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Names of the 15 state components (paper eq. 9), in storage order.
STATE_NAMES = ("m_bx", "m_by", "u1z", "u2z", "u3z", "theta1", "theta2", "theta3",
               "px", "py", "pz", "qw", "qx", "qy", "qz")
STATE_UNITS = ("N*mm", "N*mm", "1/mm", "1/mm", "1/mm", "rad", "rad", "rad",
               "mm", "mm", "mm", "-", "-", "-", "-")


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
    """Batched backbone of B configurations at N arc lengths each. Robot frame, mm and rad.

    Attributes:
        q: joints (B, 6) [beta1..3 mm, alpha1..3 rad], as commanded.
        s_mm: arc lengths (B, N), from the front plate.
        state: the 15-state (B, N, 15), see `STATE_NAMES`/`STATE_UNITS`.
        tube_ends_mm: distal ends l_i (B, 3).
        tips_mm: tip positions of tubes 1..3 (B, 3, 3).
        radius_mm: outer radius of the outermost tube present at each point (B, N).
        converged: whether each configuration was solved (B,); unsolved rows hold NaN.
        initial_state: the 15-state at s = 0 (B, 15) -- a warm start for the shooting solver.
        iterations: Newton iterations (B,) (0 for non-iterative backends).
        residual: distal boundary residual (B,), 1/m (moment over tube-1 stiffness).
        backend: name of the backend that produced it.
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

    def __len__(self) -> int:
        return self.q.shape[0]

    @property
    def positions_mm(self) -> np.ndarray:
        """Backbone points (B, N, 3), mm."""
        return self.state[..., 8:11]

    @property
    def quaternions(self) -> np.ndarray:
        """Orientation of tube 1 (B, N, 4), scalar-first."""
        return self.state[..., 11:15]

    @property
    def rotations(self) -> np.ndarray:
        """Orientation of tube 1 (B, N, 3, 3)."""
        return quaternion_to_matrix(self.quaternions)

    @property
    def tip_mm(self) -> np.ndarray:
        """Tip of the robot (tube 1), (B, 3), mm."""
        return self.tips_mm[:, 0]
