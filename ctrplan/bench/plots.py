"""Benchmark figures (matplotlib, no display needed), written atomically as PNG."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from ctrplan.dataio import atomic_write


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
    with atomic_write(path, "wb") as fh:
        fig.savefig(fh, format="png", dpi=150)
