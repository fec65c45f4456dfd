"""The paper's PINN figures: 3-D shapes (Fig. 4), error band along the backbone (Fig. 5) and the
states along arc length for one configuration (Fig. 6), each PINN against the exact solver."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ctrplan.viz.style import pyplot, write_png

if TYPE_CHECKING:
    from ctrplan.training.evaluate import Comparison


def shapes_figure(cmp: Comparison, path: Path, count: int = 12) -> Path:
    """3-D backbones of ``count`` configurations: exact (solid) vs PINN (dashed), mm."""
    plt = pyplot()
    fig = plt.figure(figsize=(7, 7))
    ax = fig.add_subplot(projection="3d")
    colors = plt.cm.tab20(np.linspace(0, 1, count))
    for i in range(min(count, len(cmp.exact))):
        e, p = cmp.exact.positions_mm[i], cmp.predicted.positions_mm[i]
        ax.plot(e[:, 0], e[:, 1], e[:, 2], "-", color=colors[i], lw=1.5)
        ax.plot(p[:, 0], p[:, 1], p[:, 2], "--", color=colors[i], lw=1.5)
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    ax.set_zlabel("z [mm]")
    ax.set_title("Cosserat (solid) vs PINN (dashed), unseen configurations")
    fig.tight_layout()
    write_png(fig, path, dpi=130)
    return path


def error_band_figure(cmp: Comparison, path: Path) -> Path:
    """Position error / arc length (%) vs s / l1: mean, +-1 std and min-max over configurations."""
    e = cmp.normalised_error_pct
    x = (cmp.exact.s_mm[:, 1:] / cmp.exact.s_mm[:, -1:]).mean(0)
    mean, std = e.mean(0), e.std(0)
    fig, ax = pyplot().subplots(figsize=(7, 4))
    ax.fill_between(x, e.min(0), e.max(0), color="tab:blue", alpha=0.15, label="min-max")
    ax.fill_between(x, np.maximum(mean - std, 0), mean + std, color="tab:blue", alpha=0.35, label="±1 std")
    ax.plot(x, mean, color="tab:blue", lw=2, label="mean")
    ax.set_xlabel("normalised arc length s / l1")
    ax.set_ylabel("position error / s  [%]")
    ax.set_title(f"PINN backbone error, {len(cmp.exact)} unseen configurations "
                 f"(mean {e.mean():.2f} %, max {e.max():.2f} %)")
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    write_png(fig, path, dpi=130)
    return path


def states_figure(cmp: Comparison, path: Path) -> Path:
    """All state groups along s for the first configuration the exact solver solved: exact (solid)
    vs PINN (dashed)."""
    index = int(np.argmax(cmp.solved))
    s = cmp.exact.s_mm[index]
    ex, pr = cmp.exact.state[index], cmp.predicted.state[index]
    n = cmp.exact.n_tubes
    names = cmp.exact.state_names
    groups = [("bending moment m_b [N mm]", range(0, 2), 1.0),
              ("torsional curvature u_z [1/m]", range(2, 2 + n), 1e3),
              ("twist theta [rad]", range(2 + n, 2 + 2 * n), 1.0),
              ("position p [mm]", range(2 + 2 * n, 5 + 2 * n), 1.0),
              ("orientation h", range(5 + 2 * n, 9 + 2 * n), 1.0)]
    fig, axes = pyplot().subplots(len(groups), 1, figsize=(7, 11), sharex=True)
    for ax, (title, idx, scale) in zip(axes, groups, strict=True):
        for k, i in enumerate(idx):
            color = f"C{k}"
            ax.plot(s, ex[:, i] * scale, "-", color=color, lw=1.5, label=names[i])
            ax.plot(s, pr[:, i] * scale, "--", color=color, lw=1.5)
        ax.set_ylabel(title, fontsize=8)
        ax.legend(fontsize=7, ncol=4, loc="best")
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("arc length s [mm]")
    q = cmp.exact.q[index]
    fig.suptitle("States: Cosserat (solid) vs PINN (dashed), q = "
                 + np.array2string(q, precision=2, separator=", "), fontsize=9)
    fig.tight_layout()
    write_png(fig, path, dpi=130)
    return path
