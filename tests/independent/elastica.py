"""An independent planar elastica of ONE pre-curved tube under a follower force at its tip -- written
apart from ctrplan's shooting kernels (scipy's adaptive RK45 and a root finder instead of fixed-step RK4 and
Newton), for tests of the loads.

The tube starts at the plate along z; its curved part (the distal ``curved_mm``) bends it about its x
axis, so that with alpha = 0 it stays in the y-z plane: tangent (0, -sin psi, cos psi), psi' =
kappa(s) + m / EI, and the bending moment about x obeys m' = cos(psi) n_y + sin(psi) n_z for a
constant internal force n (the tip force), here a force fixed in the tip frame (a follower force)
that turns with psi(l1). A rotation alpha of the tube turns the whole solution about z (no torsion: the load
lies in the bending plane).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import fsolve


def _rot_x(psi: float) -> np.ndarray:
    c, s = math.cos(psi), math.sin(psi)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _integrate(m0: float, n: np.ndarray, l1: float, start_curve: float, kappa: float, ei: float):
    """(psi, y, z, m) at s = l1 from psi = y = z = 0, m = m0 at s = 0, piecewise in kappa."""
    def f(k):
        def rhs(_s, x):
            psi, _y, _z, m = x
            return [k + m / ei, -math.sin(psi), math.cos(psi), math.cos(psi) * n[1] + math.sin(psi) * n[2]]
        return rhs

    x = np.array([0.0, 0.0, 0.0, m0])
    for a, b, k in ((0.0, max(start_curve, 0.0), 0.0), (max(start_curve, 0.0), l1, kappa)):
        if b > a:
            x = solve_ivp(f(k), (a, b), x, rtol=1e-12, atol=1e-13, method="RK45").y[:, -1]
    return x


def tip(beta_mm: float, alpha_rad: float, *, length_mm: float, curved_mm: float, kappa_per_mm: float,
        ei_nmm2: float, follower_n=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Tip (3,) mm of the tube at joints (beta, alpha) under a follower force (tip frame, N; no x
    component: the problem stays planar)."""
    follower = np.asarray(follower_n, dtype=float)
    if follower[0]:
        raise ValueError("planar only: no x component")
    l1 = beta_mm + length_mm
    start_curve = l1 - curved_mm

    def residual(z):
        m0, psi_l = z
        n = _rot_x(psi_l) @ follower
        psi, _y, _z, m = _integrate(m0, n, l1, start_curve, kappa_per_mm, ei_nmm2)
        return [m, psi - psi_l]

    guess_psi = kappa_per_mm * min(curved_mm, l1)
    m0, psi_l = fsolve(residual, [0.0, guess_psi], xtol=1e-13)
    if max(abs(v) for v in residual([m0, psi_l])) > 1e-8:
        raise RuntimeError("the planar elastica did not converge")
    n = _rot_x(psi_l) @ follower
    _psi, y, z, _m = _integrate(m0, n, l1, start_curve, kappa_per_mm, ei_nmm2)
    return _rot_z(alpha_rad) @ np.array([0.0, y, z])
