"""Benchmark figures of the records and summaries of `ctrplan.bench` (PNG): per-call times, planning
times with success rates and the time split, roadmap query times."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from ctrplan.bench.roadmap import ROADMAP_PLANNER
from ctrplan.viz.style import write_png


def timing_boxplot(series: Mapping[tuple[str, int], np.ndarray], path: str | Path, *,
                   title: str, group_name: str = "backbone points") -> None:
    """Box plot (log y) of per-call times (ms): one box per (label, group) key of ``series``.

    Boxes are grouped along x by the group value (e.g. number of points), one colour per label;
    whiskers span the 1st-99th percentile, calls beyond them are dots.
    """
    labels = list(dict.fromkeys(label for label, _ in series))
    groups = sorted({group for _, group in series})
    width = 0.8 / len(labels)
    colours = [f"C{i}" for i in range(len(labels))]
    fig = Figure(figsize=(max(6.0, 1.6 * len(groups) * len(labels) ** 0.5), 4.5))
    ax = fig.add_subplot()
    for i, label in enumerate(labels):
        keys = [(label, g) for g in groups if (label, g) in series]
        where = [groups.index(g) + (i - (len(labels) - 1) / 2) * width for _, g in keys]
        ax.boxplot([series[k] for k in keys], positions=where, widths=0.9 * width, whis=(1, 99),
                   patch_artist=True, boxprops={"facecolor": colours[i], "alpha": 0.6},
                   medianprops={"color": "black"}, flierprops={"markersize": 1.5, "alpha": 0.4})
        ax.plot([], [], "s", color=colours[i], alpha=0.6, label=label)
    ax.set_xticks(range(len(groups)), [str(g) for g in groups])
    ax.set_xlabel(group_name)
    ax.set_yscale("log")
    ax.set_ylabel("time per call (ms)")
    ax.set_title(title)
    ax.grid(axis="y", which="both", alpha=0.3)
    ax.legend(loc="best", fontsize="small")
    fig.tight_layout()
    write_png(fig, path, dpi=150)


def planning_plots(summary: list[dict], records: list[dict], out: Path) -> list[Path]:
    """``planning_times.png`` (per scene: planning time of every run per planner and backend, success
    rate above) and ``time_split.png`` (mean seconds in kinematics / collision / planner)."""
    scenes = list(dict.fromkeys(s["scene"] for s in summary))
    backends = list(dict.fromkeys(s["backend"] for s in summary))
    planners = list(dict.fromkeys(s["planner"] for s in summary))
    width = 0.8 / len(backends)
    fig = Figure(figsize=(max(6.0, 2.2 * len(planners)) * len(scenes) ** 0.5 + 1, 4.2 * len(scenes)))
    for k, scene in enumerate(scenes):
        ax = fig.add_subplot(len(scenes), 1, k + 1)
        for i, backend in enumerate(backends):
            for j, planner in enumerate(planners):
                rs = [r for r in records if (r["scene_name"], r["backend"], r["planner"])
                      == (scene, backend, planner)]
                if not rs:
                    continue
                x = j + (i - (len(backends) - 1) / 2) * width
                times = np.array([r["planning_time_s"] for r in rs])
                ok = np.array([r["solved"] for r in rs])
                ax.boxplot([times], positions=[x], widths=0.85 * width, whis=(0, 100), showfliers=False,
                           patch_artist=True, boxprops={"facecolor": f"C{i}", "alpha": 0.35},
                           medianprops={"color": "black"})
                jitter = x + (np.linspace(-0.3, 0.3, len(rs)) * width)
                ax.scatter(jitter[ok], times[ok], s=9, color=f"C{i}", zorder=3)
                ax.scatter(jitter[~ok], times[~ok], s=22, marker="x", color="red", zorder=3)
                ax.annotate(f"{ok.mean():.0%}", (x, times.max()), textcoords="offset points",
                            xytext=(0, 4), ha="center", fontsize=7)
        for i, backend in enumerate(backends):
            ax.plot([], [], "s", color=f"C{i}", alpha=0.6, label=backend)
        ax.plot([], [], "x", color="red", label="not solved")
        ax.set_xticks(range(len(planners)), planners)
        ax.set_yscale("log")
        ax.set_ylabel("planning time (s)")
        ax.set_title(f"{scene}: planning time per run (success rate above)")
        ax.grid(axis="y", which="both", alpha=0.3)
        ax.legend(fontsize="small", loc="lower right")
    fig.tight_layout()
    paths = [out / "planning_times.png", out / "time_split.png"]
    write_png(fig, paths[0], dpi=130)

    labels = [f"{s['scene']} | {s['planner']} | {s['backend']}" for s in summary]
    fig = Figure(figsize=(8.0, 1.2 + 0.28 * len(summary)))
    ax = fig.add_subplot()
    left = np.zeros(len(summary))
    for i, part in enumerate(("kinematics", "collision", "planner")):
        widths = np.array([s["time_split_s"][part] for s in summary])
        ax.barh(range(len(summary)), widths, left=left, color=f"C{i}", label=part)
        left += widths
    ax.set_yticks(range(len(summary)), labels, fontsize=7)
    ax.invert_yaxis()
    ax.set_xlabel("mean seconds per run")
    ax.set_title("Where planning time goes (mean per run)")
    ax.legend(fontsize="small", loc="lower right")
    ax.grid(axis="x", alpha=0.3)
    fig.tight_layout()
    write_png(fig, paths[1], dpi=130)
    return paths


def roadmap_times_figure(records: list[dict[str, Any]], path: Path) -> None:
    """Box plot (log scale) of roadmap query, roadmap exact validation and single-query planning times
    of `ctrplan bench roadmap`'s records (`ctrplan.bench.roadmap`)."""
    road = [r for r in records if r["planner"] == ROADMAP_PLANNER]
    single = [r for r in records if r["planner"] == "rrtconnect"]
    validated = [r["validation_s"] for r in road if r["solved"]]
    scene = road[0]["scene_name"]
    series = {("roadmap query", scene): np.array([r["planning_time_s"] for r in road]) * 1e3,
              ("roadmap exact validation", scene): np.array(validated) * 1e3}
    if single:
        series["single-query RRTConnect", scene] = np.array([r["planning_time_s"] for r in single]) * 1e3
    timing_boxplot({k: v for k, v in series.items() if len(v)}, path,
                   title=f"{len(road)} random targets in the target region (tolerance "
                         f"{road[0]['tolerance_mm']:g} mm)", group_name="scene")
