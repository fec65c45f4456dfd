"""Conservative distance-grid broadphase: clears capsules far from every obstacle before FCL.

`DistanceGrid` stores, per cubic cell of ``cell_mm`` over the obstacles' bounding box grown by
``band_mm`` plus the largest obstacle margin, the margin-reduced distance d(x) = min over obstacles j of
(distance to j - ``margin_mm`` of j) (mm) at the cell centre, clamped to [0, ``band_mm``] and rounded
down to 1/255 of ``band_mm`` (uint8). The geometry is what FCL tests: the triangles of a mesh obstacle
(a surface -- FCL's BVH models are triangle soups) and the solid of a primitive. d is 1-Lipschitz, so
for any point x in a cell with centre c, ``d(x) >= value(c) - |x - c|`` where d(c) >= 0 (a cell where
d(c) < 0 stores 0, and its bound then never clears a capsule), and a point outside the grid has
d >= ``band_mm``. A capsule's axis is sampled
at spacing <= ``cell_mm / 2``; every axis point is within half that spacing of a sample, so

    d(axis) >= min_samples(value(c) - |x - c|) - spacing / 2,

a lower bound of the margin-reduced clearance of the axis. A capsule of radius r (the robot's margin
included) is *certainly free* -- further than r plus its margin from every obstacle -- when that bound
exceeds r; only the other capsules go to FCL, which stays the judge of every free verdict.

The same cells bound d from above: a stored value v < 255 means d(c) < (v + 1) * step (rounding was
down; a negative d stored as 0), so ``d(x) < (v + 1) * step + |x - c|`` at any point x. A capsule is
*certainly in contact* when that bound, at a point of its axis and any of the 8 cell centres around
it, is below r: some obstacle is then nearer than r plus its margin to the axis, which is what FCL
reports as a contact. A planner's rejected states mostly end there, without FCL (`capsule_contact`).

The grid is built once per set of obstacles (compiled; seconds for the skull-base anatomy) and cached
in memory and, when it took long to build, on disk in the user cache directory (``$CTRPLAN_CACHE_DIR``, else
``$XDG_CACHE_HOME/ctrplan`` or ``~/.cache/ctrplan``), keyed by a hash of the obstacles' geometry and
the grid parameters; an unwritable cache directory only costs the rebuild.
"""

from __future__ import annotations

import hashlib
import math
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from numba import njit

from ctrplan.scene.objects import Obstacle

#: Bump when the grid's content or file layout changes (old cache files are then ignored).
GRID_VERSION = 3
#: Default cell edge (mm) and distance cap (mm).
CELL_MM = 0.5
BAND_MM = 4.0
#: Largest grid (cells); a larger obstacle box gets coarser cells.
MAX_CELLS = 48_000_000
_LEVELS = 255
#: Grids that build faster than this (s) are not written to the disk cache.
SAVE_AFTER_S = 0.5


def primitive_bounds(o: Obstacle) -> np.ndarray:
    """Axis-aligned bounds (2, 3) of a primitive obstacle in the scene frame (mm)."""
    R, c = o.pose[:3, :3], o.pose[:3, 3]
    if o.kind == "sphere":
        e = np.full(3, o.radius)
    elif o.kind == "box":
        e = np.abs(R) @ (0.5 * np.asarray(o.size))
    elif o.kind == "cylinder":  # disc of radius r swept along the axis a: |a_k| h + r sqrt(1 - a_k^2)
        a = R[:, 2]
        e = np.abs(a) * 0.5 * o.length + o.radius * np.sqrt(np.clip(1.0 - a**2, 0.0, 1.0))
    elif o.kind == "capsule":  # segment along the axis plus a ball
        e = np.abs(R[:, 2]) * 0.5 * o.length + o.radius
    else:
        raise ValueError(f"unknown primitive kind {o.kind!r}")
    return np.stack([c - e - 1e-9, c + e + 1e-9])


def obstacle_bounds(o: Obstacle) -> np.ndarray:
    """Axis-aligned bounds (2, 3) of any obstacle in the scene frame (mm)."""
    if o.kind == "mesh":
        v = np.asarray(o.vertices, dtype=float)
        return np.stack([v.min(axis=0), v.max(axis=0)])
    return primitive_bounds(o)


# ---- compiled kernels ----------------------------------------------------------------------------
@njit(cache=True, fastmath=False)
def _point_triangle_distance(px, py, pz, a, b, c):
    """Distance (mm) from point p to the triangle abc (closest-point regions, Ericson 5.1.5)."""
    abx, aby, abz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    acx, acy, acz = c[0] - a[0], c[1] - a[1], c[2] - a[2]
    apx, apy, apz = px - a[0], py - a[1], pz - a[2]
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return math.sqrt(apx * apx + apy * apy + apz * apz)
    bpx, bpy, bpz = px - b[0], py - b[1], pz - b[2]
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return math.sqrt(bpx * bpx + bpy * bpy + bpz * bpz)
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        t = d1 / (d1 - d3)
        qx, qy, qz = a[0] + t * abx - px, a[1] + t * aby - py, a[2] + t * abz - pz
        return math.sqrt(qx * qx + qy * qy + qz * qz)
    cpx, cpy, cpz = px - c[0], py - c[1], pz - c[2]
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        return math.sqrt(cpx * cpx + cpy * cpy + cpz * cpz)
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        t = d2 / (d2 - d6)
        qx, qy, qz = a[0] + t * acx - px, a[1] + t * acy - py, a[2] + t * acz - pz
        return math.sqrt(qx * qx + qy * qy + qz * qz)
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        qx = b[0] + t * (c[0] - b[0]) - px
        qy = b[1] + t * (c[1] - b[1]) - py
        qz = b[2] + t * (c[2] - b[2]) - pz
        return math.sqrt(qx * qx + qy * qy + qz * qz)
    den = 1.0 / (va + vb + vc)
    v = vb * den
    w = vc * den
    qx = a[0] + abx * v + acx * w - px
    qy = a[1] + aby * v + acy * w - py
    qz = a[2] + abz * v + acz * w - pz
    return math.sqrt(qx * qx + qy * qy + qz * qz)


@njit(cache=True)
def _point_segment_distance(px, py, pz, a, b):
    """Distance (mm) from point p to the segment ab."""
    dx, dy, dz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    dd = dx * dx + dy * dy + dz * dz
    t = 0.0 if dd <= 0.0 else ((px - a[0]) * dx + (py - a[1]) * dy + (pz - a[2]) * dz) / dd
    t = min(1.0, max(0.0, t))
    qx, qy, qz = a[0] + t * dx - px, a[1] + t * dy - py, a[2] + t * dz - pz
    return math.sqrt(qx * qx + qy * qy + qz * qz)


@njit(cache=True)
def _rasterise_triangles(V, F, lo, cell, band, step, values, margin):
    """Lower ``values`` (uint8 cells) to floor(clip(d - margin, 0, band) / step) of the cell centres'
    distance d (mm) to the triangles F (T, 3) of vertices V (n, 3), for centres within ``band +
    margin`` of a triangle."""
    reach = band + margin
    nx, ny, nz = values.shape
    for t in range(F.shape[0]):
        a, b, c = V[F[t, 0]], V[F[t, 1]], V[F[t, 2]]
        nrm = np.cross(b - a, c - a)
        nn = math.sqrt(nrm[0] ** 2 + nrm[1] ** 2 + nrm[2] ** 2)
        scale = max(np.sum((b - a) ** 2), np.sum((c - a) ** 2), np.sum((c - b) ** 2))
        flat = nn <= 1e-9 * scale  # degenerate (collinear or coincident vertices): its three edges
        if not flat:
            nrm = nrm / nn
        i0 = np.empty(3, dtype=np.int64)
        i1 = np.empty(3, dtype=np.int64)
        for k in range(3):
            tmin = min(a[k], b[k], c[k]) - reach
            tmax = max(a[k], b[k], c[k]) + reach
            i0[k] = max(0, int(math.floor((tmin - lo[k]) / cell - 0.5)))
            i1[k] = min(values.shape[k] - 1, int(math.ceil((tmax - lo[k]) / cell - 0.5)))
        for ix in range(i0[0], i1[0] + 1):
            x = lo[0] + (ix + 0.5) * cell
            for iy in range(i0[1], i1[1] + 1):
                y = lo[1] + (iy + 0.5) * cell
                for iz in range(i0[2], i1[2] + 1):
                    z = lo[2] + (iz + 0.5) * cell
                    if flat:
                        d = min(_point_segment_distance(x, y, z, a, b),
                                _point_segment_distance(x, y, z, b, c),
                                _point_segment_distance(x, y, z, a, c)) - margin
                    else:  # the plane distance bounds the triangle distance from below
                        pd = abs((x - a[0]) * nrm[0] + (y - a[1]) * nrm[1] + (z - a[2]) * nrm[2]) - margin
                        if pd >= band or int(max(pd, 0.0) / step) >= values[ix, iy, iz]:
                            continue
                        d = _point_triangle_distance(x, y, z, a, b, c) - margin
                    if d < band:
                        q = int(max(d, 0.0) / step)
                        if q < values[ix, iy, iz]:
                            values[ix, iy, iz] = q
    return nx * ny * nz


@njit(cache=True)
def _point_bound(x, y, z, lo, cell, step, band, values):
    """Lower bound (mm) of the distance from point (x, y, z) to the obstacles."""
    fx, fy, fz = (x - lo[0]) / cell, (y - lo[1]) / cell, (z - lo[2]) / cell
    ix, iy, iz = int(math.floor(fx)), int(math.floor(fy)), int(math.floor(fz))
    if ix < 0 or iy < 0 or iz < 0 or ix >= values.shape[0] or iy >= values.shape[1] or iz >= values.shape[2]:
        return band  # outside the grid: at least band from every obstacle
    ex, ey, ez = (fx - ix - 0.5) * cell, (fy - iy - 0.5) * cell, (fz - iz - 0.5) * cell
    return values[ix, iy, iz] * step - math.sqrt(ex * ex + ey * ey + ez * ez)


@njit(cache=True)
def _point_upper_bound(x, y, z, lo, cell, step, values):
    """Upper bound (mm) of the distance from point (x, y, z) to the obstacles, from the 8 cell centres
    around it (inf where none of them is within the band)."""
    fx, fy, fz = (x - lo[0]) / cell - 0.5, (y - lo[1]) / cell - 0.5, (z - lo[2]) / cell - 0.5
    i0, j0, k0 = int(math.floor(fx)), int(math.floor(fy)), int(math.floor(fz))
    best = np.inf
    for ix in range(max(i0, 0), min(i0 + 2, values.shape[0])):
        for iy in range(max(j0, 0), min(j0 + 2, values.shape[1])):
            for iz in range(max(k0, 0), min(k0 + 2, values.shape[2])):
                v = values[ix, iy, iz]
                if v < _LEVELS:
                    ex, ey, ez = fx - ix, fy - iy, fz - iz
                    best = min(best, (v + 1) * step + cell * math.sqrt(ex * ex + ey * ey + ez * ez))
    return best


@njit(cache=True)
def capsule_contact(a, b, radius, lo, cell, step, values, spacing):
    """Whether the capsule of axis a -> b (3,) and ``radius`` (mm) is certainly in contact with an
    obstacle (see the module docstring): the upper bound at axis samples ``spacing`` apart is below
    the radius. False says nothing (FCL decides)."""
    dx, dy, dz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    k = max(1, int(math.ceil(math.sqrt(dx * dx + dy * dy + dz * dz) / spacing)))
    for j in range(k + 1):
        t = j / k
        if _point_upper_bound(a[0] + t * dx, a[1] + t * dy, a[2] + t * dz, lo, cell, step, values) \
                < radius - 1e-9:
            return True
    return False


@njit(cache=True)
def _capsule_lower_bounds(points, radii, lo, cell, step, band, values, spacing, out):
    """Lower bounds ``out`` (B, N-1) of the distance (mm) from each segment of the polylines
    ``points`` (B, N, 3) to the obstacles; -inf for segments with non-finite points. A segment is
    first bounded from its ends and midpoint; only where that bound does not exceed its capsule
    radius ``radii`` (B, N-1) is it sampled at ``spacing`` for a tighter one."""
    nb, n = points.shape[0], points.shape[1]
    for b in range(nb):
        for i in range(n - 1):
            ax, ay, az = points[b, i, 0], points[b, i, 1], points[b, i, 2]
            dx, dy, dz = points[b, i + 1, 0] - ax, points[b, i + 1, 1] - ay, points[b, i + 1, 2] - az
            length = math.sqrt(dx * dx + dy * dy + dz * dz)
            if not (math.isfinite(length) and math.isfinite(ax + ay + az)):
                out[b, i] = -np.inf
                continue
            k = 2
            while True:
                best = np.inf
                for j in range(k + 1):
                    t = j / k
                    v = _point_bound(ax + t * dx, ay + t * dy, az + t * dz, lo, cell, step, band, values)
                    best = min(best, v)
                out[b, i] = best - 0.5 * length / k
                if out[b, i] > radii[b, i] or length / k <= spacing:
                    break
                k = max(k + 1, int(math.ceil(length / spacing)))


# ---- primitives (vectorised numpy) ---------------------------------------------------------------
def _solid_distance(o: Obstacle, x: np.ndarray) -> np.ndarray:
    """Distance (mm, 0 inside) from points x (..., 3) to the solid of primitive ``o``."""
    R, c = o.pose[:3, :3], o.pose[:3, 3]
    p = (x - c) @ R  # local frame
    if o.kind == "sphere":
        return np.maximum(np.linalg.norm(p, axis=-1) - o.radius, 0.0)
    if o.kind == "box":
        return np.linalg.norm(np.maximum(np.abs(p) - 0.5 * np.asarray(o.size), 0.0), axis=-1)
    if o.kind == "cylinder":
        dr = np.hypot(p[..., 0], p[..., 1]) - o.radius
        dz = np.abs(p[..., 2]) - 0.5 * o.length
        return np.hypot(np.maximum(dr, 0.0), np.maximum(dz, 0.0))
    if o.kind == "capsule":
        z = np.clip(p[..., 2], -0.5 * o.length, 0.5 * o.length)
        return np.maximum(np.sqrt(p[..., 0] ** 2 + p[..., 1] ** 2 + (p[..., 2] - z) ** 2) - o.radius, 0.0)
    raise ValueError(f"unknown primitive kind {o.kind!r}")


# ---- the grid ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class DistanceGrid:
    """Capped, rounded-down margin-reduced distances (uint8, unit ``band_mm / 255``) from cell centres
    to the obstacles (see the module docstring). ``lo`` (3,) is the grid's lower corner (mm, scene
    frame); cell (i, j, k) has its centre at ``lo + (i + 0.5, j + 0.5, k + 0.5) * cell_mm``."""

    lo: np.ndarray
    cell_mm: float
    band_mm: float
    values: np.ndarray

    @property
    def step_mm(self) -> float:
        """Distance per unit of ``values`` (mm)."""
        return self.band_mm / _LEVELS

    @property
    def spacing_mm(self) -> float:
        """Spacing (mm) of the samples along a capsule axis."""
        return 0.5 * self.cell_mm

    @classmethod
    def build(cls, obstacles: Sequence[Obstacle], cell_mm: float = CELL_MM,
              band_mm: float = BAND_MM) -> DistanceGrid:
        """Rasterise ``obstacles`` (scene frame, mm): exact margin-reduced distances within
        ``band_mm``."""
        bounds = np.stack([obstacle_bounds(o) for o in obstacles])
        reach = band_mm + max(o.margin_mm for o in obstacles)
        lo = bounds[:, 0].min(axis=0) - reach - cell_mm
        hi = bounds[:, 1].max(axis=0) + reach + cell_mm
        extent = hi - lo
        cells = float(np.prod(np.ceil(extent / cell_mm)))
        if cells > MAX_CELLS:
            cell_mm = float(cell_mm * (cells / MAX_CELLS) ** (1.0 / 3.0))
            while np.prod(np.ceil(extent / cell_mm)) > MAX_CELLS:  # rounding up added cells
                cell_mm *= 1.02
        shape = tuple(int(s) for s in np.ceil(extent / cell_mm))
        values = np.full(shape, _LEVELS, dtype=np.uint8)
        _paint(obstacles, lo, float(cell_mm), float(band_mm), values)
        return cls(lo, float(cell_mm), float(band_mm), values)

    def translated(self, shift_mm: np.ndarray) -> DistanceGrid:
        """The grid of the same obstacles moved by ``shift_mm`` (3,) (mm): the same cells, moved (exact:
        the distance field moves with its obstacles)."""
        return replace(self, lo=self.lo + np.asarray(shift_mm, dtype=float))

    def grown_to(self, obstacle: Obstacle) -> DistanceGrid:
        """This grid, grown (on the same lattice) to cover every cell within the band and margin of
        ``obstacle``: the new cells are at least the band from every obstacle the grid was built
        from (the grid reached that far beyond them), so they hold the cap -- exact until
        ``obstacle`` is painted in (`repainted`)."""
        b = obstacle_bounds(obstacle)
        reach = self.band_mm + obstacle.margin_mm + self.cell_mm
        shape = np.array(self.values.shape)
        below = np.maximum(0, np.ceil((self.lo - (b[0] - reach)) / self.cell_mm)).astype(int)
        hi = self.lo + shape * self.cell_mm
        above = np.maximum(0, np.ceil((b[1] + reach - hi) / self.cell_mm)).astype(int)
        if not below.any() and not above.any():
            return self
        values = np.full(tuple(shape + below + above), _LEVELS, dtype=np.uint8)
        values[tuple(slice(a, a + n) for a, n in zip(below, shape, strict=True))] = self.values
        return replace(self, lo=self.lo - below * self.cell_mm, values=values)

    def cells_of(self, box_mm: np.ndarray) -> tuple[slice, ...]:
        """The index ranges of the cells within ``box_mm`` (2, 3) (scene frame, mm), clipped to the
        grid."""
        shape = np.array(self.values.shape)
        i0 = np.clip(np.floor((box_mm[0] - self.lo) / self.cell_mm).astype(int), 0, shape)
        i1 = np.clip(np.ceil((box_mm[1] - self.lo) / self.cell_mm).astype(int), 0, shape)
        return tuple(slice(int(a), int(b)) for a, b in zip(i0, i1, strict=True))

    def painted(self, obstacles: Sequence[Obstacle], cells: tuple[slice, ...]) -> np.ndarray:
        """The values ``obstacles`` alone give the ``cells`` (`cells_of`) of this grid's lattice;
        only the obstacles near them are rasterised."""
        i0 = np.array([c.start for c in cells])
        i1 = np.array([c.stop for c in cells])
        sub = np.full(tuple(i1 - i0), _LEVELS, dtype=np.uint8)
        lo, hi = self.lo + i0 * self.cell_mm, self.lo + i1 * self.cell_mm
        near = [o for o in obstacles
                if np.all(obstacle_bounds(o)[0] - self.band_mm - o.margin_mm <= hi)
                and np.all(obstacle_bounds(o)[1] + self.band_mm + o.margin_mm >= lo)]
        if sub.size:
            _paint(near, lo, self.cell_mm, self.band_mm, sub)
        return sub

    def with_cells(self, cells: tuple[slice, ...], values: np.ndarray) -> DistanceGrid:
        """A copy with ``values`` in ``cells``: the grid of a set of obstacles that differs from the
        one this grid holds only within those cells shrunk by the band and the margins (see
        `ctrplan.collision.world.CollisionWorld.moved`)."""
        out = self.values.copy()
        out[cells] = values
        return replace(self, values=out)

    def segment_lower_bounds(self, points: np.ndarray, radii: np.ndarray | None = None) -> np.ndarray:
        """Lower bounds (B, N-1) of the margin-reduced distance (mm) from each segment of polylines
        (B, N, 3) (scene frame, mm) to the obstacles (<= 0 where it may be negative); -inf where a
        point is not finite. With capsule ``radii`` (B, N-1) (mm), a bound that already exceeds the
        radius is not tightened further (enough to clear the capsule); without, every bound is the
        tight one."""
        p = np.ascontiguousarray(points, dtype=float)
        shape = (p.shape[0], p.shape[1] - 1)
        r = np.full(shape, np.inf) if radii is None else np.ascontiguousarray(radii, dtype=float)
        out = np.empty(shape)
        _capsule_lower_bounds(p, r, self.lo, self.cell_mm, self.step_mm, self.band_mm, self.values,
                              self.spacing_mm, out)
        return out


def _paint(obstacles: Sequence[Obstacle], lo: np.ndarray, cell_mm: float, band_mm: float,
           values: np.ndarray) -> None:
    """Lower the cells ``values`` (uint8, lower corner ``lo``) to every obstacle's rounded-down
    margin-reduced distance (see the module docstring)."""
    step = band_mm / _LEVELS
    shape = np.array(values.shape)
    for o in obstacles:
        if o.kind == "mesh":
            _rasterise_triangles(np.ascontiguousarray(o.vertices, dtype=float),
                                 np.ascontiguousarray(o.faces, dtype=np.int64), lo, cell_mm, band_mm,
                                 step, values, float(o.margin_mm))
            continue
        b = primitive_bounds(o)
        m = band_mm + o.margin_mm
        i0 = np.maximum(0, np.floor((b[0] - m - lo) / cell_mm).astype(int))
        i1 = np.minimum(shape, np.ceil((b[1] + m - lo) / cell_mm).astype(int) + 1)
        if np.any(i1 <= i0):
            continue
        axes = [lo[k] + (np.arange(i0[k], i1[k]) + 0.5) * cell_mm for k in range(3)]
        centres = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
        d = np.clip(_solid_distance(o, centres) - o.margin_mm, 0.0, band_mm)
        q = np.floor(d / step).astype(np.uint8)
        sl = tuple(slice(i0[k], i1[k]) for k in range(3))
        values[sl] = np.minimum(values[sl], q)


def geometry_key(obstacles: Sequence[Obstacle], cell_mm: float, band_mm: float) -> str:
    """Hash (hex) of the obstacles' geometry, margins and the grid parameters: the cache key."""
    h = hashlib.sha256(f"ctrplan-grid-{GRID_VERSION}-{cell_mm!r}-{band_mm!r}".encode())
    for o in obstacles:
        h.update(o.kind.encode())
        for a in (o.pose, o.radius, o.length, o.size, o.vertices, o.faces, o.margin_mm):
            if a is not None:
                arr = np.ascontiguousarray(a, dtype=np.int64 if a is o.faces else float)
                h.update(str(arr.shape).encode())
                h.update(arr.tobytes())
    return h.hexdigest()[:32]


def cache_dir() -> Path:
    """Directory of cached grids: ``$CTRPLAN_CACHE_DIR``, else the user cache directory."""
    env = os.environ.get("CTRPLAN_CACHE_DIR")
    if env:
        return Path(env) / "broadphase"
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "ctrplan" / "broadphase"


def _load(path: Path) -> DistanceGrid | None:
    try:
        with np.load(path) as z:
            grid = DistanceGrid(z["lo"].astype(float), float(z["cell_mm"]), float(z["band_mm"]),
                                z["values"].astype(np.uint8))
    except (OSError, KeyError, ValueError):
        return None
    return grid if grid.values.ndim == 3 and grid.lo.shape == (3,) else None


def _save(grid: DistanceGrid, path: Path) -> None:
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp.npz")
        np.savez_compressed(tmp, lo=grid.lo, cell_mm=grid.cell_mm, band_mm=grid.band_mm,
                            values=grid.values)
        os.replace(tmp, path)
    except OSError:
        pass  # caching is an optimisation only


def grid_for(obstacles: Sequence[Obstacle], cell_mm: float = CELL_MM, band_mm: float = BAND_MM,
             use_disk: bool = True) -> DistanceGrid | None:
    """The `DistanceGrid` of ``obstacles``: from the disk cache, or built (and cached on disk when
    building took at least `SAVE_AFTER_S`). None without obstacles. Nothing is kept in memory here:
    a `ctrplan.collision.world.CollisionWorld` holds its grid, so share the world."""
    if not obstacles:
        return None
    key = geometry_key(obstacles, cell_mm, band_mm)
    path = cache_dir() / f"{key}.npz"
    grid = _load(path) if use_disk and path.is_file() else None
    if grid is None:
        t = time.perf_counter()
        grid = DistanceGrid.build(obstacles, cell_mm, band_mm)
        if use_disk and time.perf_counter() - t >= SAVE_AFTER_S:
            _save(grid, path)
    return grid
