"""What the pictures of a plan show: the corridor (where the robot meets the obstacles, and the
target) and its direction (the anatomy along it: `ctrplan.viz.sections`).

All in the scene frame, mm; backbones (K, N, 3).
"""

from __future__ import annotations

import numpy as np

from ctrplan.scene.objects import Scene


def finite_points(backbones: np.ndarray) -> np.ndarray:
    """The finite points (M, 3) of backbones (..., 3)."""
    p = np.asarray(backbones, dtype=float).reshape(-1, 3)
    return p[np.all(np.isfinite(p), axis=1)]


def corridor_bounds(backbones: np.ndarray, scene: Scene, pad: float = 8.0) -> np.ndarray:
    """(lo, hi) (2, 3): the robot's bounds cut to the obstacles' bounds (the whole robot when they
    do not overlap, or without obstacles), grown to hold the target, plus ``pad``."""
    p = finite_points(backbones)
    t = scene.target
    lo, hi = (p.min(axis=0), p.max(axis=0)) if len(p) else (t.center, t.center)
    if scene.obstacles:
        ob = np.array([o.bounds for o in scene.obstacles])
        cut_lo, cut_hi = np.maximum(lo, ob[:, 0].min(axis=0)), np.minimum(hi, ob[:, 1].max(axis=0))
        if np.all(cut_lo < cut_hi):
            lo, hi = cut_lo, cut_hi
    lo = np.minimum(lo, t.center - t.semi_axes)
    hi = np.maximum(hi, t.center + t.semi_axes)
    return np.stack([lo - pad, hi + pad])


def corridor_direction(backbones: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """Unit vector (3,) along which the last backbone runs inside ``bounds`` (its principal axis,
    pointing towards its tip); +z when too few of its points are inside."""
    last = finite_points(np.asarray(backbones)[-1:])
    inside = last[np.all((last >= bounds[0]) & (last <= bounds[1]), axis=1)]
    if len(inside) < 3:
        return np.array([0.0, 0.0, 1.0])
    axis = np.linalg.svd(inside - inside.mean(axis=0), full_matrices=False)[2][0]
    return axis if np.dot(axis, inside[-1] - inside[0]) >= 0 else -axis
