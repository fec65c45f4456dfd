"""Sections of the anatomy along the path, as a surgeon reads a curved reformat of a CT: for a projection
that hides one scene axis, every structure is cut by the surface that follows the path in that axis
(at each depth along the corridor, the plane through the path there), and the cut is drawn -- filled
where the mesh is closed (its inside, found by the even-odd rule along the cut), a solid outline where
it is an open surface (a wall given as a sheet).

The guide is a polyline (the final backbone, then the target's centre): at a depth ``a`` along the
corridor axis the cutting plane lies at the guide's coordinate in the hidden axis there (held constant
beyond its ends). Depths are binned (``step_mm``); within a bin the plane is flat. Pure geometry on the
scene's own meshes: nothing about the robot is computed here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Width (mm) of the depth bins of a curved section.
SECTION_STEP_MM = 0.75


@dataclass(frozen=True)
class Section:
    """One structure's cut in a projection's plot coordinates (along, across), mm: ``segments``
    (S, 2, 2) of the cut outline, ``fills`` (F, 4) rectangles (a0, a1, c0, c1) of its inside (closed
    meshes only)."""

    name: str
    segments: np.ndarray
    fills: np.ndarray

    @property
    def empty(self) -> bool:
        return not len(self.segments)

    def centre(self) -> np.ndarray:
        """A point (2,) on the cut: the segment midpoint nearest the cut's mean."""
        mid = self.segments.mean(axis=1)
        return mid[np.argmin(np.linalg.norm(mid - mid.mean(axis=0), axis=1))]


def guide_heights(guide: np.ndarray, along: int, hidden: int, depths: np.ndarray) -> np.ndarray:
    """The guide's coordinate in axis ``hidden`` at ``depths`` (D,) along axis ``along`` (interpolated
    over the guide's points ordered by depth; constant beyond its ends)."""
    g = guide[np.all(np.isfinite(guide), axis=1)]
    order = np.argsort(g[:, along], kind="stable")
    a, h = g[order, along], g[order, hidden]
    a, first = np.unique(a, return_index=True)
    return np.interp(depths, a, h[first])


def _plane_cuts(tri: np.ndarray, height: np.ndarray, hidden: int) -> tuple[np.ndarray, np.ndarray]:
    """Segments (M, 2, 3) where triangles (M, 3, 3) cross the planes ``hidden`` = ``height`` (M,), and
    which triangles do (M,) bool (a triangle touching the plane at a vertex only does not)."""
    d = tri[:, :, hidden] - height[:, None]  # (M, 3)
    above = d > 0
    crosses = above.any(axis=1) & ~above.all(axis=1)
    points = []
    for i, j in ((0, 1), (1, 2), (2, 0)):
        cut = above[:, i] != above[:, j]
        t = np.where(cut, d[:, i] / np.where(cut, d[:, i] - d[:, j], 1.0), np.nan)
        points.append((tri[:, i] + t[:, None] * (tri[:, j] - tri[:, i]), cut))
    seg = np.full((len(tri), 2, 3), np.nan)
    filled = np.zeros(len(tri), dtype=int)
    for p, cut in points:
        slot = cut & (filled < 2)
        seg[slot, filled[slot]] = p[slot]
        filled += slot
    return seg, crosses & (filled == 2)


def _clip(seg: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """2-D segments (M, 2, 2) clipped to their own bins lo <= x <= hi (M,) in the first coordinate;
    those outside dropped."""
    x0, x1 = seg[:, 0, 0], seg[:, 1, 0]
    dx = np.where(np.abs(x1 - x0) > 1e-12, x1 - x0, 1e-12)
    ta, tb = (lo - x0) / dx, (hi - x0) / dx
    t0 = np.clip(np.minimum(ta, tb), 0.0, 1.0)
    t1 = np.clip(np.maximum(ta, tb), 0.0, 1.0)
    flat = np.abs(x1 - x0) <= 1e-12
    inside = np.where(flat, (x0 >= lo) & (x0 <= hi), t1 > t0)
    t0, t1 = np.where(flat, 0.0, t0), np.where(flat, 1.0, t1)
    d = seg[:, 1] - seg[:, 0]
    out = np.stack([seg[:, 0] + t0[:, None] * d, seg[:, 0] + t1[:, None] * d], axis=1)
    return out[inside]


def _fills(seg2: np.ndarray, bins: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Inside intervals of a closed mesh's cut: in each bin, the crossings of its segments (M, 2, 2)
    (bin indices (M,)) with the bin's centre line, sorted and paired (even-odd); rectangles (F, 4)."""
    rects = []
    mid = 0.5 * (edges[:-1] + edges[1:])
    for k in np.unique(bins):
        s = seg2[bins == k]
        x0, x1, m = s[:, 0, 0], s[:, 1, 0], mid[k]
        cross = ((x0 <= m) & (m < x1)) | ((x1 <= m) & (m < x0))
        if cross.sum() < 2:
            continue
        s = s[cross]
        t = (m - s[:, 0, 0]) / (s[:, 1, 0] - s[:, 0, 0])
        c = np.sort(s[:, 0, 1] + t * (s[:, 1, 1] - s[:, 0, 1]))
        c = c[: len(c) // 2 * 2].reshape(-1, 2)
        rects += [(edges[k], edges[k + 1], c0, c1) for c0, c1 in c]
    return np.array(rects, dtype=float).reshape(-1, 4)


def curved_section(name: str, triangles: np.ndarray, closed: bool, guide: np.ndarray, along: int,
                   across: int, hidden: int, depth_range: tuple[float, float],
                   step_mm: float = SECTION_STEP_MM) -> Section:
    """The cut of one structure (triangles (T, 3, 3), scene frame, mm; ``closed``: a watertight mesh)
    by the surface that follows ``guide`` (P, 3) in axis ``hidden``, over ``depth_range`` of axis
    ``along``; plot coordinates (along, across)."""
    edges = np.arange(depth_range[0], depth_range[1] + step_mm, step_mm)
    heights = guide_heights(guide, along, hidden, 0.5 * (edges[:-1] + edges[1:]))
    lo, hi = triangles[:, :, along].min(axis=1), triangles[:, :, along].max(axis=1)
    first = np.clip(np.searchsorted(edges, lo, side="right") - 1, 0, len(heights) - 1)
    last = np.clip(np.searchsorted(edges, hi, side="right") - 1, 0, len(heights) - 1)
    keep = (hi >= edges[0]) & (lo <= edges[-1])
    tri_idx = np.repeat(np.flatnonzero(keep), (last - first + 1)[keep])
    bins = np.concatenate([np.arange(f, l_ + 1) for f, l_ in zip(first[keep], last[keep], strict=True)]) \
        if keep.any() else np.zeros(0, dtype=int)
    seg, ok = _plane_cuts(triangles[tri_idx], heights[bins], hidden)
    seg2, bins = seg[ok][:, :, [along, across]], bins[ok]
    fills = _fills(seg2, bins, edges) if closed and len(seg2) else np.zeros((0, 4))
    return Section(name, _clip(seg2, edges[bins], edges[bins + 1]), fills)
