"""Residual plots of a `ctrplan.calibration.Diagnosis` (PNG files; `ctrplan diagnose --out` writes
them after the diagnosis' own outputs).

* ``residual_vs_joints.png``  -- tube-1 tip error against each joint, nominal vs extended;
* ``residual_vs_direction.png`` -- per joint, the joint change that best explains each row's residual,
  split by the direction of the latest motion (a backlash shows as two separated groups);
* ``residual_direction.png``  -- tube-1 residual vectors in the robot frame (three projections);
* ``before_after.png``        -- held-out error per tube before and after (the README figure);
* ``candidates.png``          -- every candidate's BIC change and held-out error.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ctrplan.base.dataio import joint_names
from ctrplan.viz.style import EXTENDED_COLOR, NOMINAL_COLOR, TUBE_COLORS, pyplot, write_png


def _save(fig, path: Path) -> Path:
    return write_png(fig, path, dpi=110, bbox_inches="tight")


def _joint_axis(j: int, q: np.ndarray) -> tuple[np.ndarray, str]:
    names = joint_names(q.shape[1] // 2)
    if j < len(names) // 2:
        return q[:, j], f"{names[j]} (mm)"
    return np.degrees(q[:, j]), f"{names[j]} (deg)"


def _binned(x: np.ndarray, y: np.ndarray, bins: int = 10) -> tuple[np.ndarray, np.ndarray]:
    edges = np.quantile(x, np.linspace(0, 1, bins + 1))
    idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, bins - 1)
    xs, ys = [], []
    for b in range(bins):
        m = idx == b
        if m.sum() >= 2:
            xs.append(np.median(x[m]))
            ys.append(np.median(y[m]))
    return np.array(xs), np.array(ys)


def _title(diag) -> str:
    cause = " + ".join(diag.causes) if diag.causes else "none"
    return f"{Path(diag.data.source).name}: cause {cause}"


def plot_residual_vs_joints(diag, path: Path) -> Path:
    plt = pyplot()
    rows = np.setdiff1d(np.arange(len(diag.data)), diag.unsolved)
    q = diag.data.q[rows]
    e0 = diag.errors("nominal")[rows, 0]
    e1 = diag.errors("extended")[rows, 0]
    n = q.shape[1] // 2
    fig, axes = plt.subplots(2, n, figsize=(4.4 * n, 7), sharey=True, squeeze=False)
    for j, ax in enumerate(axes.ravel()):
        x, label = _joint_axis(j, q)
        ax.scatter(x, e0, s=6, color=NOMINAL_COLOR, label="nominal")
        bx, by = _binned(x, e0)
        ax.plot(bx, by, color="k", lw=1.5, label="nominal, binned median")
        if diag.chosen is not None:
            ax.scatter(x, e1, s=6, color=EXTENDED_COLOR, label="extended")
            bx, by = _binned(x, e1)
            ax.plot(bx, by, color=EXTENDED_COLOR, lw=1.5)
        ax.set_xlabel(label)
        if j % n == 0:
            ax.set_ylabel("tube-1 tip error (mm)")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(f"{_title(diag)} -- tip error against each joint (all rows)")
    fig.tight_layout()
    return _save(fig, path)


def _explaining_change(diag, which: str) -> np.ndarray:
    """Per row and joint, the joint change (mm or rad) that best explains the residual (R, 2N)."""
    sens = diag.sensitivity
    res = diag.residuals(which)
    t = list(diag.data.tubes)
    nj = sens.shape[1]
    out = np.full((len(res), nj), np.nan)
    r = res[:, t, :].reshape(len(res), -1)
    for j in range(nj):
        s = sens[:, j, t, :].reshape(len(res), -1)
        ss = (s * s).sum(1)
        ok = np.isfinite(r).all(1) & np.isfinite(s).all(1) & (ss > 1e-12)
        out[ok, j] = (r[ok] * s[ok]).sum(1) / ss[ok]
    return out


def plot_residual_vs_direction(diag, path: Path) -> Path:
    plt = pyplot()
    rows = np.setdiff1d(np.arange(len(diag.data)), diag.unsolved)
    c0 = _explaining_change(diag, "nominal")[rows]
    c1 = _explaining_change(diag, "extended")[rows] if diag.chosen is not None else None
    d = diag.direction[rows]
    n = d.shape[1] // 2
    fig, axes = plt.subplots(2, n, figsize=(4.4 * n, 7), squeeze=False)
    for j, ax in enumerate(axes.ravel()):
        conv = 1.0 if j < n else 180.0 / np.pi
        unit = "mm" if j < n else "deg"
        data, labels, colors = [], [], []
        for sign, name in ((-1, "-"), (1, "+")):
            m = (d[:, j] == sign) & np.isfinite(c0[:, j])
            data.append(c0[m, j] * conv)
            labels.append(f"nominal\nmoved {name}")
            colors.append(NOMINAL_COLOR)
            if c1 is not None:
                data.append(c1[m, j] * conv)
                labels.append(f"extended\nmoved {name}")
                colors.append(EXTENDED_COLOR)
        data = [v if v.size else np.array([np.nan]) for v in data]
        bp = ax.boxplot(data, patch_artist=True, showfliers=False, widths=0.6)
        for patch, col in zip(bp["boxes"], colors, strict=True):
            patch.set_facecolor(col)
        ax.set_xticks(range(1, len(labels) + 1), labels, fontsize=7)
        ax.axhline(0.0, color="k", lw=0.8)
        ax.set_title(joint_names(diag.data.q.shape[1] // 2)[j])
        ax.set_ylabel(f"joint change explaining the residual ({unit})", fontsize=8)
        ax.grid(alpha=0.3, axis="y")
    fig.suptitle(f"{_title(diag)} -- residual against the direction of the latest motion\n"
                 "(a backlash separates the '-' and '+' boxes by twice the lag)")
    fig.tight_layout()
    return _save(fig, path)


def plot_residual_direction(diag, path: Path) -> Path:
    plt = pyplot()
    rows = np.setdiff1d(np.arange(len(diag.data)), diag.unsolved)
    r0 = diag.residuals("nominal")[rows, 0]
    r1 = diag.residuals("extended")[rows, 0]
    tips = diag.nominal.robot_tips_mm[rows, 0]
    fig, axes = plt.subplots(1, 4, figsize=(17, 4.4))
    for ax, (a, b) in zip(axes[:3], ((0, 1), (0, 2), (1, 2)), strict=True):
        ax.scatter(r0[:, a], r0[:, b], s=6, color=NOMINAL_COLOR, label="nominal")
        if diag.chosen is not None:
            ax.scatter(r1[:, a], r1[:, b], s=6, color=EXTENDED_COLOR, label="extended")
        m = r0.mean(0)
        ax.annotate("", xy=(m[a], m[b]), xytext=(0, 0), arrowprops={"arrowstyle": "->", "color": "k"})
        ax.set_xlabel(f"residual {'xyz'[a]} (mm)")
        ax.set_ylabel(f"residual {'xyz'[b]} (mm)")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    ax = axes[3]
    ax.quiver(tips[:, 0], tips[:, 1], r0[:, 0], r0[:, 1], color="k", angles="xy", width=0.003)
    ax.set_xlabel("tip x (mm)")
    ax.set_ylabel("tip y (mm)")
    ax.set_title("nominal residual (x, y) at the tip", fontsize=9)
    ax.set_aspect("equal", adjustable="datalim")
    fig.suptitle(f"{_title(diag)} -- tube-1 residual (measured - model) in the robot frame")
    fig.tight_layout()
    return _save(fig, path)


def plot_before_after(diag, path: Path) -> Path:
    plt = pyplot()
    h = diag.heldout
    e0 = diag.errors("nominal")[h]
    e1 = diag.errors("extended")[h]
    tubes = diag.data.tubes
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(12, 4.6), gridspec_kw={"width_ratios": [1.6, 1]})
    for t in tubes:
        for e, ls, lab in ((e0, "--", "nominal"), (e1, "-", "extended")):
            v = np.sort(e[:, t][np.isfinite(e[:, t])])
            if v.size:
                ax.plot(v, np.linspace(0, 1, v.size), ls=ls, color=TUBE_COLORS[t],
                        label=f"tube {t + 1}, {lab}")
    from matplotlib.ticker import NullFormatter, ScalarFormatter

    ax.set_xscale("log")
    ax.xaxis.set_major_formatter(ScalarFormatter())
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("held-out tip error (mm)")
    ax.set_ylabel("fraction of held-out rows")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    width = 0.38
    x = np.arange(len(tubes))
    m0 = [np.nanmean(e0[:, t]) for t in tubes]
    m1 = [np.nanmean(e1[:, t]) for t in tubes]
    bx.bar(x - width / 2, m0, width, color=NOMINAL_COLOR, label="nominal")
    bx.bar(x + width / 2, m1, width, color=EXTENDED_COLOR, label="extended")
    for xi, a, b in zip(x, m0, m1, strict=True):
        bx.text(xi - width / 2, a, f"{a:.2f}", ha="center", va="bottom", fontsize=8)
        bx.text(xi + width / 2, b, f"{b:.2f}", ha="center", va="bottom", fontsize=8)
    bx.set_xticks(x, [f"tube {t + 1}" for t in tubes])
    bx.set_ylabel("held-out mean tip error (mm)")
    bx.legend(fontsize=8)
    bx.grid(alpha=0.3, axis="y")
    fig.suptitle(f"{_title(diag)} -- held-out tip error before -> after "
                 f"({diag.gain_pct():.0f} % lower at the tip, {len(h)} held-out rows)")
    fig.tight_layout()
    return _save(fig, path)


def plot_candidates(diag, path: Path) -> Path:
    plt = pyplot()
    cands = sorted(diag.candidates, key=lambda c: c.fit.bic)
    names = [c.name for c in cands]
    dbic = [c.delta_bic for c in cands]
    held = [c.heldout_mean(0) for c in cands]
    nom = diag.stats("nominal")["mean_mm"]
    colors = [EXTENDED_COLOR if (diag.chosen is c) else ("#9ecae1" if c.significant else NOMINAL_COLOR)
              for c in cands]
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(13, 0.4 * len(cands) + 1.8), sharey=True)
    y = np.arange(len(cands))
    ax.barh(y, dbic, color=colors)
    ax.set_xscale("symlog", linthresh=10)
    ax.axvline(-diag.options.bic_margin, color="k", ls=":", lw=1)
    ax.set_yticks(y, names)
    ax.invert_yaxis()
    ax.set_xlabel("training BIC - nominal BIC")
    bx.barh(y, held, color=colors)
    bx.axvline(nom, color="k", ls="--", lw=1, label="nominal")
    bx.set_xlabel("held-out mean tip error (mm)")
    bx.legend(fontsize=8)
    for a in (ax, bx):
        a.grid(alpha=0.3, axis="x")
    fig.suptitle(f"{_title(diag)} -- candidates (dark: named; light: significant on the main split)")
    fig.tight_layout()
    return _save(fig, path)


def write_plots(diag, out_dir: Path) -> list[Path]:
    """All plots of a diagnosis into ``out_dir``; returns the paths."""
    out_dir = Path(out_dir)
    return [plot_before_after(diag, out_dir / "before_after.png"),
            plot_residual_vs_joints(diag, out_dir / "residual_vs_joints.png"),
            plot_residual_vs_direction(diag, out_dir / "residual_vs_direction.png"),
            plot_residual_direction(diag, out_dir / "residual_direction.png"),
            plot_candidates(diag, out_dir / "candidates.png")]
