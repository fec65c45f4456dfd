"""Training samples over the robot's joint domain (paper Table II): collocation points, boundary
configurations, tip observations and dense exact Cosserat states. Arrays are float64 numpy; q in
mm/rad.

Exact states are nearly free (the shooting solver gives thousands of full solutions a second), so a
pool of them is the backbone of every learned recipe. A configuration the solver cannot solve is
never a training target: it is left out, counted and kept (`DenseStates.unsolved`) so the model card
can say how many there were and where.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ctrplan.kinematics.cosserat import CosseratBackend
from ctrplan.kinematics.pinn_net import P_REF_MM
from ctrplan.model.robot import Robot
from ctrplan.training.budget import now

#: Configurations solved per call while a pool is built (progress is reported between chunks).
SOLVE_CHUNK = 4096
#: The same under a deadline (a finer check of the time).
DEADLINE_CHUNK = 512


@dataclass(frozen=True)
class DenseStates:
    """Exact solutions for N tubes: joints q (B, 2N), arc fractions sigma (P,), states (B, P, 2N + 9),
    tips (B, N, 3) mm, tube ends (B, N) mm; ``unsolved`` (U, 2N) the configurations the solver could
    not solve (left out of the rest), ``seconds`` the time it took."""

    q: np.ndarray
    sigma: np.ndarray
    states: np.ndarray
    tips: np.ndarray
    ends: np.ndarray
    unsolved: np.ndarray = field(default_factory=lambda: np.empty((0, 0)))
    seconds: float = 0.0

    def __len__(self) -> int:
        return self.q.shape[0]

    @property
    def solved_per_s(self) -> float:
        """Configurations the exact solver went through per second while it built this pool."""
        return (len(self) + len(self.unsolved)) / max(self.seconds, 1e-9)

    def unsolved_report(self, limit: int = 10) -> dict:
        """How many configurations were left out, and the first ``limit`` of them (mm, rad)."""
        return {"count": int(len(self.unsolved)), "of": int(len(self) + len(self.unsolved)),
                "joints": [[round(float(v), 4) for v in row] for row in self.unsolved[:limit]]}


def solve_dense(robot: Robot, q: np.ndarray, points: int,
                progress: Callable[[int, int], None] | None = None,
                deadline: float | None = None) -> DenseStates:
    """Exact states at ``points`` uniform arc fractions for configurations q (B, 2N), solved in
    chunks (``progress(done, total)`` after each). Rows the solver could not converge on are left out
    and listed in ``unsolved``. With a ``deadline`` (`budget.now` time) solving stops after the
    first chunk that ends past it: the pool then covers the first rows of q only."""
    t0 = time.perf_counter()
    backend = CosseratBackend(robot)
    chunk = SOLVE_CHUNK if deadline is None else DEADLINE_CHUNK
    parts = []
    for a in range(0, len(q), chunk):
        parts.append(backend.forward(q[a:a + chunk], points=points, check=False))
        if progress is not None:
            progress(min(a + chunk, len(q)), len(q))
        if deadline is not None and now() >= deadline:
            q = q[:a + chunk]
            break
    ok = np.concatenate([bb.converged for bb in parts]) if parts else np.zeros(0, dtype=bool)

    def joined(name: str) -> np.ndarray:
        return np.concatenate([getattr(bb, name) for bb in parts])[ok]

    sigma = np.linspace(0.0, 1.0, points)
    if not parts:
        n = robot.n_tubes
        return DenseStates(q=q, sigma=sigma, states=np.empty((0, points, robot.n_states)),
                           tips=np.empty((0, n, 3)), ends=np.empty((0, n)), unsolved=q)
    return DenseStates(q=q[ok], sigma=sigma, states=joined("state"), tips=joined("tips_mm"),
                       ends=joined("tube_ends_mm"), unsolved=q[~ok], seconds=time.perf_counter() - t0)


def pool_joints(robot: Robot, n: int, rng: np.random.Generator, edge_share: float = 0.0) -> np.ndarray:
    """``n`` configurations (n, 2N) for the exact pool: uniform in the domain box, except that in a
    share ``edge_share`` of them, spread over the pool (a pool cut short keeps the share), each
    translation box coordinate follows the arcsine law on its interval (density
    ``1 / sqrt(x (1 - x))``: more near both limits, where the tubes are fully extended or retracted
    and the tail of a network's error lives)."""
    q = robot.sample_joints(n, rng)
    k = int(round(edge_share * n))
    if k:
        nt, dom = robot.n_tubes, robot.domain
        box = dom.to_box(q[n - k:])
        u = 0.5 * (1.0 - np.cos(np.pi * rng.uniform(size=(k, nt))))
        box[:, :nt] = dom.box_lower[:nt] + (dom.box_upper[:nt] - dom.box_lower[:nt]) * u
        q[n - k:] = dom.from_box(box)
        q = q[rng.permutation(n)]
    return q


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


#: Configurations and rotation step (rad) of `frame_tube`'s finite differences.
FRAME_SAMPLES = 400
FRAME_STEP_RAD = 1e-3


def frame_tube(robot: Robot, n: int = FRAME_SAMPLES, seed: int = 0) -> int:
    """The equivariant network's frame tube (0-based; `PinnNet`): the rotatable tube whose own
    rotation moves the tube-1 tip most (median over ``n`` configurations of the domain, exact model,
    finite differences). Turning all tubes together turns the tip rigidly, so with this tube as the
    frame the network learns the smallest motion left: the others' rotations relative to it."""
    nt = robot.n_tubes
    rotatable = [i for i in range(nt) if not robot.domain.fixed[nt + i]]
    if len(rotatable) < 2:
        return rotatable[0] if rotatable else 0
    backend = CosseratBackend(robot)
    q = robot.sample_joints(n, np.random.default_rng([seed, 7]))
    turned = [q.copy() for _ in rotatable]
    for qi, i in zip(turned, rotatable, strict=True):
        qi[:, nt + i] += FRAME_STEP_RAD
    bb = backend.forward(np.concatenate([q, *turned]), points=2, check=False)
    tips = bb.tips_mm[:, 0].reshape(len(rotatable) + 1, n, 3)
    ok = bb.converged.reshape(len(rotatable) + 1, n).all(axis=0)
    moved = np.linalg.norm(tips[1:, ok] - tips[:1, ok], axis=-1)
    return rotatable[int(np.argmax(np.median(moved, axis=1)))] if ok.any() else 0
