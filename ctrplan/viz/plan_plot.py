"""Static picture of a planned path: the scene and backbones along the path (matplotlib, Agg)."""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ctrplan.scene.objects import Scene
from ctrplan.viz.framing import corridor_bounds, corridor_direction, finite_points
from ctrplan.viz.sections import Section, curved_section, guide_heights
from ctrplan.viz.style import TARGET_COLOR, axis_labels, pyplot, scene_colors, view_name, write_png

#: The overview draws the obstacles' triangles when there are at most this many near the path.
OVERVIEW_TRIANGLES = 6000


def triangles_in(scene: Scene, bounds: np.ndarray, max_triangles: int | None = 6000):
    """(name, triangles (T, 3, 3)) of every obstacle, clipped to triangles touching ``bounds``; thinned
    out uniformly to ``max_triangles`` in all (None: never)."""
    out = [(n, t) for n, t, _ in obstacles_in(scene, bounds)]
    total = sum(len(t) for _, t in out)
    if max_triangles is not None and total > max_triangles:  # thin out uniformly for speed
        step = int(np.ceil(total / max_triangles))
        out = [(n, t[::step]) for n, t in out]
    return out


def obstacles_in(scene: Scene, bounds: np.ndarray) -> list[tuple[str, np.ndarray, bool]]:
    """(name, triangles (T, 3, 3) touching ``bounds``, whether the mesh is closed) of every obstacle
    that reaches into ``bounds``."""
    out = []
    for o in scene.obstacles:
        m = o.to_trimesh()
        tri = np.asarray(m.vertices)[np.asarray(m.faces)]
        keep = np.all((tri.max(axis=1) >= bounds[0]) & (tri.min(axis=1) <= bounds[1]), axis=1)
        if keep.any():
            out.append((o.name, tri[keep], _closed(m)))
    return out


def _closed(mesh) -> bool:
    """Whether ``mesh`` is closed once its coincident vertices are merged (an STL repeats every vertex
    per triangle)."""
    merged = mesh.copy()
    merged.merge_vertices()
    return bool(merged.is_watertight)


def plot_plan(scene: Scene, backbones_scene: np.ndarray, path: str | Path, *, title: str = "",
              tip_path: np.ndarray | None = None, max_backbones: int = 12,
              notes: Sequence[tuple[str, bool]] = (), marks: Sequence[Mark] = ()) -> Path:
    """Write a PNG of `plan_figure` (arguments as there)."""
    path = Path(path)
    fig = plan_figure(scene, backbones_scene, title=title, tip_path=tip_path, max_backbones=max_backbones,
                      notes=notes, marks=marks)
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_png(fig, path, dpi=100)


@dataclass(frozen=True)
class Mark:
    """A structure named on the picture: ``text`` (e.g. its clearance), the robot's point nearest it
    (3,) (scene frame, mm; None: the label goes on the structure's cut), ``warn``: in red, and the
    structure's point nearest the robot (3,), joined to the robot's by a line (the clearance)."""

    structure: str
    text: str
    point: np.ndarray | None = None
    warn: bool = False
    structure_point: np.ndarray | None = None


@dataclass(frozen=True)
class _View:
    """A projection: plot axes ``a`` (the corridor's), ``b``, the hidden axis, and the anatomy's cuts."""

    a: int
    b: int
    hidden: int
    cuts: tuple[Section, ...]


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
    marks: tuple[Mark, ...] = ()

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
                notes: Sequence[tuple[str, bool]] = (), marks: Sequence[Mark] = ()):
    """A matplotlib figure: a 3-D overview plus two projections along the corridor (the scene axis
    closest to its direction runs across both) of backbones along the path (start blue -> end red),
    drawn over the translucent obstacles, the tip trace and the target region (`TARGET_COLOR`,
    outlined and named), and a column of ``notes`` (text, warn: warnings in red) -- the result,
    the reason of a failure, the clearances. A projection shows the anatomy cut by the surface that
    follows the final backbone (then the target) in the axis it projects away -- filled where a mesh is
    closed, outlined where it is a sheet (`ctrplan.viz.sections`); the overview shows the outlines of
    both projections' cuts in 3-D over the obstacles near the path (translucent, where they have
    few enough triangles to draw whole). ``marks`` name structures: at the robot's point nearest them
    (with their clearance), or on their cut. Axes are named with the scene's patient
    directions when it gives them; the legend names every obstacle; touching obstacles get
    distinguishable colours (`scene_colors`).

    ``backbones_scene`` (K, N, 3): backbones along the path in the scene frame (mm); ``tip_path``
    (M, 3): the tip along the path (mm).
    """
    plt = pyplot()
    bbs = np.asarray(backbones_scene, dtype=float)
    k = bbs.shape[0]
    pick = np.unique(np.linspace(0, k - 1, min(k, max_backbones)).round().astype(int))
    d = _Drawing(scene, bbs, pick, tip_path, scene_colors(scene.obstacles), plt.get_cmap("coolwarm"),
                 tuple(marks))
    names = [o.name for o in scene.obstacles]
    ncol = 8
    legend_rows = -(-(len(names) + 4) // ncol)
    bottom = 0.08 + 0.025 * legend_rows
    fig = plt.figure(figsize=(18, 8.0 + 0.2 * legend_rows), dpi=100)
    grid = fig.add_gridspec(2, 4, width_ratios=(1.0, 1.0, 1.0, 0.85), hspace=0.35, wspace=0.25, left=0.02,
                            right=0.99, top=0.92, bottom=bottom)
    zoom = corridor_bounds(bbs, scene)
    views = _views(d, zoom)
    _overview(fig.add_subplot(grid[:, 0], projection="3d"), d, views, zoom)
    _projections(fig, grid, d, views, zoom)
    _notes(fig.add_subplot(grid[:, 3]), notes)
    _legend(fig, d, names, ncol)
    fig.suptitle(title or f"{scene.name}: planned path ({k} states)", fontsize=11)
    return fig


def _overview(ax3, d: _Drawing, views: list[_View], bounds: np.ndarray) -> None:
    """The 3-D overview of the corridor (``bounds`` (2, 3): where the robot meets the anatomy, and the
    target): the outlines of the ``views``' cuts (the anatomy along the path), the obstacles there
    (translucent, a face plate faint; none when they have more than `OVERVIEW_TRIANGLES`, which
    thinned would be dots), the backbones on top (cut at the bounds), the marks."""
    from matplotlib.ticker import MaxNLocator
    from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

    ax3.computed_zorder = False  # drawn in zorder: the backbones over the translucent obstacles
    tris = triangles_in(d.scene, bounds, max_triangles=None)
    for n, t in tris if sum(len(t) for _, t in tris) <= OVERVIEW_TRIANGLES else ():
        backdrop = np.ptp(t.reshape(-1, 3), axis=0).max() > 0.8 * np.ptp(bounds, axis=0).max()  # a face plate
        ax3.add_collection3d(Poly3DCollection(t, facecolor=d.colour[n], edgecolor="none",
                                              alpha=0.04 if backdrop else 0.16, zorder=1))
    for view in views:
        _cuts_3d(ax3, d, view, bounds)
    shown = np.where(np.all((d.bbs >= bounds[0]) & (d.bbs <= bounds[1]), axis=-1)[..., None], d.bbs, np.nan)
    for j in range(len(d.pick)):
        d.backbone(ax3, j, shown[d.pick[j]].T)
    for m in d.marks:
        if m.point is not None:
            ax3.scatter(*m.point, color="#c0001a" if m.warn else "k", s=18, zorder=8)
            ax3.text(*m.point, f"  {m.structure}", fontsize=7, color="#c0001a" if m.warn else "k", zorder=8)
    if d.tip_path is not None:
        tip = np.where(np.all((d.tip_path >= bounds[0]) & (d.tip_path <= bounds[1]), axis=-1)[:, None],
                       d.tip_path, np.nan)
        ax3.add_collection3d(Line3DCollection([tip], colors="k", linewidths=0.6, zorder=6))
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


def _views(d: _Drawing, zoom: np.ndarray) -> list[_View]:
    """The two projections along the corridor and the anatomy's cuts along the path in each."""
    along = int(np.argmax(np.abs(corridor_direction(d.bbs, zoom))))
    across = [a for a in range(3) if a != along]
    depth = np.full((2, 3), np.inf) * [[-1.0], [1.0]]
    depth[:, along] = zoom[:, along]
    solids = obstacles_in(d.scene, depth)  # whole across the corridor: a closed mesh's cut stays closed
    guide = np.concatenate([finite_points(d.bbs[-1:]), d.scene.target.center[None]])
    views = []
    for b, away in ((across[1], across[0]), (across[0], across[1])):
        cuts = tuple(curved_section(n, t, closed, guide, along, b, away, (zoom[0, along], zoom[1, along]))
                     for n, t, closed in solids)
        views.append(_View(along, b, away, cuts))
    return views


def _projections(fig, grid, d: _Drawing, views: list[_View], zoom: np.ndarray) -> None:
    """Two projections along the corridor, each with the anatomy cut along the path, and the marks."""
    for row, v in enumerate(views):
        a, b = v.a, v.b
        ax = fig.add_subplot(grid[row, 1:3])
        _draw_sections(ax, v.cuts, d.colour)
        for j in range(len(d.pick)):
            d.backbone(ax, j, (d.bbs[d.pick[j], :, a], d.bbs[d.pick[j], :, b]))
        if d.tip_path is not None:
            ax.plot(d.tip_path[:, a], d.tip_path[:, b], "k-", lw=0.6, zorder=6)
        _target_2d(ax, d.scene, a, b)
        ax.set_xlim(zoom[:, a])
        ax.set_ylim(zoom[:, b])
        _marks_2d(ax, d.marks, {c.name: c for c in v.cuts}, a, b)
        ax.set_aspect("equal")
        ax.set_xlabel(d.axis_title(a))
        ax.set_ylabel(d.axis_title(b))
        h = "xyz"[v.hidden]
        ax.set_title(f"{view_name(d.scene.anatomy, h)} ({'xyz'[a]}-{'xyz'[b]}): the anatomy cut along the "
                     f"path ({h} follows it)", fontsize=10)


def _marks_2d(ax, marks: Sequence[Mark], cuts: dict[str, Section], a: int, b: int) -> None:
    """Each mark: a dot at the robot's point (or on the structure's cut), the line to the structure's,
    and its text, stacked in the top corner on the mark's side (labels never overlap) with a line to
    the dot. The axes' limits must be set."""
    (x0, x1), stacked = ax.get_xlim(), {False: 0, True: 0}
    for m in marks:
        if m.point is not None:
            at = np.asarray(m.point)[[a, b]]
        elif m.structure in cuts and not cuts[m.structure].empty:
            at = cuts[m.structure].centre()
        else:
            continue
        colour = "#c0001a" if m.warn else "k"
        if m.structure_point is not None:
            to = np.asarray(m.structure_point)[[a, b]]
            ax.plot([at[0], to[0]], [at[1], to[1]], "-", color=colour, lw=1.2, zorder=9)
            ax.plot(*to, "s", color=colour, ms=3.5, zorder=9)
        ax.plot(*at, "o", color=colour, ms=5, zorder=9, markeredgecolor="white")
        right = bool((at[0] - x0) / (x1 - x0) > 0.5)
        ax.annotate(m.text, at, xytext=(0.99 if right else 0.01, 0.97 - 0.09 * stacked[right]),
                    textcoords="axes fraction", va="top", ha="right" if right else "left", fontsize=8,
                    color=colour, zorder=9, arrowprops={"arrowstyle": "-", "color": colour, "lw": 0.8},
                    bbox={"boxstyle": "round,pad=0.2", "facecolor": "white", "edgecolor": colour, "lw": 0.6,
                          "alpha": 0.9})
        stacked[right] += 1


def _cuts_3d(ax3, d: _Drawing, view: _View, bounds: np.ndarray) -> None:
    """The outlines of ``view``'s cuts within ``bounds`` in 3-D: each point back on its cutting plane."""
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    guide = np.concatenate([finite_points(d.bbs[-1:]), d.scene.target.center[None]])
    for c in view.cuts:
        if c.empty:
            continue
        seg = np.zeros(c.segments.shape[:2] + (3,))
        seg[..., view.a], seg[..., view.b] = c.segments[..., 0], c.segments[..., 1]
        seg[..., view.hidden] = guide_heights(guide, view.a, view.hidden, c.segments[..., 0].ravel()).reshape(
            c.segments.shape[:2])
        seg = seg[np.all((seg >= bounds[0]) & (seg <= bounds[1]), axis=(1, 2))]
        if not len(seg):
            continue
        ax3.add_collection3d(Line3DCollection(seg, colors=[_outline(d.colour[c.name])], linewidths=1.0,
                                              zorder=2))


def _outline(colour: str) -> tuple[float, float, float]:
    """A structure's colour as its cut's outline: as saturated as it is, darkened a little (pale ones
    most) so that a wall reads against the white page."""
    from matplotlib.colors import hsv_to_rgb, rgb_to_hsv, to_rgb

    h, s, v = rgb_to_hsv(to_rgb(colour))
    return tuple(hsv_to_rgb((h, min(1.0, 0.35 + 1.2 * s), 0.75 * v)))


def _draw_sections(ax, cuts: Sequence[Section], colour: dict[str, str]) -> None:
    """Each structure's cut: its inside filled, its outline solid and darker."""
    from matplotlib.collections import LineCollection, PolyCollection

    for c in cuts:
        if c.empty:
            continue
        if len(c.fills):
            a0, a1, c0, c1 = c.fills.T
            boxes = np.stack([np.stack([a0, c0], 1), np.stack([a1, c0], 1), np.stack([a1, c1], 1),
                              np.stack([a0, c1], 1)], axis=1)
            ax.add_collection(PolyCollection(boxes, facecolor=colour[c.name], edgecolor=colour[c.name],
                                             linewidth=0.3, alpha=0.75, zorder=2))
        ax.add_collection(LineCollection(c.segments, colors=[_outline(colour[c.name])], linewidths=2.0,
                                         zorder=3))


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
