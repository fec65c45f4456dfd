"""Measurement noise, estimated from the data alone -- independently of any fitted model extension.

Whatever the model gets wrong is a smooth function of the joints (and, for lag effects, of the
direction of motion); tracker noise is not. So the nominal residual of each row is predicted from the
rows with the nearest configurations by a local linear model in the moving joints plus the direction
of motion of the moving rotations (a near-repeated configuration is the best neighbour of all). For
pure noise the leave-one-out error of such a linear smoother is ``e_i = n_i - w_i . n_neighbours``
with variance ``sigma^2 (1 + |w_i|^2)`` exactly, so ``e_i / sqrt(1 + |w_i|^2)`` is a noise sample;
a robust (median) scale over all rows, coordinates and measured tubes estimates sigma. Model error the
local linear model does not capture can only inflate it; of two neighbourhood sizes the smaller
estimate is kept.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

#: Tip motion per radian of a rotation joint used to put alpha on the scale of beta (mm/rad).
ALPHA_MM_PER_RAD = 30.0
#: Mean norm of a 3-D isotropic Gaussian with unit per-coordinate sigma: sqrt(8 / pi).
MEAN_NORM_PER_SIGMA = math.sqrt(8.0 / math.pi)


def estimate_noise(q: np.ndarray, direction: np.ndarray, residual_mm: np.ndarray,
                   tubes: tuple[int, ...]) -> dict:
    """Tracker noise from the nominal residuals ``residual_mm`` (R, T, 3) of rows with joints ``q``
    (R, 2N) and directions of motion ``direction`` (R, 2N).

    Returns ``noise_mm`` (the mean tip-error norm pure noise would give, comparable to ``mean_mm``),
    ``sigma_mm`` (per coordinate), ``method`` (how) and the numbers behind it.
    """
    q = np.asarray(q, dtype=float)
    n_joints = q.shape[-1]
    half = n_joints // 2
    r = np.asarray(residual_mm, dtype=float)[:, list(tubes), :].reshape(len(q), -1)
    ok = np.isfinite(r).all(1)
    q, d, r = q[ok], np.asarray(direction, dtype=float)[ok], r[ok]
    weight = np.where(np.arange(n_joints) < half, 1.0, ALPHA_MM_PER_RAD)
    moving = np.ptp(q, axis=0) > 1e-9 if len(q) else np.zeros(n_joints, dtype=bool)
    x = (q * weight)[:, moving]
    lag = d[:, half:][:, moving[half:]]
    lag = lag[:, np.ptp(lag, axis=0) > 0] if lag.size else lag
    p = 1 + x.shape[1] + lag.shape[1]
    out: dict = {"method": "", "noise_mm": None, "sigma_mm": None, "rows": int(len(q))}
    estimates = {}
    for k in (p + 4, 2 * p + 4):
        if len(q) < k + 2:
            continue
        sigma, dist = _local_linear_sigma(x, lag, r, k)
        estimates[k] = (sigma, dist)
    if not estimates:
        out["method"] = f"not estimated: {len(q)} rows are too few for {p} local parameters"
        return out
    k, (sigma, dist) = min(estimates.items(), key=lambda t: t[1][0])
    out.update(
        noise_mm=float(sigma * MEAN_NORM_PER_SIGMA), sigma_mm=float(sigma),
        neighbours=int(k), median_neighbour_distance_mm=float(dist),
        estimates_sigma_mm={str(kk): float(v[0]) for kk, v in estimates.items()},
        method=(f"leave-one-out local linear fit of the nominal residual over the {k} nearest "
                f"configurations (moving joints, alpha at {ALPHA_MM_PER_RAD:g} mm/rad; direction of "
                f"motion as a regressor), robust scale over {len(q)} rows x {r.shape[1]} coordinates; "
                f"independent of the fitted extensions"))
    return out


def _local_linear_sigma(x: np.ndarray, lag: np.ndarray, r: np.ndarray, k: int) -> tuple[float, float]:
    """Robust per-coordinate noise sigma (mm) of the leave-one-out local linear smoother with ``k``
    neighbours, and the median distance to the neighbours."""
    n = len(x)
    if x.shape[1]:
        dist, nb = cKDTree(x).query(x, k=k + 1)
        dist, nb = dist[:, 1:], nb[:, 1:]          # drop the row itself
    else:                                          # nothing moves: the neighbours are any rows
        nb = np.array([np.delete(np.arange(n), i)[:k] for i in range(n)])
        dist = np.zeros_like(nb, dtype=float)
    dx = x[nb] - x[:, None, :]                                  # (n, k, D)
    X = np.concatenate([np.ones((n, k, 1)), dx, lag[nb]], axis=2)
    x0 = np.concatenate([np.ones((n, 1)), np.zeros((n, x.shape[1])), lag], axis=1)
    w = np.einsum("np,npk->nk", x0, np.linalg.pinv(X))          # prediction weights (n, k)
    e = r - np.einsum("nk,nkc->nc", w, r[nb])
    z = e / np.sqrt(1.0 + (w * w).sum(1))[:, None]
    return float(1.4826 * np.median(np.abs(z))), float(np.median(dist))
