"""Static picture of a planned path: the scene and backbones along the path (matplotlib, Agg)."""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ctrplan.scene.objects import Scene
from ctrplan.viz.framing import corridor_bounds, corridor_direction, section
from ctrplan.viz.style import TARGET_COLOR, axis_labels, pyplot, scene_colors, view_name, write_png

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
              tip_path: np.ndarray | None = None, max_backbones: int = 12,
              notes: Sequence[tuple[str, bool]] = ()) -> Path:
    """Write a PNG of `plan_figure` (arguments as there)."""
    path = Path(path)
    fig = plan_figure(scene, backbones_scene, title=title, tip_path=tip_path, max_backbones=max_backbones,
                      notes=notes)
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_png(fig, path, dpi=100)


@dataclass(frozen=True)
class _Drawing:
    """What every panel of `plan_figure` draws: the scene, backbones (K, N, 3) and which of them
    (``pick``), the tip trace, obstacle colours, the path's colour map and the axis titles."""

    scene: Scene
    bbs: np.ndarray
    pick: np.ndarray
    tip_path: np.ndarray | None
    colour: dict[str, str]
    cmap: Any

    def backbone(self, ax, j: int, coords: Sequence[np.ndarray]) -> None:
        """Backbone ``pick[j]`` over everything (obstacles are translucent and below it), with a
        white halo so that it reads as in front of them; start and end thick."""
        import matplotlib.patheffects as pe

        i = self.pick[j]
        lw = 2.5 if i in (self.pick[0], self.pick[-1]) else 1.0
        c = self.cmap(j / max(1, len(self.pick) - 1))
        ax.plot(*coords, color=c, lw=lw, zorder=4 + j / len(self.pick),
                path_effects=[pe.Stroke(linewidth=lw + 2.0, foreground="white"), pe.Normal()])

    def axis_title(self, a: int) -> str:
        ax = "xyz"[a]
        labels = axis_labels(self.scene.anatomy)
        return f"{ax} (mm): {labels[ax][1]} to {labels[ax][0]}" if self.scene.anatomy else f"{ax} (mm)"


def plan_figure(scene: Scene, backbones_scene: np.ndarray, *, title: str = "",
                tip_path: np.ndarray | None = None, max_backbones: int = 12,
                notes: Sequence[tuple[str, bool]] = ()):
    """A matplotlib figure: a 3-D overview plus two projections along the corridor (the scene axis
    closest to its direction runs across both) of backbones along the path (start blue -> end red),
    drawn over the translucent obstacles, the tip trace and the target region (`TARGET_COLOR`,
    outlined and named), and a column of ``notes`` (text, warn: warnings in red) -- the result,
    the reason of a failure, the clearances. A projection shows only the obstacles within
    `SECTION_MM` of the final backbone in the axis it projects away (a section along the corridor:
    what lies beside the path is not drawn over it). Axes are named with the scene's patient
    directions when it gives them; the legend names every obstacle; touching obstacles get
    distinguishable colours (`scene_colors`).

    ``backbones_scene`` (K, N, 3): backbones along the path in the scene frame (mm); ``tip_path``
    (M, 3): the tip along the path (mm).
    """
    plt = pyplot()
    bbs = np.asarray(backbones_scene, dtype=float)
    k = bbs.shape[0]
    pick = np.unique(np.linspace(0, k - 1, min(k, max_backbones)).round().astype(int))
    d = _Drawing(scene, bbs, pick, tip_path, scene_colors(scene.obstacles), plt.get_cmap("coolwarm"))
    names = [o.name for o in scene.obstacles]
    ncol = 8
    legend_rows = -(-(len(names) + 4) // ncol)
    bottom = 0.08 + 0.025 * legend_rows
    fig = plt.figure(figsize=(18, 8.0 + 0.2 * legend_rows), dpi=100)
    grid = fig.add_gridspec(2, 4, width_ratios=(1.0, 1.0, 1.0, 0.85), hspace=0.35, wspace=0.25, left=0.02,
                            right=0.99, top=0.92, bottom=bottom)
    _overview(fig.add_subplot(grid[:, 0], projection="3d"), d)
    _projections(fig, grid, d)
    _notes(fig.add_subplot(grid[:, 3]), notes)
    _legend(fig, d, names, ncol)
    fig.suptitle(title or f"{scene.name}: planned path ({k} states)", fontsize=11)
    return fig


def _overview(ax3, d: _Drawing) -> None:
    """The 3-D overview: obstacles near the path (a face plate faint), backbones on top."""
    from matplotlib.ticker import MaxNLocator
    from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

    bounds = _view_bounds(d.bbs, d.scene)
    ax3.computed_zorder = False  # drawn in zorder: the backbones over the translucent obstacles
    for n, t in triangles_in(d.scene, bounds):
        backdrop = np.ptp(t.reshape(-1, 3), axis=0).max() > 0.8 * np.ptp(bounds, axis=0).max()  # a face plate
        ax3.add_collection3d(Poly3DCollection(t, facecolor=d.colour[n], edgecolor="none",
                                              alpha=0.04 if backdrop else 0.13, zorder=1))
    for j in range(len(d.pick)):
        d.backbone(ax3, j, d.bbs[d.pick[j]].T)
    if d.tip_path is not None:
        ax3.add_collection3d(Line3DCollection([d.tip_path], colors="k", linewidths=0.6, zorder=6))
    _target_3d(ax3, d.scene)
    ax3.set_xlim(bounds[:, 0])
    ax3.set_ylim(bounds[:, 1])
    ax3.set_zlim(bounds[:, 2])
    for axis in (ax3.xaxis, ax3.yaxis, ax3.zaxis):  # few, small ticks: labels must not overlap
        axis.set_major_locator(MaxNLocator(4))
    ax3.tick_params(labelsize=7, pad=1)
    for a, set_label in enumerate((ax3.set_xlabel, ax3.set_ylabel, ax3.set_zlabel)):
        set_label(d.axis_title(a), fontsize=8, labelpad=2)
    ax3.view_init(elev=18, azim=-60)
    ax3.set_box_aspect(np.maximum(np.ptp(bounds, axis=0), 0.25 * np.ptp(bounds, axis=0).max()))
    ax3.set_title("overview", fontsize=10)


def _projections(fig, grid, d: _Drawing) -> None:
    """Two projections along the corridor, each with the obstacles of its section."""
    from matplotlib.collections import PolyCollection

    zoom = corridor_bounds(d.bbs, d.scene)
    along = int(np.argmax(np.abs(corridor_direction(d.bbs, zoom))))
    across = [a for a in range(3) if a != along]
    tris = triangles_in(d.scene, zoom, max_triangles=12000)
    a = along
    for row, (b, away) in enumerate(((across[1], across[0]), (across[0], across[1]))):
        ax = fig.add_subplot(grid[row, 1:3])
        for n, t in tris:
            t = t[section(t, d.bbs[-1:], along, away, SECTION_MM)]
            ax.add_collection(PolyCollection(t[:, :, [a, b]], facecolor=d.colour[n], edgecolor="none",
                                             alpha=0.3, zorder=1))
        for j in range(len(d.pick)):
            d.backbone(ax, j, (d.bbs[d.pick[j], :, a], d.bbs[d.pick[j], :, b]))
        if d.tip_path is not None:
            ax.plot(d.tip_path[:, a], d.tip_path[:, b], "k-", lw=0.6, zorder=6)
        _target_2d(ax, d.scene, a, b)
        ax.set_xlim(zoom[:, a])
        ax.set_ylim(zoom[:, b])
        ax.set_aspect("equal")
        ax.set_xlabel(d.axis_title(a))
        ax.set_ylabel(d.axis_title(b))
        ax.set_title(f"{view_name(d.scene.anatomy, 'xyz'[away])} ({'xyz'[a]}-{'xyz'[b]}): obstacles "
                     f"within {SECTION_MM:g} mm of the final path in {'xyz'[away]}", fontsize=10)


def _notes(ax, notes: Sequence[tuple[str, bool]], width: int = 52) -> None:
    """The notes as wrapped lines (fixed width: tables stay aligned) from the top of an empty panel;
    warnings in red."""
    ax.axis("off")
    y = 1.0
    for text, warn in notes:
        for line in textwrap.wrap(text, width, subsequent_indent="  ") or [""]:
            ax.text(0.0, y, line, transform=ax.transAxes, va="top", fontsize=7, family="monospace",
                    color="#c0001a" if warn else "#222", fontweight="bold" if warn else "normal")
            y -= 0.024


def _legend(fig, d: _Drawing, names: list[str], ncol: int) -> None:
    from matplotlib.patches import Patch

    plt = pyplot()
    handles = [Patch(color=d.colour[n], alpha=0.6) for n in names]
    handles += [Patch(facecolor=TARGET_COLOR, edgecolor="k", alpha=0.8),
                plt.Line2D([], [], color="k", lw=0.8), plt.Line2D([], [], color=d.cmap(0.0), lw=2.5),
                plt.Line2D([], [], color=d.cmap(1.0), lw=2.5)]
    labels = [*names, "target", "tip trace", "start", "end"]
    fig.legend(handles, labels, loc="lower center", ncol=min(ncol, len(labels)), fontsize=7, frameon=False)


def _ellipsoid_points(scene: Scene, n: int = 24) -> np.ndarray:
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, n), np.linspace(0, np.pi, n // 2))
    p = np.stack([np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v)], -1) * scene.target.semi_axes
    return p @ scene.target.rotation.T + scene.target.center


def _target_3d(ax, scene: Scene) -> None:
    p = _ellipsoid_points(scene)
    ax.plot_surface(p[..., 0], p[..., 1], p[..., 2], color=TARGET_COLOR, alpha=0.7, lw=0, zorder=3)
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
