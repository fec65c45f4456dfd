"""Training samples over the snap-free domain (paper Table II): collocation points, boundary
configurations, tip observations and dense Cosserat states. Arrays are float64 numpy; q in mm/rad."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ctrplan.kinematics.cosserat import CosseratBackend
from ctrplan.kinematics.pinn import P_REF_MM
from ctrplan.robot import Robot


@dataclass(frozen=True)
class DenseStates:
    """Exact solutions: joints q (B, 6), arc fractions sigma (P,), states (B, P, 15), tips (B, 3, 3),
    tube ends (B, 3) mm."""

    q: np.ndarray
    sigma: np.ndarray
    states: np.ndarray
    tips: np.ndarray
    ends: np.ndarray

    def __len__(self) -> int:
        return self.q.shape[0]


def solve_dense(robot: Robot, q: np.ndarray, points: int) -> DenseStates:
    """Exact states at ``points`` uniform arc fractions for configurations q (B, 6).

    Rows the solver could not converge on are dropped (and counted by the caller via ``len``).
    """
    bb = CosseratBackend(robot).forward(q, points=points)
    ok = bb.converged
    return DenseStates(q=q[ok], sigma=np.linspace(0.0, 1.0, points), states=bb.state[ok],
                       tips=bb.tips_mm[ok], ends=bb.tube_ends_mm[ok])


def collocation(robot: Robot, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``n`` collocation points: arc fractions sigma (n,) uniform in [0, 1] and joints q (n, 6)."""
    return rng.uniform(0.0, 1.0, n), robot.sample_joints(n, rng)


def state_scales(dense: DenseStates, features: str) -> np.ndarray:
    """Typical size (15,) of each raw network output, from exact states.

    Positions are scaled as the PINN represents them, ``(p - s e3) * P_REF / s^2``; with
    ``equivariant`` features twist angles are learned as deviations from ``alpha_i - alpha1``.
    Floors keep every scale positive (m_b is identically zero in free space).
    """
    x = dense.states.reshape(-1, 15).copy()
    if features == "equivariant":
        dalpha = dense.q[:, 3:6] - dense.q[:, 3:4]
        x[:, 5:8] -= np.repeat(dalpha, dense.sigma.size, axis=0)
    s = (dense.sigma[None, :] * dense.ends[:, :1]).reshape(-1)
    scales = x.std(axis=0)
    keep = s > 10.0
    bent = x[keep, 8:11].copy()
    bent[:, 2] -= s[keep]
    scales[8:11] = (bent * P_REF_MM / s[keep, None] ** 2).std(axis=0)
    scales[0:2] = np.maximum(scales[0:2], 1.0)    # N*mm
    scales[2:5] = np.maximum(scales[2:5], 1e-3)   # 1/mm
    scales[5:8] = np.maximum(scales[5:8], 0.1)    # rad
    scales[8:11] = np.maximum(scales[8:11], 1e-2)
    scales[11:15] = 1.0
    return scales
