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
    """Exact solutions for N tubes: joints q (B, 2N), arc fractions sigma (P,), states (B, P, 2N + 9),
    tips (B, N, 3) mm, tube ends (B, N) mm."""

    q: np.ndarray
    sigma: np.ndarray
    states: np.ndarray
    tips: np.ndarray
    ends: np.ndarray

    def __len__(self) -> int:
        return self.q.shape[0]


def solve_dense(robot: Robot, q: np.ndarray, points: int) -> DenseStates:
    """Exact states at ``points`` uniform arc fractions for configurations q (B, 2N).

    Rows the solver could not converge on are dropped (and counted by the caller via ``len``).
    """
    bb = CosseratBackend(robot).forward(q, points=points)
    ok = bb.converged
    return DenseStates(q=q[ok], sigma=np.linspace(0.0, 1.0, points), states=bb.state[ok],
                       tips=bb.tips_mm[ok], ends=bb.tube_ends_mm[ok])


def collocation(robot: Robot, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``n`` collocation points: arc fractions sigma (n,) uniform in [0, 1] and joints q (n, 2N)."""
    return rng.uniform(0.0, 1.0, n), robot.sample_joints(n, rng)


def state_scales(dense: DenseStates, features: str) -> np.ndarray:
    """Typical size (2N + 9,) of each raw network output, from exact states.

    Positions are scaled as the PINN represents them, ``(p - s e3) * P_REF / s^2``; with
    ``equivariant`` features twist angles are learned as deviations from ``alpha_i - alpha1``.
    Floors keep every scale positive (m_b is identically zero in free space; a fixed joint or a
    straight tube leaves other states constant).
    """
    n = dense.q.shape[1] // 2
    ns, i_th, i_p = 2 * n + 9, 2 + n, 2 + 2 * n
    x = dense.states.reshape(-1, ns).copy()
    if features == "equivariant":
        dalpha = dense.q[:, n:] - dense.q[:, n:n + 1]
        x[:, i_th:i_p] -= np.repeat(dalpha, dense.sigma.size, axis=0)
    s = (dense.sigma[None, :] * dense.ends[:, :1]).reshape(-1)
    scales = x.std(axis=0)
    keep = s > min(10.0, 0.5 * s.max())  # away from s = 0, where (p - s e3) / s^2 is 0/0
    bent = x[keep, i_p:i_p + 3].copy()
    bent[:, 2] -= s[keep]
    scales[i_p:i_p + 3] = (bent * P_REF_MM / s[keep, None] ** 2).std(axis=0)
    scales[0:2] = np.maximum(scales[0:2], 1.0)        # N*mm
    scales[2:i_th] = np.maximum(scales[2:i_th], 1e-3)  # 1/mm
    scales[i_th:i_p] = np.maximum(scales[i_th:i_p], 0.1)  # rad
    scales[i_p:i_p + 3] = np.maximum(scales[i_p:i_p + 3], 1e-2)
    scales[i_p + 3:] = 1.0
    return scales
