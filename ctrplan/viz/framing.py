"""What the pictures of a plan show: the corridor (where the robot meets the obstacles, and the
target), its direction, and, for a 2-D projection, the obstacles near the path in the projected-away
axis (a section along the corridor, so nothing beside the path seems to lie on it).

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


def section(triangles: np.ndarray, backbones: np.ndarray, along: int, away: int,
            half_width: float = 4.0, bin_mm: float = 1.0) -> np.ndarray:
    """Which triangles (T, 3, 3) lie within ``half_width`` of the path in the projected-away axis
    ``away``, at their position along axis ``along`` (T,) bool: at every depth along ``along``, the
    path's extent in ``away`` is widened by ``half_width`` (also along ``along``, to cover the
    neighbourhood) and a triangle is kept when its extent meets it there."""
    p = finite_points(backbones)
    if not len(p) or not len(triangles):
        return np.zeros(len(triangles), dtype=bool)
    start = p[:, along].min() - half_width
    bins = np.floor((p[:, along] - start) / bin_mm).astype(int)
    n = int(bins.max()) + 1 + int(np.ceil(half_width / bin_mm))
    lo, hi = np.full(n, np.inf), np.full(n, -np.inf)
    np.minimum.at(lo, bins, p[:, away])
    np.maximum.at(hi, bins, p[:, away])
    reach = int(np.ceil(half_width / bin_mm))  # widen along the corridor too
    lo = np.min([np.roll(np.pad(lo, reach, constant_values=np.inf), k)[reach:-reach]
                 for k in range(-reach, reach + 1)], axis=0) - half_width
    hi = np.max([np.roll(np.pad(hi, reach, constant_values=-np.inf), k)[reach:-reach]
                 for k in range(-reach, reach + 1)], axis=0) + half_width
    t_lo, t_hi = triangles.min(axis=1), triangles.max(axis=1)
    first = np.clip(np.floor((t_lo[:, along] - start) / bin_mm).astype(int), 0, n - 1)
    last = np.clip(np.floor((t_hi[:, along] - start) / bin_mm).astype(int), 0, n - 1)
    inside = (t_hi[:, along] >= start) & (t_lo[:, along] <= start + n * bin_mm)
    keep = np.zeros(len(triangles), dtype=bool)
    for i in np.flatnonzero(inside):
        a, b = first[i], last[i] + 1
        keep[i] = t_hi[i, away] >= lo[a:b].min() and t_lo[i, away] <= hi[a:b].max()
    return keep
