"""The stability verdict as a picture a designer can read (matplotlib, Agg)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ctrplan.stability import StabilityReport


def plot_stability(report: StabilityReport, path: Path) -> Path:
    """Two panels: the stability measure along every rotation sweep (it must stay above 0), and where
    in the domain the flagged configurations lie (relative rotation of the swept tube vs tip arc
    length). Writes ``path`` (PNG) and returns it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2), constrained_layout=True)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    seen: set[int] = set()
    for s in report.sweeps:
        if s.tube == 0:
            continue
        n = s.q.shape[1] // 2
        angle = np.degrees(s.q[:, n + s.tube - 1])
        label = f"tube {s.tube} turned" if s.tube not in seen else None
        seen.add(s.tube)
        ax1.plot(angle, np.clip(s.stability, -1.0, 1.0), color=colours[(s.tube - 1) % len(colours)],
                 lw=0.8, alpha=0.6, label=label)
        bad = s.flagged
        ax1.plot(angle[bad], np.clip(np.nan_to_num(s.stability[bad], nan=-1.0), -1.0, 1.0), "x",
                 color="crimson", ms=4)
    ax1.axhline(0.0, color="black", lw=1)
    ax1.set_xlabel("rotation of the swept tube (deg)")
    ax1.set_ylabel("stability measure (> 0: stable)")
    ax1.set_title("Stability along rotation sweeps (x: flagged)")
    if seen:
        ax1.legend(loc="lower left", fontsize=8)

    rel, arc, flagged = [], [], []
    for s in report.sweeps:
        n = s.q.shape[1] // 2
        t = max(s.tube, 1) - 1
        other = 1 if t == 0 and n > 1 else 0
        rel.append(np.degrees(np.angle(np.exp(1j * (s.q[:, n + t] - s.q[:, n + other])))))
        arc.append(s.q[:, 0])
        flagged.append(s.flagged)
    rel, arc, flagged = np.concatenate(rel), np.concatenate(arc), np.concatenate(flagged)
    ax2.scatter(rel[~flagged], arc[~flagged], s=3, color="0.7", label="stable, single-valued")
    ax2.scatter(rel[flagged], arc[flagged], s=8, color="crimson",
                label="snaps (unstable, jump or two equilibria)")
    ax2.set_xlabel("relative rotation of the swept tube (deg)")
    ax2.set_ylabel("beta1 (mm)")
    share = 100 * report.unstable_fraction
    verdict = "snap-free" if report.snap_free else f"NOT snap-free ({share:.1f} % flagged)"
    ax2.set_title(f"{report.robot}: {verdict}")
    ax2.legend(loc="upper right", fontsize=8)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
