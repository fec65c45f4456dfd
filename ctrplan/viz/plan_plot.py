"""Static picture of a planned path: the scene and backbones along the path (matplotlib, Agg)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ctrplan.scene import Scene


def _view_bounds(backbones: np.ndarray, scene: Scene, pad: float = 12.0) -> np.ndarray:
    pts = [backbones.reshape(-1, 3), scene.target.center[None]]
    p = np.concatenate([q[np.all(np.isfinite(q), axis=1)] for q in pts])
    lo, hi = p.min(axis=0) - pad, p.max(axis=0) + pad
    return np.stack([lo, hi])


def _zoom_bounds(backbones: np.ndarray, scene: Scene, pad: float = 8.0) -> np.ndarray:
    """Where robot and obstacles meet: the robot's bounds cut to the obstacles' bounds (or the
    robot's bounds alone when they do not overlap)."""
    full = _view_bounds(backbones, scene, pad=0.0)
    if not scene.obstacles:
        return full + np.array([[-pad], [pad]])
    ob = np.array([o.bounds for o in scene.obstacles])
    lo = np.maximum(full[0], ob[:, 0].min(axis=0))
    hi = np.minimum(full[1], ob[:, 1].max(axis=0))
    if np.any(lo >= hi):
        lo, hi = full
    t = scene.target
    lo = np.minimum(lo, t.center - t.semi_axes)
    hi = np.maximum(hi, t.center + t.semi_axes)
    return np.stack([lo - pad, hi + pad])


def triangles_in(scene: Scene, bounds: np.ndarray, max_triangles: int = 6000):
    """(name, triangles (T, 3, 3)) of every obstacle, clipped to triangles touching ``bounds``."""
    out = []
    for o in scene.obstacles:
        m = o.to_trimesh()
        tri = np.asarray(m.vertices)[np.asarray(m.faces)]
        lo, hi = tri.min(axis=1), tri.max(axis=1)
        keep = np.all((hi >= bounds[0]) & (lo <= bounds[1]), axis=1)
        if keep.any():
            out.append((o.name, tri[keep]))
    total = sum(len(t) for _, t in out)
    if total > max_triangles:  # thin out uniformly for speed
        step = int(np.ceil(total / max_triangles))
        out = [(n, t[::step]) for n, t in out]
    return out


def plot_plan(scene: Scene, backbones_scene: np.ndarray, path: str | Path, *, title: str = "",
              tip_path: np.ndarray | None = None, max_backbones: int = 12) -> Path:
    """Write a PNG of `plan_figure` (arguments as there)."""
    import matplotlib.pyplot as plt

    path = Path(path)
    fig = plan_figure(scene, backbones_scene, title=title, tip_path=tip_path, max_backbones=max_backbones)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path


def plan_figure(scene: Scene, backbones_scene: np.ndarray, *, title: str = "",
                tip_path: np.ndarray | None = None, max_backbones: int = 12):
    """A matplotlib figure: a 3-D view plus sagittal (z-y) and axial (z-x) projections of the
    obstacles near the robot, backbones along the path (start blue -> end red), the tip trace and
    the target region; the legend names every obstacle.

    ``backbones_scene`` (K, N, 3): backbones along the path in the scene frame (mm); ``tip_path``
    (M, 3): the tip along the path (mm).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection
    from matplotlib.patches import Patch
    from matplotlib.ticker import MaxNLocator
    from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

    bbs = np.asarray(backbones_scene, dtype=float)
    k = bbs.shape[0]
    pick = np.unique(np.linspace(0, k - 1, min(k, max_backbones)).round().astype(int))
    bounds = _view_bounds(bbs, scene)
    tris = triangles_in(scene, bounds)
    cmap = plt.get_cmap("coolwarm")
    names = [o.name for o in scene.obstacles]
    tab = plt.get_cmap("tab20")  # colours repeat after 20 obstacles; the legend names them all
    colour = {n: tab(i % 20) for i, n in enumerate(names)}

    ncol = 8
    legend_rows = -(-(len(names) + 4) // ncol)
    bottom = 0.08 + 0.025 * legend_rows
    fig = plt.figure(figsize=(15, 8.0 + 0.2 * legend_rows), dpi=100)
    grid = fig.add_gridspec(2, 3, hspace=0.35, wspace=0.25, left=0.02, right=0.98, top=0.92, bottom=bottom)
    ax3 = fig.add_subplot(grid[:, 0], projection="3d")
    for n, t in tris:
        pc = Poly3DCollection(t, facecolor=colour[n], edgecolor="none", alpha=0.12)
        ax3.add_collection3d(pc)
    for j, i in enumerate(pick):
        c = cmap(j / max(1, len(pick) - 1))
        ax3.plot(*bbs[i].T, color=c, lw=2.5 if i in (pick[0], pick[-1]) else 1.0)
    if tip_path is not None:
        ax3.add_collection3d(Line3DCollection([tip_path], colors="k", linewidths=0.6))
    _target_3d(ax3, scene)
    ax3.set_xlim(bounds[:, 0])
    ax3.set_ylim(bounds[:, 1])
    ax3.set_zlim(bounds[:, 2])
    for axis in (ax3.xaxis, ax3.yaxis, ax3.zaxis):  # few, small ticks: labels must not overlap
        axis.set_major_locator(MaxNLocator(4))
    ax3.tick_params(labelsize=7, pad=1)
    ax3.set_xlabel("x (mm)", fontsize=8, labelpad=2)
    ax3.set_ylabel("y (mm)", fontsize=8, labelpad=2)
    ax3.set_zlabel("z (mm)", fontsize=8, labelpad=2)
    ax3.view_init(elev=18, azim=-60)
    ax3.set_box_aspect(np.maximum(np.ptp(bounds, axis=0), 0.25 * np.ptp(bounds, axis=0).max()))
    ax3.set_title("overview", fontsize=10)

    zoom = _zoom_bounds(bbs, scene)
    tris = triangles_in(scene, zoom, max_triangles=12000)
    for row, (a, b, lab) in enumerate(((2, 1, "side view (z-y)"), (2, 0, "top view (z-x)"))):
        ax = fig.add_subplot(grid[row, 1:])
        for n, t in tris:
            ax.add_collection(PolyCollection(t[:, :, [a, b]], facecolor=colour[n], edgecolor="none",
                                             alpha=0.10))
        for j, i in enumerate(pick):
            c = cmap(j / max(1, len(pick) - 1))
            ax.plot(bbs[i, :, a], bbs[i, :, b], color=c, lw=2.5 if i in (pick[0], pick[-1]) else 1.0)
        if tip_path is not None:
            ax.plot(tip_path[:, a], tip_path[:, b], "k-", lw=0.6)
        _target_2d(ax, scene, a, b)
        ax.set_xlim(zoom[:, a])
        ax.set_ylim(zoom[:, b])
        ax.set_aspect("equal")
        ax.set_xlabel("xyz"[a] + " (mm)")
        ax.set_ylabel("xyz"[b] + " (mm)")
        ax.set_title(lab, fontsize=10)
    handles = [Patch(color=colour[n], alpha=0.4) for n in names]
    handles += [Patch(color="green", alpha=0.35), plt.Line2D([], [], color="k", lw=0.8),
                plt.Line2D([], [], color=cmap(0.0), lw=2.5), plt.Line2D([], [], color=cmap(1.0), lw=2.5)]
    labels = [*names, "target", "tip trace", "start", "end"]
    fig.legend(handles, labels, loc="lower center", ncol=min(ncol, len(labels)), fontsize=7, frameon=False)
    fig.suptitle(title or f"{scene.name}: planned path ({k} states)", fontsize=11)
    return fig


def _ellipsoid_points(scene: Scene, n: int = 24) -> np.ndarray:
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, n), np.linspace(0, np.pi, n // 2))
    p = np.stack([np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v)], -1) * scene.target.semi_axes
    return p @ scene.target.rotation.T + scene.target.center


def _target_3d(ax, scene: Scene) -> None:
    p = _ellipsoid_points(scene)
    ax.plot_wireframe(p[..., 0], p[..., 1], p[..., 2], color="green", lw=0.4, alpha=0.6)


def _target_2d(ax, scene: Scene, a: int, b: int) -> None:
    p = _ellipsoid_points(scene, 48).reshape(-1, 3)
    from scipy.spatial import ConvexHull

    pts = p[:, [a, b]]
    hull = ConvexHull(pts)
    poly = pts[hull.vertices]
    ax.fill(poly[:, 0], poly[:, 1], color="green", alpha=0.35, lw=0)
