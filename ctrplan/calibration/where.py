"""Where the nominal model's error grows: against each joint, against the direction of motion, and
the direction of the residual in the robot frame. Numbers for the JSON report and for the plots."""

from __future__ import annotations

import numpy as np
from scipy import stats

from ctrplan.base.dataio import joint_names
from ctrplan.calibration.predict import Evaluator

#: Finite-difference steps for the joint sensitivities: mm for beta, rad for alpha.
BETA_STEP_MM, ALPHA_STEP_RAD = 1e-3, 1e-4


def joint_steps(n_joints: int) -> np.ndarray:
    """Finite-difference step of every joint (2N,): `BETA_STEP_MM`, then `ALPHA_STEP_RAD`."""
    n = n_joints // 2
    return np.array([BETA_STEP_MM] * n + [ALPHA_STEP_RAD] * n)


def joint_sensitivity(diag) -> np.ndarray:
    """d(tip_t)/d(q_j) of the nominal model (R, 2N, N, 3): rows, joint, tube, xyz -- one batched
    solve."""
    d = diag.data
    nj = d.q.shape[1]
    step = joint_steps(nj)
    ev = Evaluator(d.q, diag.motion)
    models = []
    for j in range(nj):
        off = np.zeros(nj)
        off[j] = step[j]
        models.append(diag.robot.with_changes(joint_offset=tuple(np.asarray(diag.robot.joint_offset) + off)))
    preds = ev.predict(models, guess=diag.nominal.initial_state)
    diag.solves += ev.solves
    base = diag.nominal.robot_tips_mm
    return np.stack([(p.robot_tips_mm - base) / step[j] for j, p in enumerate(preds)], axis=1)


def motion_lag(residual: np.ndarray, sens: np.ndarray, direction: np.ndarray, tubes) -> dict:
    """Per joint, the lag behind the command in the direction of motion that best explains the
    residuals, with its standard error: one linear least-squares fit over all rows and measured tubes
    of ``residual ~ sum_j sens_j (offset_j - lag_j d_j)`` (offsets absorb direction-free errors)."""
    t = list(tubes)
    n = len(residual)
    nj = sens.shape[1]
    names = joint_names(nj // 2)
    r = residual[:, t, :].reshape(n, -1)
    S = sens[:, :, t, :].reshape(n, nj, -1)                      # (n, 2N, m)
    ok = np.isfinite(r).all(1) & np.isfinite(S).all((1, 2))
    r, S, d = r[ok], S[ok], direction[ok]
    A = np.concatenate([S, -S * d[:, :, None]], axis=1)          # (n, 4N, m): offsets, lags
    A = A.transpose(0, 2, 1).reshape(-1, 2 * nj)
    b = r.reshape(-1)
    out = {}
    if len(b) <= 2 * nj:
        return {name: {"lag": None, "lag_std": None} for name in names}
    x, *_ = np.linalg.lstsq(A, b, rcond=None)
    s2 = float(np.sum((b - A @ x) ** 2) / (len(b) - 2 * nj))
    cov = s2 * np.linalg.pinv(A.T @ A)
    for j, name in enumerate(names):
        moved = int((d[:, j] != 0).sum())
        ident = moved >= 3 and (d[:, j] > 0).any() and (d[:, j] < 0).any()
        out[name] = {"lag": float(x[nj + j]) if ident else None,
                     "lag_std": float(np.sqrt(max(cov[nj + j, nj + j], 0.0))) if ident else None,
                     "rows_plus": int((d[:, j] > 0).sum()), "rows_minus": int((d[:, j] < 0).sum())}
    return out


def where_analysis(diag) -> dict:
    """Numbers describing where the nominal error grows (all solved rows)."""
    d = diag.data
    rows = np.setdiff1d(np.arange(len(d)), diag.unsolved)
    err = diag.errors("nominal")[rows, 0]
    q = d.q[rows]
    res = diag.residuals("nominal")
    findings = []
    by_joint = {}
    best = (0.0, None)
    names = joint_names(q.shape[1] // 2)
    for j, name in enumerate(names):
        x = q[:, j]
        if np.ptp(x) <= 1e-12:
            by_joint[name] = {"spearman": None}
            continue
        rho = float(stats.spearmanr(x, err).statistic)
        edges = np.quantile(x, [0, 0.25, 0.5, 0.75, 1.0])
        idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, 3)
        means = [float(err[idx == b].mean()) if (idx == b).any() else None for b in range(4)]
        by_joint[name] = {"spearman": rho, "quartile_edges": [float(v) for v in edges],
                          "quartile_mean_mm": means}
        if np.isfinite(rho) and abs(rho) > abs(best[0]):
            best = (rho, name)
    if best[1] is not None and abs(best[0]) >= 0.3:
        low, high = by_joint[best[1]]["quartile_mean_mm"][::3]
        quarters = "" if low is None or high is None else \
            f": {low:.2f} mm in its lowest quarter, {high:.2f} mm in its highest"
        findings.append(f"tip error {'grows' if best[0] > 0 else 'shrinks'} with {best[1]} (Spearman "
                        f"{best[0]:+.2f}){quarters}")
    # direction of motion
    sens = joint_sensitivity(diag)
    diag.sensitivity = sens
    lag = motion_lag(res[rows], sens[rows], diag.direction[rows], d.tubes)
    e_all = diag.errors("nominal")[rows, 0]
    for j, name in enumerate(names):
        dj = diag.direction[rows, j]
        lag[name]["err_plus_mm"] = float(e_all[dj > 0].mean()) if (dj > 0).any() else None
        lag[name]["err_minus_mm"] = float(e_all[dj < 0].mean()) if (dj < 0).any() else None
        v, s = lag[name]["lag"], lag[name]["lag_std"]
        if v is not None and s is not None and abs(v) > 8 * s and j >= len(names) // 2 \
                and abs(v) > np.radians(0.3):
            findings.append(f"{name} lags {np.degrees(v):+.2f} deg (+- {np.degrees(s):.2f}) behind the "
                            f"command in the direction of motion")
    # residual direction in the robot frame (tube 1)
    r1 = res[rows, 0, :]
    mean = r1.mean(0)
    power = float(np.mean((r1 * r1).sum(1)))
    bias = float(mean @ mean / power) if power > 0 else 0.0
    _, sv, vt = np.linalg.svd(r1 - mean, full_matrices=False)
    axis = vt[0]
    frac = float(sv[0] ** 2 / (sv ** 2).sum()) if sv.size and (sv ** 2).sum() > 0 else 0.0
    if bias > 0.3:
        u = mean / np.linalg.norm(mean)
        findings.append(f"residuals share a common direction ({u[0]:+.2f}, {u[1]:+.2f}, {u[2]:+.2f}) in the "
                        f"robot frame: a mean offset of {np.linalg.norm(mean):.2f} mm, {100 * bias:.0f} % of "
                        f"the squared error")
    if frac > 0.6:
        findings.append(f"{100 * frac:.0f} % of the residual spread lies along ({axis[0]:+.2f}, "
                        f"{axis[1]:+.2f}, {axis[2]:+.2f})")
    return {
        "by_joint": by_joint,
        "by_direction": lag,
        "residual_direction": {"mean_mm": [float(v) for v in mean], "bias_fraction": bias,
                               "principal_axis": [float(v) for v in axis], "principal_fraction": frac,
                               "rms_xyz_mm": [float(v) for v in np.sqrt((r1 ** 2).mean(0))]},
        "findings": findings,
    }
