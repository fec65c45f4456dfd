"""Static picture of a planned path: the scene and backbones along the path (matplotlib, Agg)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ctrplan.dataio import save_figure
from ctrplan.scene import Scene
from ctrplan.viz.framing import corridor_bounds, corridor_direction, section
from ctrplan.viz.style import TARGET_COLOR, axis_labels, obstacle_colors, view_name

#: A projection shows the obstacles within this distance (mm) of the path in its hidden axis.
SECTION_MM = 4.0


def _view_bounds(backbones: np.ndarray, scene: Scene, pad: float = 12.0) -> np.ndarray:
    pts = [backbones.reshape(-1, 3), scene.target.center[None]]
    p = np.concatenate([q[np.all(np.isfinite(q), axis=1)] for q in pts])
    lo, hi = p.min(axis=0) - pad, p.max(axis=0) + pad
    return np.stack([lo, hi])


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
    save_figure(fig, path)
    plt.close(fig)
    return path


def plan_figure(scene: Scene, backbones_scene: np.ndarray, *, title: str = "",
                tip_path: np.ndarray | None = None, max_backbones: int = 12):
    """A matplotlib figure: a 3-D overview plus two projections along the corridor (the scene axis
    closest to its direction runs across both) of backbones along the path (start blue -> end red),
    the tip trace and the target region (`TARGET_COLOR`, outlined and named). A projection shows
    only the obstacles within `SECTION_MM` of the final backbone in the axis it projects away (a
    section along the corridor: what lies beside the path is not drawn over it). Axes are named with the
    scene's patient directions when it gives them; the legend names every obstacle.

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
    colour = obstacle_colors(names)
    labels = axis_labels(scene.anatomy)

    def axis_title(a: int) -> str:
        ax = "xyz"[a]
        return f"{ax} (mm): {labels[ax][1]} to {labels[ax][0]}" if scene.anatomy else f"{ax} (mm)"

    ncol = 8
    legend_rows = -(-(len(names) + 4) // ncol)
    bottom = 0.08 + 0.025 * legend_rows
    fig = plt.figure(figsize=(15, 8.0 + 0.2 * legend_rows), dpi=100)
    grid = fig.add_gridspec(2, 3, hspace=0.35, wspace=0.25, left=0.02, right=0.98, top=0.92, bottom=bottom)
    ax3 = fig.add_subplot(grid[:, 0], projection="3d")
    for n, t in tris:
        backdrop = np.ptp(t.reshape(-1, 3), axis=0).max() > 0.8 * np.ptp(bounds, axis=0).max()  # a face plate
        pc = Poly3DCollection(t, facecolor=colour[n], edgecolor="none", alpha=0.04 if backdrop else 0.15)
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
    ax3.set_xlabel(axis_title(0), fontsize=8, labelpad=2)
    ax3.set_ylabel(axis_title(1), fontsize=8, labelpad=2)
    ax3.set_zlabel(axis_title(2), fontsize=8, labelpad=2)
    ax3.view_init(elev=18, azim=-60)
    ax3.set_box_aspect(np.maximum(np.ptp(bounds, axis=0), 0.25 * np.ptp(bounds, axis=0).max()))
    ax3.set_title("overview", fontsize=10)

    zoom = corridor_bounds(bbs, scene)
    along = int(np.argmax(np.abs(corridor_direction(bbs, zoom))))
    across = [a for a in range(3) if a != along]
    tris = triangles_in(scene, zoom, max_triangles=12000)
    for row, (b, away) in enumerate(((across[1], across[0]), (across[0], across[1]))):
        a = along
        ax = fig.add_subplot(grid[row, 1:])
        for n, t in tris:
            t = t[section(t, bbs[-1:], along, away, SECTION_MM)]
            ax.add_collection(PolyCollection(t[:, :, [a, b]], facecolor=colour[n], edgecolor="none",
                                             alpha=0.25))
        for j, i in enumerate(pick):
            c = cmap(j / max(1, len(pick) - 1))
            ax.plot(bbs[i, :, a], bbs[i, :, b], color=c, lw=2.5 if i in (pick[0], pick[-1]) else 1.0)
        if tip_path is not None:
            ax.plot(tip_path[:, a], tip_path[:, b], "k-", lw=0.6)
        _target_2d(ax, scene, a, b)
        ax.set_xlim(zoom[:, a])
        ax.set_ylim(zoom[:, b])
        ax.set_aspect("equal")
        ax.set_xlabel(axis_title(a))
        ax.set_ylabel(axis_title(b))
        ax.set_title(f"{view_name(scene.anatomy, 'xyz'[away])} ({'xyz'[a]}-{'xyz'[b]}): obstacles within "
                     f"{SECTION_MM:g} mm of the final path in {'xyz'[away]}", fontsize=10)
    handles = [Patch(color=colour[n], alpha=0.5) for n in names]
    handles += [Patch(facecolor=TARGET_COLOR, edgecolor="k", alpha=0.8),
                plt.Line2D([], [], color="k", lw=0.8), plt.Line2D([], [], color=cmap(0.0), lw=2.5),
                plt.Line2D([], [], color=cmap(1.0), lw=2.5)]
    labels_ = [*names, "target", "tip trace", "start", "end"]
    fig.legend(handles, labels_, loc="lower center", ncol=min(ncol, len(labels_)), fontsize=7, frameon=False)
    fig.suptitle(title or f"{scene.name}: planned path ({k} states)", fontsize=11)
    return fig


def _ellipsoid_points(scene: Scene, n: int = 24) -> np.ndarray:
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, n), np.linspace(0, np.pi, n // 2))
    p = np.stack([np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v)], -1) * scene.target.semi_axes
    return p @ scene.target.rotation.T + scene.target.center


def _target_3d(ax, scene: Scene) -> None:
    p = _ellipsoid_points(scene)
    ax.plot_surface(p[..., 0], p[..., 1], p[..., 2], color=TARGET_COLOR, alpha=0.7, lw=0)
    c = scene.target.center
    ax.text(c[0], c[1], c[2] + 1.5 * scene.target.semi_axes.max(), "target", color="k", fontsize=8)


def _target_2d(ax, scene: Scene, a: int, b: int) -> None:
    p = _ellipsoid_points(scene, 48).reshape(-1, 3)
    from scipy.spatial import ConvexHull

    pts = p[:, [a, b]]
    hull = ConvexHull(pts)
    poly = pts[hull.vertices]
    ax.fill(poly[:, 0], poly[:, 1], facecolor=TARGET_COLOR, edgecolor="k", alpha=0.75, lw=1.2, zorder=5)
    top = poly[np.argmax(poly[:, 1])]
    ax.annotate("target", top, xytext=(0, 8), textcoords="offset points", ha="center", fontsize=8,
                zorder=6)
