"""Diagnosis: what the nominal model gets wrong on measured tips, which physical cause explains it,
the extended model and its held-out gain.

Procedure (`diagnose`):

1. split the rows into contiguous blocks, some held out (rows are sequences);
2. nominal errors per tube and where they grow (joints, direction of motion, residual direction); the
   measurement noise from the data alone (`noise.estimate_noise`), independent of any fitted model;
3. fit every candidate cause of `effects.CAUSES` on the training rows (least squares on all measured
   tube tips, finite-difference Jacobians, warm-started batched Cosserat solves); parameters the data
   cannot see (offset of a joint that never moves, backlash of a rotation that never reverses) are
   not fitted, and joint offsets stay within what keeps every row of the file physical;
4. a candidate *beats the nominal model* when it lowers the training BIC by more than ``bic_margin``
   AND lowers the held-out mean error by at least ``min_gain`` with a one-sided Wilcoxon signed-rank
   test on the held-out rows at ``alpha``, with no parameter at a bound away from its base value;
   the named cause is the one with the lowest BIC among those;
5. when one is not enough: the best cause paired with the ``pairs`` partners that a score test
   (linearised RSS at the best fit) ranks first, each fitted fully and accepted under the same test
   against the single cause; repeated up to ``max_causes`` causes;
6. outliers (rows far off the extended model) are reported; if some are training rows, the
   selection is repeated without them (and the report says so);
7. stability: the selection is repeated on ``resamples`` other contiguous splits (fits warm-started)
   and on bootstrap draws of the held-out rows; only causes chosen on ``stable_fraction`` of the
   splits are named, disagreement is reported as a tie;
8. verdict: ``explained`` when the extended model's held-out error is within ``noise_tolerance`` x
   the noise; with no cause named, ``none`` if the nominal model is, else ``unexplained``.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import stats

from ctrplan.calibration.data import MeasuredData, rows_text, split_blocks
from ctrplan.calibration.effects import CAUSES, Combined, Effect, make_effect
from ctrplan.calibration.fit import (
    Evaluator,
    FitResult,
    Prediction,
    bic,
    fit_effect,
    partner_scores,
    residual_vector,
)
from ctrplan.calibration.noise import estimate_noise
from ctrplan.errors import InputError
from ctrplan.measurement import Calibration, motion_direction
from ctrplan.robot import Robot


@dataclass(frozen=True)
class DiagnoseOptions:
    """Knobs of the diagnosis (defaults are what the CLI uses)."""

    candidates: tuple[str, ...] = CAUSES
    heldout_fraction: float = 0.25
    blocks: int = 10
    seed: int = 0
    pairs: int = 3               # pair the best cause with this many next-best ones (0: no pairs)
    max_causes: int = 3          # add causes one at a time (each under the same test) up to this many
    bic_margin: float = 10.0     # BIC must drop by more than this ("very strong" evidence)
    min_gain: float = 0.05       # and the held-out mean error by at least this fraction
    alpha: float = 0.01          # with this significance (one-sided Wilcoxon, held-out rows)
    outlier_mads: float = 8.0    # outlier: error > median + this many robust sigmas (and > 3 x median)
    max_nfev: int = 30
    max_rows: int = 1000         # larger files: this many rows in 20 contiguous runs spread over the file
    noise_tolerance: float = 1.3  # "within the noise": held-out mean error <= this x noise_mm
    resamples: int = 2           # other contiguous splits the selection is repeated on (stability)
    resample_nfev: int = 8       # their fits start from the main fit: a few steps suffice
    bootstrap: int = 200         # bootstrap draws of the held-out rows (selection among the fits)
    stable_fraction: float = 2 / 3  # a cause is named when chosen in at least this share of splits


@dataclass
class Candidate:
    """A fitted candidate and how it does on the held-out rows."""

    fit: FitResult
    heldout: Prediction
    heldout_err: np.ndarray      # (h, 3) per-row per-tube error, mm (NaN for unmeasured tubes)
    delta_bic: float = 0.0       # training BIC minus the nominal model's
    reference: str = "nominal"   # the model it must beat: nominal, or the single cause of a pair
    delta_bic_ref: float = 0.0   # training BIC minus the reference's
    p_value: float = 1.0         # one-sided Wilcoxon on held-out rows vs the reference
    gain: float = 0.0            # relative held-out gain vs the reference (pooled over tubes)
    significant: bool = False

    @property
    def cause(self) -> str:
        return self.fit.name

    def off_limits(self) -> list[str]:
        """Parameters at a bound other than their base value: the fit is unphysical there, so the
        candidate never counts as significant (a parameter at its base-value bound is just zero)."""
        at = set(self.fit.at_bound())
        return [p.name for p, v0 in zip(self.fit.params, self.fit.x0, strict=True)
                if p.name in at and not (abs(v0 - p.lower) < 1e-9 or abs(v0 - p.upper) < 1e-9)]

    @property
    def causes(self) -> tuple[str, ...]:
        return self.fit.effect.causes

    def heldout_mean(self, tube: int | None = 0) -> float:
        e = self.heldout_err if tube is None else self.heldout_err[:, tube]
        return float(np.nanmean(e))

    def to_json(self) -> dict:
        return {"cause": self.cause, "causes": list(self.causes), "parameters": self.fit.parameters(),
                "derived": self.fit.derived,
                "heldout_mean_mm": self.heldout_mean(0),
                "heldout_mean_all_tubes_mm": self.heldout_mean(None),
                "bic": self.fit.bic, "delta_bic": self.delta_bic, "train_rms_mm": self.fit.rms_mm,
                "reference": self.reference, "delta_bic_vs_reference": self.delta_bic_ref,
                "heldout_gain_vs_reference_pct": 100.0 * self.gain, "p_value": self.p_value,
                "significant": bool(self.significant), "fit_seconds": round(self.fit.seconds, 3),
                "converged": self.fit.success, "at_bound": self.fit.at_bound(),
                "not_fitted": self.fit.fixed}


@dataclass
class Diagnosis:
    """Everything `diagnose` found; `to_json` gives the DESIGN §3 document."""

    data: MeasuredData                # the rows diagnosed (all, or max_rows of them)
    rows_in_file: int
    robot: Robot
    calibration: Calibration
    options: DiagnoseOptions
    direction: np.ndarray
    train: np.ndarray                 # row indices used for fitting
    heldout: np.ndarray               # held-out row indices
    unsolved: np.ndarray              # rows the nominal model could not solve (excluded)
    nominal: Prediction               # all rows
    extended: Prediction              # all rows (== nominal when cause is none)
    nominal_bic: float
    singles: list[Candidate]
    pairs: list[Candidate]
    chosen: Candidate | None
    outliers: np.ndarray              # row indices
    outliers_refit: bool
    where: dict = field(default_factory=dict)
    sensitivity: np.ndarray | None = None   # d tips / d q of the nominal model (N, 6, 3, 3)
    seconds: float = 0.0
    solves: int = 0
    noise: dict = field(default_factory=dict)          # `noise.estimate_noise`
    stability: dict = field(default_factory=dict)      # how often each cause was selected
    ties: list[str] = field(default_factory=list)      # causes the data cannot tell apart
    unstable: list[str] = field(default_factory=list)  # chosen on some splits only: not named
    not_fitted: dict = field(default_factory=dict)     # candidate -> why the data cannot see it

    # ---- derived ----------------------------------------------------------------------------------
    @property
    def noise_mm(self) -> float | None:
        return self.noise.get("noise_mm")

    def within_noise(self, which: str) -> bool:
        """Every measured tube's held-out mean error within ``noise_tolerance`` x the noise."""
        if self.noise_mm is None:
            return False
        means = [t["mean_mm"] for t in self.stats(which)["per_tube"] if t["mean_mm"] is not None]
        return bool(means) and max(means) <= self.options.noise_tolerance * self.noise_mm

    @property
    def explained(self) -> bool:
        """Held-out error after the extension (the nominal model for `none`) within the noise."""
        return self.within_noise("extended")

    @property
    def cause(self) -> str:
        """The primary named cause; ``none`` only when the nominal model matches to the noise,
        ``unexplained`` when it does not and no candidate of the library beats it."""
        if self.chosen is not None:
            return self.chosen.causes[0]
        return "none" if self.within_noise("nominal") else "unexplained"

    def unexplained_mm(self) -> float | None:
        """RMS held-out tip error (tube 1) the noise does not account for:
        sqrt(max(mean |e|^2 - 3 sigma^2, 0)), mm."""
        sigma = self.noise.get("sigma_mm")
        if sigma is None:
            return None
        e = self.errors("extended")[self.heldout, 0]
        e = e[np.isfinite(e)]
        return float(np.sqrt(max(float(np.mean(e * e)) - 3.0 * sigma ** 2, 0.0))) if e.size else None

    def remaining(self) -> dict:
        """Where the extended model's error still lives (all solved rows, tube 1): per-tube held-out
        means, the joint it grows with, the direction-of-motion split and the mean offset."""
        rows = np.setdiff1d(np.arange(len(self.data)), self.unsolved)
        err = self.errors("extended")[rows, 0]
        q = self.data.q[rows]
        half = q.shape[1] // 2
        names = [f"beta{i + 1}" for i in range(half)] + [f"alpha{i + 1}" for i in range(half)]
        by_joint = {}
        for j, name in enumerate(names):
            if np.ptp(q[:, j]) > 1e-12:
                by_joint[name] = float(stats.spearmanr(q[:, j], err).statistic)
        by_dir = {}
        for j, name in enumerate(names[half:], start=half):
            dj = self.direction[rows, j]
            if (dj > 0).any() and (dj < 0).any():
                by_dir[name] = {"plus_mm": float(err[dj > 0].mean()), "minus_mm": float(err[dj < 0].mean())}
        res = self.residuals("extended")[rows, 0]
        mean = np.nanmean(res, axis=0)
        findings = []
        if by_joint:
            name, rho = max(by_joint.items(), key=lambda t: abs(t[1]) if np.isfinite(t[1]) else 0.0)
            if np.isfinite(rho) and abs(rho) >= 0.3:
                findings.append(f"remaining error {'grows' if rho > 0 else 'shrinks'} with {name} "
                                f"(Spearman {rho:+.2f})")
        for name, v in by_dir.items():
            if abs(v["plus_mm"] - v["minus_mm"]) > 0.2 * max(v["plus_mm"], v["minus_mm"]):
                findings.append(f"remaining error depends on the direction of {name}: "
                                f"{v['plus_mm']:.2f} mm moving +, {v['minus_mm']:.2f} mm moving -")
        power = float(np.nanmean((res ** 2).sum(1)))
        if power > 0 and float(mean @ mean) / power > 0.3:
            findings.append(f"remaining residual has a mean offset of {np.linalg.norm(mean):.2f} mm")
        return {"per_tube_heldout_mean_mm": {str(t["tube"]): t["mean_mm"]
                                             for t in self.stats("extended")["per_tube"]},
                "spearman_by_joint": by_joint, "by_direction": by_dir,
                "mean_residual_mm": [float(v) for v in mean], "findings": findings}

    @property
    def causes(self) -> tuple[str, ...]:
        return () if self.chosen is None else self.chosen.causes

    @property
    def extended_robot(self) -> Robot:
        if self.chosen is None:
            return self.robot
        return self.chosen.fit.robot.with_changes(name=f"{self.robot.name}-{'+'.join(self.causes)}")

    @property
    def extended_calibration(self) -> Calibration:
        return self.calibration if self.chosen is None else self.chosen.fit.calibration

    def errors(self, which: str = "nominal") -> np.ndarray:
        """Per-row, per-tube tip error (N, 3), mm, NaN where unmeasured or unsolved."""
        pred = self.nominal if which == "nominal" else self.extended
        return np.linalg.norm(self.data.tips_mm - pred.tips_mm, axis=-1)

    def residuals(self, which: str = "nominal") -> np.ndarray:
        """measured - predicted (N, 3, 3), mm, in the robot frame of the respective model."""
        pred = self.nominal if which == "nominal" else self.extended
        calib = self.calibration if which == "nominal" else self.extended_calibration
        return calib.to_robot_frame(self.data.tips_mm) - calib.to_robot_frame(pred.tips_mm)

    def arc_lengths(self) -> np.ndarray:
        """Arc length of each tube's tip (N, 3), mm (commanded joints plus the base offsets)."""
        return self.robot.tube_ends_mm(self.data.q)

    def stats(self, which: str = "nominal", rows: np.ndarray | None = None) -> dict:
        rows = self.heldout if rows is None else rows
        err = self.errors(which)[rows]
        length = self.arc_lengths()[rows]
        per_tube = [dict(tube=t + 1, **error_stats(err[:, t], length[:, t])) for t in self.data.tubes]
        out = dict(error_stats(err[:, 0], length[:, 0]))
        out["rows"] = int(len(rows))
        out["per_tube"] = per_tube
        return out

    def gain_pct(self) -> float:
        nom = self.stats("nominal")["mean_mm"]
        ext = self.stats("extended")["mean_mm"]
        return float(100.0 * (1.0 - ext / nom)) if nom > 0 else 0.0

    def to_json(self) -> dict:
        """The JSON document of DESIGN §3 (plus details); non-finite numbers become null."""
        return clean_json(self._json())

    def _json(self) -> dict:
        d = self.data
        nominal = self.stats("nominal")
        nominal["scope"] = "held-out rows, tip of tube 1 (per_tube: every measured tube)"
        nominal["all_rows"] = self.stats("nominal", np.setdiff1d(np.arange(len(d)), self.unsolved))
        nominal["where"] = self.where
        extended = self.stats("extended")
        extended["scope"] = nominal["scope"]
        cands = [c.to_json() for c in self.singles + self.pairs]
        chosen = self.chosen
        noise = dict(self.noise)
        return {
            "source": d.source,
            "format": d.format,
            "rows": int(self.rows_in_file),
            "rows_used": int(len(d)),
            "rows_dropped": int(self.rows_in_file - len(d)),
            "train_rows": int(len(self.train)),
            "heldout_rows": int(len(self.heldout)),
            "tubes_measured": [t + 1 for t in d.tubes],
            "nominal": nominal,
            "cause": self.cause,
            "causes": list(self.causes),
            "explained": self.explained,
            "unexplained_mm": self.unexplained_mm(),
            "noise_mm": self.noise_mm,
            "noise": noise,
            "stability": self.stability,
            "ties": list(self.ties),
            "unstable": list(self.unstable),
            "not_fitted": self.not_fitted,
            "remaining": self.remaining(),
            "parameters": {} if chosen is None else chosen.fit.parameters(),
            "derived": {} if chosen is None else chosen.fit.derived,
            "extended": extended,
            "gain_pct": self.gain_pct(),
            "candidates": cands,
            "selection": {
                "criterion": "lowest training BIC among candidates that beat the nominal model: "
                             f"delta BIC < -{self.options.bic_margin:g} and held-out mean error lower by "
                             f">= {100 * self.options.min_gain:g} % (one-sided Wilcoxon p < "
                             f"{self.options.alpha:g}); a second cause is added under the same test",
                "nominal_bic": self.nominal_bic,
                "noise_tolerance": self.options.noise_tolerance,
                "seed": self.options.seed,
            },
            "outliers": [{"row": int(d.lines[i]), "error_mm": float(np.nanmean(self.errors("extended")[i])),
                          "split": "heldout" if i in set(self.heldout.tolist()) else "train"}
                         for i in self.outliers],
            "outliers_excluded_from_fit": bool(self.outliers_refit),
            "outside_domain_rows": [int(v) for v in d.lines[d.outside_domain]],
            "unsolved_rows": [int(d.lines[i]) for i in self.unsolved],
            "seconds": round(self.seconds, 2),
            "solves": int(self.solves),
        }

    def summary(self) -> str:
        """A human-readable report (the CLI prints it without --json)."""
        j = self.to_json()
        nom, ext = j["nominal"], j["extended"]
        used = "" if j["rows_used"] == j["rows"] else (
            f", {j['rows_used']} used in contiguous runs ({j['rows_dropped']} dropped by max_rows)")
        lines = [f"{self.data.source}: {j['rows']} rows{used} ({j['train_rows']} train, "
                 f"{j['heldout_rows']} held out in contiguous blocks), tubes measured: {j['tubes_measured']}"]
        if j["outside_domain_rows"]:
            lines.append(f"  note: {rows_text(j['outside_domain_rows'])} lie outside the snap-free "
                         f"planning domain (accepted)")
        if j["unsolved_rows"]:
            lines.append(f"  note: the nominal model does not solve {rows_text(j['unsolved_rows'])} "
                         f"(excluded)")
        lines.append("nominal model, held-out error per tube:")
        for t in nom["per_tube"]:
            lines.append(f"  tube {t['tube']}: mean {t['mean_mm']:.3f} mm, median {t['median_mm']:.3f}, "
                         f"p95 {t['p95_mm']:.3f}, {t['mean_pct_length']:.2f} % of arc length")
        for s in self.where.get("findings", []):
            lines.append(f"  where: {s}")
        lines.append("candidates (training BIC, held-out mean tip error):")
        for c in sorted(self.singles + self.pairs, key=lambda c: c.fit.bic):
            mark = "*" if c.significant else " "
            ref = "" if c.reference == "nominal" else f" vs {c.reference}"
            lines.append(f"  {mark} {c.cause:<26s} dBIC {c.delta_bic:10.1f}  "
                         f"held-out {c.heldout_mean(0):.3f} mm  gain {100 * c.gain:5.1f} %{ref}")
        for name, why in self.not_fitted.items():
            lines.append(f"  not fitted: {name} ({'; '.join(why)})")
        fixed = {k: v for c in self.singles for k, v in c.fit.fixed.items()}
        if fixed:
            lines.append("  held at their file values (the data cannot see them): "
                         + ", ".join(f"{k} ({v})" for k, v in fixed.items()))
        noise_mm = j["noise_mm"]
        noise_txt = "not estimated" if noise_mm is None else f"{noise_mm:.3f} mm mean tip error"
        lines.append(f"measurement noise: {noise_txt} ({j['noise']['method']})")
        st = self.stability
        if st:
            lines.append("selection under resampling: "
                         + ", ".join(f"{k} {v}/{st['splits']} splits" for k, v in st["chosen"].items())
                         + "; bootstrap of held-out rows: "
                         + ", ".join(f"{k} {100 * v:.0f} %" for k, v in st["bootstrap_heldout"].items()))
        if self.chosen is None and j["cause"] == "none":
            lines.append("cause: none -- the nominal model matches the held-out rows to the measurement "
                         "noise")
        elif self.chosen is None:
            lines.append(f"cause: unexplained -- the nominal model is off by {nom['mean_mm']:.3f} mm "
                         f"(noise {noise_txt}) and no cause of the library beats it")
        else:
            lines.append(f"cause: {' + '.join(self.causes)}")
            if self.ties:
                lines.append(f"  tie: the data do not tell apart {', '.join(self.ties)} (each chosen on "
                             "some splits, or as good on the held-out rows); treat the naming as tentative")
            if self.unstable:
                lines.append("  not named (chosen on some splits only): " + ", ".join(self.unstable))
            for name, p in j["parameters"].items():
                if p.get("fitted") is False:
                    lines.append(f"  {name} not fitted: {p['reason']}")
                    continue
                std = "n/a (at its bound)" if p.get("at_bound") else (
                    "n/a" if p["std"] is None else f"{p['std']:.3g}")
                extra = ""
                if p["unit"] == "rad":
                    extra = f"  ({np.degrees(p['value']):.3f} deg +- " + (
                        "n/a" if p["std"] is None else f"{np.degrees(p['std']):.3f}") + ")"
                lines.append(f"  {name} = {p['value']:.6g} +- {std} {p['unit']} (was {p['nominal']:.6g})"
                             f"{extra}")
            if j["derived"]:
                lines.append("  i.e. " + ", ".join(f"{k} = {v:.4g}" for k, v in j["derived"].items()))
            lines.append(f"held-out tip error: {nom['mean_mm']:.3f} -> {ext['mean_mm']:.3f} mm mean, "
                         f"{nom['p95_mm']:.3f} -> {ext['p95_mm']:.3f} mm p95 "
                         f"(gain {j['gain_pct']:.1f} %)")
        if not j["explained"]:
            left = "?" if j["unexplained_mm"] is None else f"{j['unexplained_mm']:.3f}"
            lines.append(f"NOT EXPLAINED: the library does not explain the data -- {left} mm RMS of "
                         f"held-out tip error is beyond the noise")
            for f in j["remaining"]["findings"]:
                lines.append(f"  where: {f}")
        if j["outliers"]:
            o = j["outliers"]
            fate = "excluded from the fit" if j["outliers_excluded_from_fit"] else "kept in the fit"
            lines.append(f"outliers (reported, {fate}): "
                         + ", ".join(f"row {x['row']} ({x['error_mm']:.2f} mm)" for x in o[:10])
                         + (f" and {len(o) - 10} more" if len(o) > 10 else ""))
        lines.append(f"time: {j['seconds']:.1f} s ({j['solves']} Cosserat solves)")
        return "\n".join(lines)


def error_stats(err: np.ndarray, length: np.ndarray) -> dict:
    ok = np.isfinite(err)
    e, L = err[ok], length[ok]
    if e.size == 0:
        return {"mean_mm": None, "median_mm": None, "p95_mm": None, "max_mm": None,
                "mean_pct_length": None}
    return {"mean_mm": float(e.mean()), "median_mm": float(np.median(e)),
            "p95_mm": float(np.percentile(e, 95)), "max_mm": float(e.max()),
            "mean_pct_length": float(np.mean(100.0 * e / L))}


def _per_row(err: np.ndarray) -> np.ndarray:
    return np.nanmean(err, axis=1)


def _compare(cand_err: np.ndarray, ref_err: np.ndarray, alpha: float,
             min_gain: float) -> tuple[float, float, bool]:
    """Relative gain, p-value and whether the candidate beats the reference on held-out rows."""
    a, b = _per_row(ref_err), _per_row(cand_err)
    gain = 1.0 - b.mean() / a.mean() if a.mean() > 0 else 0.0
    diff = a - b
    if np.allclose(diff, 0.0):
        return float(gain), 1.0, False
    # the exact null distribution where it is cheap (<= 50 rows, no zeros or ties); the normal
    # approximation otherwise -- scipy would fall back to a permutation test, slow inside the bootstrap
    exact = diff.size <= 50 and np.all(diff != 0) and np.unique(np.abs(diff)).size == diff.size
    try:
        test = stats.wilcoxon(diff, alternative="greater", method="exact" if exact else "approx")
        p = float(test.pvalue)
    except ValueError:
        p = 1.0
    return float(gain), p, bool(gain >= min_gain and p < alpha)


def diagnose(data: MeasuredData, robot: Robot | None = None, calibration: Calibration | None = None,
             options: DiagnoseOptions | None = None, direction: np.ndarray | None = None) -> Diagnosis:
    """Diagnose measured tips against ``robot`` (+ ``calibration``); see the module docstring.

    ``direction`` (N, 2N_tubes): direction of motion of every row, when ``data`` is a subset of a
    longer acquisition (default: from the rows of ``data``, `motion_direction`)."""
    t0 = time.perf_counter()
    robot = robot or Robot.nominal()
    calibration = calibration or Calibration()
    opt = options or DiagnoseOptions()
    for c in opt.candidates:
        make_effect(c)  # validates names
    rows_in_file = len(data)
    if direction is None:
        direction = motion_direction(data.q)   # from the full sequence, before any subsampling
    # what the data cannot see, and the joint offsets that keep every row of the file physical
    fixed = unseen_parameters(data.q, direction, robot)
    limits = (offset_limits(data.q, robot, share=1.0), offset_limits(data.q, robot, share=0.5))
    q_file = data.q
    if len(data) > opt.max_rows:
        keep = contiguous_subsample(len(data), opt.max_rows)
        data, direction = data.subset(keep), direction[keep]
    n = len(data)
    ev_all = Evaluator(data.q, direction)
    nominal = ev_all.predict([(robot, calibration)])[0]
    unsolved = np.flatnonzero(~nominal.converged)
    solved = np.setdiff1d(np.arange(n), unsolved)
    noise = estimate_noise(data.q[solved], direction[solved], (data.tips_mm - nominal.tips_mm)[solved],
                           data.tubes)
    state = _Selection(data, robot, calibration, opt, direction, nominal, fixed, limits, q_file)

    def split(seed: int, drop: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        tr, he = split_blocks(n, opt.heldout_fraction, opt.blocks, seed)
        return np.setdiff1d(tr, np.union1d(unsolved, drop)), np.setdiff1d(he, unsolved)

    train0, heldout = split(opt.seed, unsolved)
    sel = state.run(train0, heldout)
    extended = _extended(ev_all, sel, nominal)
    outliers = _outliers(data, extended, unsolved, opt.outlier_mads)
    refit = False
    if np.intersect1d(outliers, train0).size:
        refit = True
        sel = state.run(np.setdiff1d(train0, outliers), heldout)
        extended = _extended(ev_all, sel, nominal)
        outliers = _outliers(data, extended, unsolved, opt.outlier_mads)
    # stability: the selection on other contiguous splits (fits warm-started from these) and on
    # bootstrap draws of the held-out rows
    # (only candidates that lowered the training BIC on the main split can be chosen on another)
    warm = {c.cause: c.fit.x for c in sel["singles"] + sel["pairs"]}
    contenders = tuple(c.cause for c in sel["singles"] if c.delta_bic < 0)
    picks = [_pick_name(sel["chosen"])]
    for r in range(1, opt.resamples + 1):
        tr, he = split(opt.seed + r, outliers if refit else unsolved)
        picks.append(_pick_name(state.run(tr, he, warm=warm, max_nfev=opt.resample_nfev,
                                          only=contenders)["chosen"]))
    boot = state.bootstrap(sel, opt.bootstrap)
    stability = _stability(picks, boot, opt)
    top, n_top = max(stability["chosen"].items(), key=lambda t: (t[1], t[0] == picks[0]))
    if top != picks[0] and n_top >= opt.stable_fraction * len(picks):
        # most splits agree on another answer than the main split: that is the stable one
        sel["chosen"] = None if top == "none" else state.named(top, sel)
        stability["main_split_choice"] = picks[0]
    chosen, ties, unstable = _stable_choice(sel, stability, opt)
    sel["chosen"] = chosen
    extended = _extended(ev_all, sel, nominal)
    diag = Diagnosis(data=data, rows_in_file=rows_in_file, robot=robot, calibration=calibration,
                     options=opt, direction=direction,
                     train=sel["train"], heldout=heldout, unsolved=unsolved, nominal=nominal,
                     extended=extended, nominal_bic=sel["nominal_bic"], singles=sel["singles"],
                     pairs=sel["pairs"], chosen=chosen, outliers=outliers, outliers_refit=refit,
                     noise=noise, stability=stability, ties=ties, unstable=unstable,
                     not_fitted=sel["not_fitted"])
    from ctrplan.calibration.where import where_analysis

    diag.where = where_analysis(diag)
    diag.seconds = time.perf_counter() - t0
    diag.solves = ev_all.solves + state.solves
    return diag


def unseen_parameters(q: np.ndarray, direction: np.ndarray, robot: Robot) -> dict[str, str]:
    """Parameters the data cannot see -> why: the zero offset of a joint that never moves, the
    backlash of a rotation that never reverses its direction."""
    q = np.asarray(q, dtype=float)
    n = q.shape[-1] // 2
    out = {}
    for j in range(2 * n):
        kind, i = ("beta", j + 1) if j < n else ("alpha", j - n + 1)
        if np.ptp(q[:, j]) <= 1e-9:
            unit = "mm" if kind == "beta" else "rad"
            out[f"{kind}{i}_offset_{unit}"] = f"{kind}{i} never moves in the data"
        if kind == "alpha":
            d = direction[:, j]
            if not ((d > 0).any() and (d < 0).any()):
                out[f"backlash{i}_rad"] = f"alpha{i} never reverses its direction of motion"
                out[f"windup{i}_rad_per_mm"] = out[f"backlash{i}_rad"]
            elif np.ptp(q[:, i - 1]) <= 1e-9:
                out[f"windup{i}_rad_per_mm"] = f"beta{i} never moves: windup is backlash there"
    return out


def offset_limits(q: np.ndarray, robot: Robot, share: float = 0.5,
                  margin_mm: float = 1e-6) -> dict[str, tuple[float, float]]:
    """Bounds on the beta zero offsets (mm, absolute) under which every row of ``q`` stays physically
    valid (tube order, bases behind the plate, inner tubes reaching furthest; `Robot.check_joints`).
    Each tube may use ``share`` of the slack of a pairwise constraint: 0.5 guarantees validity for
    any offsets in the box, 1.0 is each tube's own limit (check the fitted robot)."""
    n = q.shape[-1] // 2
    base = np.asarray(robot.joint_offset, dtype=float)[:n]
    b = np.asarray(q, dtype=float)[:, :n] + base
    ends = b + robot.lengths_mm
    lo, hi = np.full(n, -np.inf), np.full(n, np.inf)
    for i in range(n - 1):
        gap = max(float((b[:, i + 1] - b[:, i]).min()) - margin_mm, 0.0)      # beta_i <= beta_i+1
        hi[i], lo[i + 1] = min(hi[i], base[i] + share * gap), max(lo[i + 1], base[i + 1] - share * gap)
        gap = max(float((ends[:, i] - ends[:, i + 1]).min()) - margin_mm, 0.0)  # l_i >= l_i+1
        lo[i], hi[i + 1] = max(lo[i], base[i] - share * gap), min(hi[i + 1], base[i + 1] + share * gap)
    hi[n - 1] = min(hi[n - 1], base[n - 1] + max(float(-b[:, n - 1].max()) - margin_mm, 0.0))
    lo[n - 1] = max(lo[n - 1], base[n - 1] - max(float(ends[:, n - 1].min()) - 1e-3, 0.0))
    return {f"beta{i + 1}_offset_mm": (float(lo[i]), float(hi[i])) for i in range(n)}


def _pick_name(c: Candidate | None) -> str:
    return "none" if c is None else "+".join(sorted(c.causes))


def _stability(picks: list[str], boot: dict[str, float], opt: DiagnoseOptions) -> dict:
    counts: dict[str, int] = {}
    for p in picks:
        counts[p] = counts.get(p, 0) + 1
    comp: dict[str, float] = {}
    for p in picks:
        for c in p.split("+"):
            comp[c] = comp.get(c, 0.0) + 1.0 / len(picks)
    return {"splits": len(picks), "chosen": counts, "cause_fraction": comp,
            "bootstrap_heldout": boot,
            "method": f"selection repeated on {len(picks) - 1} other contiguous train/held-out splits "
                      f"(seeds {opt.seed + 1}..{opt.seed + len(picks) - 1}, fits warm-started) and on "
                      f"{opt.bootstrap} bootstrap draws of the held-out rows (fits kept)"}


def _stable_choice(sel: dict, stability: dict,
                   opt: DiagnoseOptions) -> tuple[Candidate | None, list[str], list[str]]:
    """What to name: the main split's choice reduced to its causes chosen on at least
    ``stable_fraction`` of the splits (nothing, if the splits mostly chose nothing); the ties (causes
    the data cannot tell apart) and the unstable causes (chosen on some splits, not named)."""
    chosen = sel["chosen"]
    frac = stability["cause_fraction"]
    unstable = sorted(c for c, f in frac.items() if c != "none" and 0 < f < opt.stable_fraction)
    if chosen is None:
        return None, [], unstable
    ties: list[str] = []
    stable = {c for c in chosen.causes if frac.get(c, 0.0) >= opt.stable_fraction}
    if stable and stable != set(chosen.causes):
        sub = [c for c in sel["singles"] + sel["pairs"] if set(c.causes) == stable and c.significant]
        if sub:
            chosen = sub[0]
    elif not stable:
        if frac.get("none", 0.0) >= opt.stable_fraction:
            return None, [], unstable
        ties = list(unstable)       # the splits disagree: a tie among what they chose
    # near-ties on the main split: significant singles as good as the choice
    for c in sel["singles"]:
        if c.significant and c.cause not in chosen.causes and \
                abs(c.fit.bic - chosen.fit.bic) < opt.bic_margin and \
                c.heldout_mean(None) <= 1.05 * chosen.heldout_mean(None):
            ties.append(c.cause)
    if ties:
        ties = sorted(set(ties) | set(chosen.causes))
    return chosen, ties, [c for c in unstable if c not in chosen.causes and c not in ties]


def contiguous_subsample(n: int, rows: int, runs: int = 20) -> np.ndarray:
    """``rows`` indices of ``range(n)`` as ``runs`` contiguous runs spread evenly over the sequence."""
    runs = max(1, min(runs, rows))
    sizes = np.full(runs, rows // runs)
    sizes[: rows % runs] += 1
    starts = np.linspace(0, n - sizes.max(), runs).astype(int)
    return np.unique(np.concatenate([np.arange(a, a + k) for a, k in zip(starts, sizes, strict=True)]))


def _extended(ev_all: Evaluator, sel: dict, nominal: Prediction) -> Prediction:
    chosen = sel["chosen"]
    if chosen is None:
        return nominal
    return ev_all.predict([(chosen.fit.robot, chosen.fit.calibration)], guess=nominal.initial_state)[0]


def _outliers(data: MeasuredData, pred: Prediction, unsolved: np.ndarray, mads: float = 8.0) -> np.ndarray:
    err = np.nanmean(np.linalg.norm(data.tips_mm - pred.tips_mm, axis=-1), axis=1)
    ok = np.isfinite(err)
    med = np.median(err[ok])
    mad = 1.4826 * np.median(np.abs(err[ok] - med))
    thr = max(med + mads * mad, 3.0 * med)
    return np.setdiff1d(np.flatnonzero(ok & (err > thr)), unsolved)


class _Selection:
    """Fits and selects candidates for given training and held-out rows."""

    def __init__(self, data, robot, calibration, opt, direction, nominal, fixed, limits, q_file):
        self.data, self.robot, self.calibration, self.opt = data, robot, calibration, opt
        self.direction, self.nominal = direction, nominal
        self.fixed, self.limits, self.q_file = fixed, limits, q_file
        self.solves = 0

    def _candidate(self, effect: Effect, ev: Evaluator, measured, nom_train, heldout, x_start=None,
                   max_nfev=None) -> Candidate:
        wide, safe = self.limits

        def fit_within(limits, x_start):
            return fit_effect(effect, self.robot, self.calibration, ev, measured, self.data.tubes,
                              nom_train, x_start=x_start, max_nfev=max_nfev or self.opt.max_nfev,
                              fixed=self.fixed, limits=limits)

        fit = fit_within(wide, x_start)
        try:   # every row of the file must stay physical under the fitted robot
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                fit.robot.check_joints(self.q_file, allow_outside_domain=True)
        except InputError:
            fit = fit_within(safe, None if x_start is None else np.asarray(x_start))
        nom_held = self.nominal.subset(heldout)
        ev_held = Evaluator(self.data.q[heldout], self.direction[heldout])
        held = ev_held.predict([(fit.robot, fit.calibration)], guess=nom_held.initial_state)[0]
        self.solves += ev_held.solves
        # unsolved held-out rows keep the nominal prediction (and its error)
        held.tips_mm = np.where(held.converged[:, None, None], held.tips_mm, nom_held.tips_mm)
        err = np.linalg.norm(self.data.tips_mm[heldout] - held.tips_mm, axis=-1)
        return Candidate(fit=fit, heldout=held, heldout_err=err)

    def _judge(self, c: Candidate, ref_err: np.ndarray, ref_bic: float) -> None:
        opt = self.opt
        c.delta_bic_ref = c.fit.bic - ref_bic
        c.gain, c.p_value, beats = _compare(c.heldout_err, ref_err, opt.alpha, opt.min_gain)
        c.significant = beats and c.delta_bic_ref < -opt.bic_margin and not c.off_limits()

    def run(self, train: np.ndarray, heldout: np.ndarray, warm: dict[str, np.ndarray] | None = None,
            max_nfev: int | None = None, only: tuple[str, ...] | None = None) -> dict:
        """Fit the candidates (``only`` these, if given) on ``train``, judge them on ``heldout``."""
        opt, d = self.opt, self.data
        warm = warm or {}
        ev = Evaluator(d.q[train], self.direction[train])
        measured = d.tips_mm[train]
        nom_train = self.nominal.subset(train)
        r0 = residual_vector(measured, nom_train, d.tubes)
        bic0 = bic(float(r0 @ r0), r0.size, 0)
        nom_held_err = np.linalg.norm(d.tips_mm[heldout] - self.nominal.tips_mm[heldout], axis=-1)
        singles, not_fitted = [], {}
        for name in opt.candidates if only is None else [c for c in opt.candidates if c in only]:
            eff = make_effect(name)
            names = [p.name for p in eff.params(self.robot, self.calibration)]
            if all(n in self.fixed for n in names):
                not_fitted[name] = sorted({self.fixed[n] for n in names})
                continue
            c = self._candidate(eff, ev, measured, nom_train, heldout, x_start=warm.get(name),
                                max_nfev=max_nfev)
            self._judge(c, nom_held_err, bic0)
            c.delta_bic = c.delta_bic_ref
            singles.append(c)
        ranked = sorted(singles, key=lambda c: c.fit.bic)
        winners = [c for c in ranked if c.significant]
        chosen = winners[0] if winners else None
        pairs = []
        while chosen is not None and opt.pairs > 0 and len(chosen.causes) < opt.max_causes:
            # add a cause: rank the partners by a score test at the chosen fit, fit the best few fully
            mine = {p.name for p in chosen.fit.params}
            others = [c for c in ranked if c.cause not in chosen.causes
                      and not mine & {p.name for p in c.fit.params}]
            scores = partner_scores(chosen.fit, [o.fit.effect for o in others], ev, measured,
                                    d.tubes, nom_train)
            others = [o for _, o in sorted(zip(scores, others, strict=True), key=lambda t: t[0])][:opt.pairs]
            added = []
            for o in others:
                eff = Combined([chosen.fit.effect, o.fit.effect])
                x_start = warm.get(eff.name, np.concatenate([chosen.fit.x, o.fit.x0]))
                c = self._candidate(eff, ev, measured, nom_train, heldout, x_start=x_start,
                                    max_nfev=max_nfev)
                c.delta_bic = c.fit.bic - bic0
                c.reference = chosen.cause
                self._judge(c, chosen.heldout_err, chosen.fit.bic)
                added.append(c)
            pairs += added
            better = sorted([c for c in added if c.significant], key=lambda c: c.fit.bic)
            if not better:
                break
            chosen = better[0]
        self.solves += ev.solves
        return {"train": train, "heldout": heldout, "nominal_bic": bic0, "singles": singles,
                "pairs": pairs, "chosen": chosen, "not_fitted": not_fitted,
                "nominal_heldout_err": nom_held_err}

    def named(self, name: str, sel: dict) -> Candidate:
        """The candidate ``name`` (``a+b`` for several causes) of the split of ``sel``: already fitted
        there, or fitted now (judged against the nominal model)."""
        found = [c for c in sel["singles"] + sel["pairs"] if _pick_name(c) == name]
        if found:
            return found[0]
        train, heldout, d = sel["train"], sel["heldout"], self.data
        nom_train = self.nominal.subset(train)
        ev = Evaluator(d.q[train], self.direction[train])
        parts = [c for c in sel["singles"] + sel["pairs"] if set(c.causes) < set(name.split("+"))]
        start = max(parts, key=lambda c: len(c.causes), default=None)
        eff = make_effect(name) if start is None else Combined(
            [start.fit.effect, make_effect("+".join(c for c in name.split("+") if c not in start.causes))])
        x_start = None if start is None else np.concatenate(
            [start.fit.x, eff.effects[1].x0(self.robot, self.calibration)])
        c = self._candidate(eff, ev, d.tips_mm[train], nom_train, heldout, x_start=x_start)
        self._judge(c, sel["nominal_heldout_err"], sel["nominal_bic"])
        c.delta_bic = c.delta_bic_ref
        self.solves += ev.solves
        sel["pairs"].append(c)
        return c

    def bootstrap(self, sel: dict, draws: int) -> dict[str, float]:
        """Share of bootstrap draws of the held-out rows in which each cause set is selected (the
        fits and training BICs kept; the held-out test of `_compare` redone on the draw)."""
        if draws <= 0:
            return {}
        rng = np.random.default_rng(self.opt.seed)
        nom = sel["nominal_heldout_err"]
        h = len(nom)
        counts: dict[str, int] = {}
        opt = self.opt
        for _ in range(draws):
            idx = rng.integers(0, h, h)
            ok = [c for c in sel["singles"] if c.delta_bic < -opt.bic_margin and not c.off_limits()
                  and _compare(c.heldout_err[idx], nom[idx], opt.alpha, opt.min_gain)[2]]
            pick = min(ok, key=lambda c: c.fit.bic) if ok else None
            while pick is not None:
                more = [c for c in sel["pairs"] if c.reference == pick.cause
                        and c.delta_bic_ref < -opt.bic_margin and not c.off_limits()
                        and _compare(c.heldout_err[idx], pick.heldout_err[idx], opt.alpha,
                                     opt.min_gain)[2]]
                if not more:
                    break
                pick = min(more, key=lambda c: c.fit.bic)
            key = _pick_name(pick)
            counts[key] = counts.get(key, 0) + 1
        return {k: v / draws for k, v in sorted(counts.items(), key=lambda t: -t[1])}


__all__ = ["Candidate", "DiagnoseOptions", "Diagnosis", "diagnose", "error_stats", "write_outputs"]


def write_outputs(diag: Diagnosis, out_dir: str | Path, plots: bool = True) -> list[Path]:
    """Write the extended robot file, ``report.json``, ``report.txt`` and the plots into ``out_dir``
    (created if needed). Every file is written atomically, after the diagnosis is complete."""
    import json

    from ctrplan.calibration.calibration import write_extended_robot
    from ctrplan.dataio import atomic_write, output_dir

    out = output_dir(out_dir)
    j = diag.to_json()
    cause = " + ".join(diag.causes) if diag.causes else "none"
    comment = (f"Extended robot written by `ctrplan diagnose` from {diag.data.source}\n"
               f"base robot: {diag.robot.name}; cause: {cause}\n"
               f"held-out tip error {j['nominal']['mean_mm']:.3f} -> {j['extended']['mean_mm']:.3f} mm "
               f"({j['gain_pct']:.1f} % lower), {j['heldout_rows']} held-out rows")
    robot_path = out / "extended_robot.yaml"
    write_extended_robot(robot_path, diag.extended_robot, diag.extended_calibration, comment)
    paths = [robot_path]
    with atomic_write(out / "report.json") as fh:
        json.dump(j, fh, indent=2, allow_nan=False, default=_json_default)
        fh.write("\n")
    paths.append(out / "report.json")
    with atomic_write(out / "report.txt") as fh:
        fh.write(diag.summary() + "\n")
    paths.append(out / "report.txt")
    if plots:
        from ctrplan.calibration.plots import write_plots

        paths += write_plots(diag, out)
    return paths


def _json_default(obj):
    if isinstance(obj, (np.floating, np.integer)):
        return obj.item()
    raise TypeError(f"not JSON serialisable: {type(obj)}")


def clean_json(obj):
    """Replace non-finite floats by None (JSON has no NaN/inf)."""
    if isinstance(obj, dict):
        return {k: clean_json(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [clean_json(v) for v in obj]
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        return v if np.isfinite(v) else None
    if isinstance(obj, np.integer):
        return int(obj)
    return obj
