"""The stability verdict as a picture a designer can read (PNG)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ctrplan.viz.style import pyplot, write_png

if TYPE_CHECKING:
    from ctrplan.kinematics.stability import StabilityReport


def _relative_rotation_deg(sweep) -> np.ndarray:
    """Rotation of the swept tube relative to its inner neighbour (tube 1: to tube 2), wrapped to
    [-180, 180) deg, for every configuration of the sweep (K,)."""
    n = sweep.q.shape[1] // 2
    t = max(sweep.tube, 1) - 1
    other = t - 1 if t > 0 else min(1, n - 1)
    return np.degrees(np.angle(np.exp(1j * (sweep.q[:, n + t] - sweep.q[:, n + other]))))


def plot_stability(report: StabilityReport, path: Path) -> Path:
    """Two panels over the relative rotation of the swept tube: the stability measure along every
    sweep (it must stay above 0; x marks flagged configurations), and the share of configurations
    flagged per 10 deg -- where the robot snaps. Writes ``path`` (PNG) and returns it."""
    plt = pyplot()
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2), constrained_layout=True)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    seen: set[int] = set()
    rel_all, flag_all = [], []
    for s in report.sweeps:
        rel = _relative_rotation_deg(s)
        rel_all.append(rel)
        flag_all.append(s.flagged)
        order = np.argsort(rel)
        label = f"tube {s.tube} turned" if s.tube not in seen else None
        seen.add(s.tube)
        colour = colours[(max(s.tube, 1) - 1) % len(colours)]
        ax1.plot(rel[order], np.clip(s.stability[order], -1.0, 1.0), color=colour, lw=0.8, alpha=0.6,
                 label=label)
        bad = s.flagged
        ax1.plot(rel[bad], np.clip(np.nan_to_num(s.stability[bad], nan=-1.0), -1.0, 1.0), "x",
                 color="crimson", ms=4)
    ax1.axhline(0.0, color="black", lw=1)
    ax1.set_xlim(-180, 180)
    ax1.set_xlabel("relative rotation of the swept tube (deg)")
    ax1.set_ylabel("stability measure (> 0: stable)")
    ax1.set_title("Stability along rotation sweeps (x: flagged)")
    ax1.legend(loc="lower left", fontsize=8)

    rel, flagged = np.concatenate(rel_all), np.concatenate(flag_all)
    bins = np.linspace(-180, 180, 37)
    total, _ = np.histogram(rel, bins)
    bad, _ = np.histogram(rel[flagged], bins)
    share = np.divide(bad, total, out=np.zeros(len(total)), where=total > 0)
    ax2.bar(0.5 * (bins[1:] + bins[:-1]), 100 * share, width=9.0, color="crimson")
    ax2.set_xlim(-180, 180)
    ax2.set_ylim(0, max(5.0, 100 * share.max() * 1.15))
    ax2.set_xlabel("relative rotation of the swept tube (deg)")
    ax2.set_ylabel("configurations flagged (%)")
    pct = 100 * report.unstable_fraction
    verdict = "snap-free" if report.snap_free else f"NOT snap-free ({pct:.1f} % flagged)"
    ax2.set_title(f"{report.robot}: {verdict}\n({report.checked} configurations checked)")
    write_png(fig, path, dpi=110)
    return path
