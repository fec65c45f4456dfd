"""An independent free-space Cosserat-rod model of an N-tube concentric-tube robot.

Written from docs/design.md §1 and the paper's equations only (no ctrplan import): fixed-step RK4 on every
piece between the points where a tube starts, starts curving or ends (so the piecewise-constant
coefficients never change inside a step), vectorised over configurations, and Newton shooting on
u_iz(0) with a finite-difference Jacobian. Free space: the bending moment m_b,xy is zero everywhere,

    u_xy = (sum_i EI_i Rz(theta_i) [kappa_i, 0]) / sum_i EI_i          (present tubes)
    u_iz' = -(EI_i / GJ_i) kappa_i u_iy,   u_iy = -sin(theta_i) u_x + cos(theta_i) u_y
    theta_i' = u_iz - u_1z,   p' = R e3,   R' = R [u_x, u_y, u_1z]^

with R(0) = Rz(psi_1), theta_i(0) = psi_i - psi_1, psi_i = alpha_i - (beta_i - d_i) u_iz(0) -- the tube
twists over the length -beta_i behind the plate plus an extra transmission length d_i (0 in docs/design.md §1:
a compliant drive, or a longer clamp-to-plate length than the model's) -- and u_iz(l_i) = 0 (u_iz
stays constant past l_i, so u_iz(l_1) = 0 for all i). Units: mm, rad.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Tubes:
    """Tube parameters, index 0 = innermost. Lengths mm, curvature 1/mm, moduli N/mm^2."""

    inner_mm: np.ndarray
    outer_mm: np.ndarray
    straight_mm: np.ndarray
    curved_mm: np.ndarray
    kappa_per_mm: np.ndarray
    E: np.ndarray
    G: np.ndarray
    transmission_mm: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @classmethod
    def paper(cls) -> Tubes:
        """Paper Table I."""
        return cls(inner_mm=np.array([0.40, 0.70, 1.20]), outer_mm=np.array([0.50, 0.90, 1.50]),
                   straight_mm=np.array([169.0, 65.0, 10.0]), curved_mm=np.array([41.0, 100.0, 100.0]),
                   kappa_per_mm=np.array([28.0, 12.4, 4.37]) * 1e-3, E=np.full(3, 50e3),
                   G=np.full(3, 19.23e3))

    def scaled(self, **factors: np.ndarray) -> Tubes:
        """A copy with some fields multiplied elementwise."""
        d = {k: getattr(self, k) for k in self.__dataclass_fields__}
        for k, f in factors.items():
            d[k] = d[k] * np.asarray(f, dtype=float)
        return Tubes(**d)

    @property
    def ei(self) -> np.ndarray:
        return self.E * np.pi / 64 * (self.outer_mm ** 4 - self.inner_mm ** 4)

    @property
    def gj(self) -> np.ndarray:
        return self.G * np.pi / 32 * (self.outer_mm ** 4 - self.inner_mm ** 4)

    @property
    def length_mm(self) -> np.ndarray:
        return self.straight_mm + self.curved_mm


def _rz(a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def _hat(u: np.ndarray) -> np.ndarray:
    x, y, z = u[..., 0], u[..., 1], u[..., 2]
    o = np.zeros_like(x)
    return np.stack([np.stack([o, -z, y], -1), np.stack([z, o, -x], -1), np.stack([-y, x, o], -1)], -2)


def _rhs(y, present, curved, t: Tubes):
    """Derivatives of (uz (B,N), theta (B,N), p (B,3), R (B,3,3)); masks (B,N) for this piece."""
    uz, th, p, R = y
    K = t.ei * present
    kap = t.kappa_per_mm * curved
    ux = (K * np.cos(th) * kap).sum(1) / K.sum(1)
    uy = (K * np.sin(th) * kap).sum(1) / K.sum(1)
    uiy = -np.sin(th) * ux[:, None] + np.cos(th) * uy[:, None]
    duz = np.where(present, -(t.ei / t.gj) * kap * uiy, 0.0)
    dth = uz - uz[:, :1]
    dp = R[:, :, 2]
    dR = R @ _hat(np.stack([ux, uy, uz[:, 0]], -1))
    return duz, dth, dp, dR


def integrate(q: np.ndarray, uz0: np.ndarray, t: Tubes, steps: int = 24) -> tuple:
    """Integrate from s = 0 to l_1 for joints q (B, 2N) and u_iz(0) (B, N). Returns the final state
    (uz, theta, p, R) and the tips p(l_i) (B, N, 3)."""
    q = np.atleast_2d(q)
    B, N = q.shape[0], q.shape[1] // 2
    beta, alpha = q[:, :N], q[:, N:]
    ends = beta + t.length_mm
    l1 = ends[:, 0]
    psi = alpha - (beta - t.transmission_mm) * uz0
    th = psi - psi[:, :1]
    R = _rz(psi[:, 0])
    p = np.zeros((B, 3))
    uz = uz0.copy()
    cuts = np.concatenate([np.zeros((B, 1)), beta + t.straight_mm, ends], axis=1)
    cuts = np.sort(np.clip(cuts, 0.0, l1[:, None]), axis=1)
    tips = np.full((B, N, 3), np.nan)
    y = (uz, th, p, R)
    for k in range(cuts.shape[1] - 1):
        a, b = cuts[:, k], cuts[:, k + 1]
        mid = 0.5 * (a + b)[:, None]
        present = (mid >= beta) & (mid <= ends)
        curved = present & (mid >= beta + t.straight_mm)
        h = ((b - a) / steps)
        for _ in range(steps):
            k1 = _rhs(y, present, curved, t)
            k2 = _rhs(_axpy(y, k1, h / 2), present, curved, t)
            k3 = _rhs(_axpy(y, k2, h / 2), present, curved, t)
            k4 = _rhs(_axpy(y, k3, h), present, curved, t)
            y = tuple(yi + _bc(h, yi) / 6 * (a1 + 2 * a2 + 2 * a3 + a4)
                      for yi, a1, a2, a3, a4 in zip(y, k1, k2, k3, k4, strict=True))
        hit = np.isclose(b[:, None], ends)            # a tube ends here: record its tip
        tips[hit] = np.repeat(y[2][:, None, :], N, axis=1)[hit]
    return y, tips


def _bc(h: np.ndarray, like: np.ndarray) -> np.ndarray:
    return h.reshape((-1,) + (1,) * (like.ndim - 1))


def _axpy(y, k, h):
    return tuple(yi + _bc(h, yi) * ki for yi, ki in zip(y, k, strict=True))


def solve(q: np.ndarray, t: Tubes, tol: float = 1e-11, iters: int = 30) -> dict:
    """Shoot every configuration of q (B, 2N): tips (B, N, 3) mm, tip frame R(l_1) (B, 3, 3),
    u_z(0) (B, N) 1/mm, converged (B,)."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    B, N = q.shape[0], q.shape[1] // 2
    x = np.zeros((B, N))
    eps = 1e-7
    done = np.zeros(B, dtype=bool)
    for _ in range(iters):
        stack = np.concatenate([x] + [x + eps * np.eye(N)[j] for j in range(N)], axis=0)
        (uz, *_), _tips = integrate(np.tile(q, (N + 1, 1)), stack, t)
        r = uz[:B]
        J = np.stack([(uz[B * (j + 1):B * (j + 2)] - r) / eps for j in range(N)], axis=-1)
        done = np.abs(r).max(1) < tol
        if done.all():
            break
        x = x - np.linalg.solve(J, r[..., None])[..., 0]
    (uz, th, p, R), tips = integrate(q, x, t)
    return {"tips_mm": tips, "tip_rotation": R, "uz0_per_mm": x, "converged": np.abs(uz).max(1) < 1e-8}
