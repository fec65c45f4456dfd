"""Diagnosis: what the nominal model gets wrong on measured tips, which physical cause explains it,
the extended model and its held-out gain.

Procedure (`diagnose`):

1. split the rows (`split.split_rows`): contiguous blocks held out at random, or the last rows;
2. nominal errors per tube and where they grow (joints, direction of motion, residual direction); the
   measurement noise from the data alone (`noise.estimate_noise`), independent of any fitted model;
3. fit every candidate cause (`ctrplan.model.causes`) on the training rows (least squares on all measured
   tube tips, finite-difference Jacobians, warm-started batched Cosserat solves); parameters the data
   cannot show (`Effect.unseen`, e.g. the offset of a joint that never moves) are not fitted, and
   joint offsets stay within what keeps every row of the file physical;
4. choose (`selection`): significant (repeated configurations counted once), plausible within its
   confidence interval, resolved by the rows, not pushed past a bound, stable across ``resamples``
   other splits, and the simplest of the best -- with the ties the data cannot tell apart, and
   (`experiment`) the configurations that would separate them;
5. outliers (rows far off the extended model) are reported; if some are training rows, the choice is
   repeated without them, warm-started from the first (and the report says so);
6. verdict: ``explained`` when the extended model's held-out error is within ``noise_tolerance`` x
   the noise; with no cause named, ``none`` if the nominal model is, ``undetermined`` if the rows
   cannot identify a cause (`Selection.undetermined` says why; no extended robot is written), else
   ``unexplained``.

Over 500 lines because it holds the procedure end to end (the steps above and the `Diagnosis` they
fill, with its JSON and text report); each step's own work lives in its module.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy import stats

from ctrplan.base.dataio import plain
from ctrplan.base.errors import InputError
from ctrplan.calibration.data import MeasuredData, rows_text
from ctrplan.calibration.experiment import Experiment, separating_rows
from ctrplan.calibration.fit import Evaluator, Prediction
from ctrplan.calibration.noise import estimate_noise
from ctrplan.calibration.options import DiagnoseOptions
from ctrplan.calibration.selection import Candidate, Selection, Selector, configuration_groups
from ctrplan.calibration.split import Split, contiguous_subsample
from ctrplan.model.causes.base import make_effect
from ctrplan.model.measurement import motion_direction
from ctrplan.model.robot import Robot


@dataclass
class Diagnosis:
    """Everything `diagnose` found; `to_json` gives the docs/design.md §3 document."""

    data: MeasuredData                # the rows diagnosed (all, or max_rows of them)
    rows_in_file: int
    robot: Robot                      # the base model (its calibration included)
    options: DiagnoseOptions
    direction: np.ndarray             # direction of motion of every row (R, 2N)
    selection: Selection
    unsolved: np.ndarray              # rows the nominal model could not solve (excluded)
    nominal: Prediction               # all rows
    extended: Prediction              # all rows (== nominal when no cause is named)
    outliers: np.ndarray              # row indices
    outliers_refit: bool
    where: dict = field(default_factory=dict)
    sensitivity: np.ndarray | None = None   # d tips / d q of the nominal model (R, 2N, T, 3)
    seconds: float = 0.0
    solves: int = 0
    noise: dict = field(default_factory=dict)          # `noise.estimate_noise`
    experiment: Experiment | None = None               # configurations that separate the ties

    # ---- the choice -------------------------------------------------------------------------------
    @property
    def chosen(self) -> Candidate | None:
        return self.selection.chosen

    @property
    def candidates(self) -> list[Candidate]:
        return self.selection.candidates

    @property
    def train(self) -> np.ndarray:
        return self.selection.split.train

    @property
    def heldout(self) -> np.ndarray:
        return self.selection.split.heldout

    @property
    def causes(self) -> tuple[str, ...]:
        return () if self.chosen is None else self.chosen.causes

    @property
    def cause(self) -> str:
        """The primary named cause; ``none`` only when the nominal model matches to the noise,
        ``undetermined`` when it does not and the rows cannot identify a cause
        (`Selection.undetermined` says why), ``unexplained`` when no candidate of the library beats it."""
        if self.chosen is not None:
            return self.chosen.causes[0]
        if self.within_noise("nominal"):
            return "none"
        return "undetermined" if self.selection.undetermined else "unexplained"

    @property
    def extended_robot(self) -> Robot:
        """The base robot extended by the named causes: one `Robot`, its measurement side in its
        calibration, its mechanics in its tubes, loads and joint offsets."""
        if self.chosen is None:
            return self.robot
        return self.chosen.fit.robot.with_changes(name=f"{self.robot.name}-{'+'.join(self.causes)}")

    # ---- errors -----------------------------------------------------------------------------------
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

    def unexplained_mm(self) -> float | None:
        """RMS held-out tip error (tube 1) the noise does not account for:
        sqrt(max(mean |e|^2 - 3 sigma^2, 0)), mm."""
        sigma = self.noise.get("sigma_mm")
        if sigma is None:
            return None
        e = self.errors("extended")[self.heldout, 0]
        e = e[np.isfinite(e)]
        return float(np.sqrt(max(float(np.mean(e * e)) - 3.0 * sigma ** 2, 0.0))) if e.size else None

    def errors(self, which: str = "nominal") -> np.ndarray:
        """Per-row, per-tube tip error (R, T), mm, NaN where unmeasured or unsolved."""
        pred = self.nominal if which == "nominal" else self.extended
        return np.linalg.norm(self.data.tips_mm - pred.tips_mm, axis=-1)

    def residuals(self, which: str = "nominal") -> np.ndarray:
        """measured - predicted (R, T, 3), mm, in the robot frame of the respective model."""
        pred = self.nominal if which == "nominal" else self.extended
        calib = (self.robot if which == "nominal" else self.extended_robot).calibration
        return calib.to_robot_frame(self.data.tips_mm) - calib.to_robot_frame(pred.tips_mm)

    def arc_lengths(self) -> np.ndarray:
        """Arc length of each tube's tip (R, T), mm (reported joints plus the base offsets)."""
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

    def remaining(self) -> dict:
        """Where the extended model's error still lives (all solved rows, tube 1): per-tube held-out
        means, the joint it grows with, the direction-of-motion split and the mean offset."""
        rows = np.setdiff1d(np.arange(len(self.data)), self.unsolved)
        err = self.errors("extended")[rows, 0]
        q = self.data.q[rows]
        names = self.robot.joint_names
        half = len(names) // 2
        by_joint = {name: float(stats.spearmanr(q[:, j], err).statistic)
                    for j, name in enumerate(names) if np.ptp(q[:, j]) > 1e-12}
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
                "mean_residual_mm": mean, "findings": findings}

    # ---- report -----------------------------------------------------------------------------------
    def stability(self) -> dict:
        """On how many splits each candidate significantly beat the nominal model."""
        sel, opt = self.selection, self.options
        return {"splits": sel.splits,
                "significant_splits": {c.name: c.significant_splits() for c in sel.candidates
                                       if c.significant_splits()},
                "method": f"every candidate that beat the nominal model on the main split refitted on "
                          f"{len(sel.resample_splits)} other splits ("
                          + ("blocks of the training rows" if sel.split.last else "other contiguous blocks")
                          + f", fits warm-started); stable: significant on at least "
                            f"{opt.stable_fraction:.0%} of the splits"}

    def to_json(self) -> dict:
        """The JSON document of docs/design.md §3 (plus details); non-finite numbers become null."""
        return plain(self._json())

    def _json(self) -> dict:
        d, sel, opt = self.data, self.selection, self.options
        nominal = self.stats("nominal")
        nominal["scope"] = "held-out rows, tip of tube 1 (per_tube: every measured tube)"
        nominal["all_rows"] = self.stats("nominal", np.setdiff1d(np.arange(len(d)), self.unsolved))
        nominal["where"] = self.where
        extended = self.stats("extended")
        extended["scope"] = nominal["scope"]
        chosen = self.chosen
        heldout = set(self.heldout.tolist())
        return {
            "source": d.source,
            "format": d.format,
            "rows": self.rows_in_file,
            "rows_used": len(d),
            "rows_dropped": self.rows_in_file - len(d),
            "train_rows": len(self.train),
            "heldout_rows": len(self.heldout),
            "heldout": {"fraction": sel.split.fraction, "last": sel.split.last, "seed": sel.split.seed,
                        "how": sel.split.describe()},
            "tubes_measured": [t + 1 for t in d.tubes],
            "nominal": nominal,
            "cause": self.cause,
            "causes": list(self.causes),
            "explained": self.explained,
            "unexplained_mm": self.unexplained_mm(),
            "noise_mm": self.noise_mm,
            "noise": self.noise,
            "stability": self.stability(),
            "undetermined": sel.undetermined if self.cause == "undetermined" else None,
            "distinct_configurations": int(np.unique(configuration_groups(d.q, self.direction)).size),
            "ties": [c.name for c in sel.ties],
            "experiment": None if self.experiment is None else self.experiment.to_json(),
            "unstable": [c.name for c in sel.unstable],
            "implausible": {c.name: c.fit.implausible for c in sel.implausible},
            "at_edge": {c.name: c.fit.edge for c in sel.candidates if c.fit.edge},
            "pushed_past_bound": {c.name: c.fit.pushed for c in sel.candidates if c.fit.pushed},
            "unresolved": {c.name: c.fit.unresolved() for c in sel.candidates if c.fit.unresolved()},
            "sources": self.sources(),
            "not_fitted": sel.not_fitted,
            "remaining": self.remaining(),
            "parameters": {} if chosen is None else chosen.fit.parameters(),
            "derived": {} if chosen is None else chosen.fit.derived,
            "extended": extended,
            "gain_pct": self.gain_pct(),
            "candidates": [c.to_json() for c in sel.candidates],
            "selection": {
                "criterion": f"significant: beats the nominal model with delta BIC < -{opt.bic_margin:g} "
                             f"and a held-out mean error lower by >= {100 * opt.min_gain:g} % (one-sided "
                             f"Wilcoxon p < {opt.alpha:g}), plausible parameters inside their bounds; "
                             f"stable: significant on >= {opt.stable_fraction:.0%} of the splits; named: the "
                             f"fewest causes among the stable candidates no other beats on the pooled "
                             f"held-out rows; of those the data cannot tell apart (training BIC, or the "
                             f"fit without its parameter penalty, within {opt.bic_margin:g}) the fewest "
                             f"parameters, then the lowest held-out error; the others are ties",
                "nominal_bic": sel.nominal_bic,
                "noise_tolerance": opt.noise_tolerance,
                "seed": opt.seed,
            },
            "outliers": [{"row": int(d.lines[i]), "error_mm": float(np.nanmean(self.errors("extended")[i])),
                          "split": "heldout" if i in heldout else "train"} for i in self.outliers],
            "outliers_excluded_from_fit": self.outliers_refit,
            "outside_domain_rows": d.lines[d.outside_domain],
            "unsolved_rows": d.lines[self.unsolved],
            "seconds": round(self.seconds, 2),
            "solves": self.solves,
        }

    def sources(self) -> dict[str, str]:
        """The source of every plausible range a report line refers to, by check name (once each)."""
        return {k: v for c in self.candidates for k, v in sorted(c.fit.sources.items())}

    def summary(self) -> str:
        """A human-readable report (the CLI prints it without --json)."""
        j = self.to_json()
        return "\n".join(self._summary_rows(j) + self._summary_candidates(j) + self._summary_verdict(j)
                         + _summary_tail(j))

    def _summary_rows(self, j: dict) -> list[str]:
        used = "" if j["rows_used"] == j["rows"] else (
            f", {j['rows_used']} used in contiguous runs ({j['rows_dropped']} dropped by max_rows)")
        m = j["distinct_configurations"]
        lines = [f"{self.data.source}: {j['rows']} rows{used}, {m} distinct configuration{'s' * (m != 1)} "
                 f"({j['train_rows']} train, {j['heldout']['how']}), tubes measured: "
                 f"{j['tubes_measured']}"]
        if j["outside_domain_rows"]:
            lines.append(f"  note: {rows_text(j['outside_domain_rows'])} lie outside the snap-free "
                         f"planning domain (accepted)")
        if j["unsolved_rows"]:
            lines.append(f"  note: the nominal model does not solve {rows_text(j['unsolved_rows'])} "
                         f"(excluded)")
        lines.append("nominal model, held-out error per tube:")
        for t in j["nominal"]["per_tube"]:
            lines.append(f"  tube {t['tube']}: mean {t['mean_mm']:.3f} mm, median {t['median_mm']:.3f}, "
                         f"p95 {t['p95_mm']:.3f}, {t['mean_pct_length']:.2f} % of arc length")
        lines += [f"  where: {s}" for s in self.where.get("findings", [])]
        return lines

    def _summary_candidates(self, j: dict) -> list[str]:
        splits = self.selection.splits
        lines = [f"candidates (training BIC, held-out mean tip error, splits of {splits} where "
                 f"significant; * significant on the main split):"]
        for c in sorted(self.candidates, key=lambda c: c.fit.bic):
            ref = "" if c.reference == "nominal" else f" vs {c.reference}"
            bad = " IMPLAUSIBLE" if c.fit.implausible else ""
            bad += " UNRESOLVED" if c.fit.unresolved() else ""
            bad += " PAST-BOUND" if c.fit.pushed else ""
            lines.append(f"  {'*' if c.significant else ' '} {c.name:<34s} dBIC {c.delta_bic:10.1f}  "
                         f"held-out {c.heldout_mean(0):.3f} mm  gain {100 * c.main.gain:5.1f} %{ref}  "
                         f"{c.significant_splits()}/{splits}{bad}")
        lines += [f"  not fitted: {name} ({'; '.join(why)})" for name, why in j["not_fitted"].items()]
        fixed = {k: v for c in self.candidates if len(c.causes) == 1 for k, v in c.fit.fixed.items()}
        if fixed:
            lines.append("  held at their file values (the data cannot show them):")
            lines += [f"    {k}: {v}" for k, v in fixed.items()]
        for title, key in (("implausible, not named", "implausible"), ("at its bound, not named",
                                                                        "pushed_past_bound")):
            lines += [f"  {title}: {name}: " + "; ".join(f"{k} {v}" for k, v in why.items())
                      for name, why in j[key].items()]
        lines += [f"  not resolved by the rows, not named: {name}: {', '.join(ps)}"
                  for name, ps in j["unresolved"].items()]
        noise_mm = j["noise_mm"]
        noise_txt = "not estimated" if noise_mm is None else f"{noise_mm:.3f} mm mean tip error"
        lines.append(f"measurement noise: {noise_txt} ({j['noise']['method']})")
        return lines

    def _summary_verdict(self, j: dict) -> list[str]:
        nom, ext = j["nominal"], j["extended"]
        if self.chosen is None:
            off = f"the nominal model is off by {nom['mean_mm']:.3f} mm"
            return [{"none": "cause: none -- the nominal model matches the held-out rows to the measurement "
                             "noise",
                     "undetermined": f"cause: undetermined -- {off}, but the rows cannot identify a cause: "
                                     f"{j['undetermined']}; nothing named, no extended robot",
                     "unexplained": f"cause: unexplained -- {off} (noise {_noise_text(j)}) and no plausible "
                                    f"cause of the library beats it on the splits"}[j["cause"]]]
        lines = [f"cause: {' + '.join(self.causes)}"]
        if j["ties"]:
            lines.append(f"  tie: {', '.join(j['ties'])} fit as well (neither is better on the held-out "
                         "rows, and the training BIC is within its margin or its preference does not "
                         "repeat there); the data do not tell them apart: the fewest parameters is named, "
                         "tentatively" + ("; experiment.csv lists configurations that separate them"
                                          if self.experiment is not None else ""))
        if j["unstable"]:
            lines.append("  not named (significant on too few splits): " + ", ".join(j["unstable"]))
        lines += [_parameter_line(name, p) for name, p in j["parameters"].items()]
        if j["derived"]:
            lines.append("  i.e. " + ", ".join(f"{k} = " + ("not determined" if v is None else f"{v:.4g}")
                                               for k, v in j["derived"].items()))
        lines.append(f"held-out tip error: {nom['mean_mm']:.3f} -> {ext['mean_mm']:.3f} mm mean, "
                     f"{nom['p95_mm']:.3f} -> {ext['p95_mm']:.3f} mm p95 (gain {j['gain_pct']:.1f} %)")
        return lines


def _noise_text(j: dict) -> str:
    return "not estimated" if j["noise_mm"] is None else f"{j['noise_mm']:.3f} mm mean tip error"


def _parameter_line(name: str, p: dict) -> str:
    """One fitted parameter of the report: value +- std (unit), its base value, and what is special."""
    if p.get("fitted") is False:
        return f"  {name} not fitted: {p['reason']}"
    std = "n/a (at its bound)" if p.get("at_bound") else ("n/a" if p["std"] is None else f"{p['std']:.3g}")
    extra = ""
    if p["unit"] == "rad":
        extra = f"  ({np.degrees(p['value']):.3f} deg +- " + (
            "n/a" if p["std"] is None else f"{np.degrees(p['std']):.3f}") + ")"
    if p.get("at_edge"):
        extra += f"  at the edge of its plausible range: {p['at_edge']}"
    return f"  {name} = {p['value']:.6g} +- {std} {p['unit']} (was {p['nominal']:.6g}){extra}"


def _summary_tail(j: dict) -> list[str]:
    """Not explained, outliers, the sources of the plausible ranges cited above (once each), time."""
    lines = []
    if not j["explained"] and j["cause"] not in ("undetermined",):
        left = "?" if j["unexplained_mm"] is None else f"{j['unexplained_mm']:.3f}"
        lines.append(f"NOT EXPLAINED: the library does not explain the data -- {left} mm RMS of "
                     f"held-out tip error is beyond the noise")
        lines += [f"  where: {f}" for f in j["remaining"]["findings"]]
    if j["outliers"]:
        o = j["outliers"]
        fate = "excluded from the fit" if j["outliers_excluded_from_fit"] else "kept in the fit"
        lines.append(f"outliers (reported, {fate}): "
                     + ", ".join(f"row {x['row']} ({x['error_mm']:.2f} mm)" for x in o[:10])
                     + (f" and {len(o) - 10} more" if len(o) > 10 else ""))
    cited = {k for why in list(j["implausible"].values()) + list(j["at_edge"].values()) for k in why}
    texts = sorted({j["sources"][k] for k in cited if k in j["sources"]})
    if texts:
        lines.append("plausible ranges from: " + "; ".join(f"[{i + 1}] {t}" for i, t in enumerate(texts)))
    lines.append(f"time: {j['seconds']:.1f} s ({j['solves']} Cosserat solves)")
    return lines


def error_stats(err: np.ndarray, length: np.ndarray) -> dict:
    ok = np.isfinite(err)
    e, L = err[ok], length[ok]
    if e.size == 0:
        return {"mean_mm": None, "median_mm": None, "p95_mm": None, "max_mm": None,
                "mean_pct_length": None}
    return {"mean_mm": float(e.mean()), "median_mm": float(np.median(e)),
            "p95_mm": float(np.percentile(e, 95)), "max_mm": float(e.max()),
            "mean_pct_length": float(np.mean(100.0 * e / L))}


def diagnose(data: MeasuredData, robot: Robot | None = None, options: DiagnoseOptions | None = None, *,
             direction: np.ndarray | None = None, progress: Callable[[str], None] | None = None) -> Diagnosis:
    """Diagnose measured tips against ``robot`` (nominal if None; its calibration is part of the base
    model); see the module docstring.

    ``direction`` (R, 2N): direction of motion of every row, when ``data`` is a subset of a longer
    acquisition (default: from the rows of ``data``, `motion_direction`). ``progress`` is called with
    a line saying what runs now (each fit, the experiment)."""
    t0 = time.perf_counter()
    robot = robot or Robot.nominal()
    opt = options or DiagnoseOptions()
    for c in opt.candidates:
        make_effect(c)  # validates names
    if data.q.shape[1] != robot.n_joints:
        raise InputError(f"{data.source}: the data have {data.q.shape[1] // 2} tubes, robot {robot.name!r} "
                         f"has {robot.n_tubes}")
    rows_in_file = len(data)
    direction_file = motion_direction(data.q) if direction is None else np.asarray(direction, dtype=float)
    q_file, direction = data.q, direction_file
    if len(data) > opt.max_rows:
        keep = contiguous_subsample(len(data), opt.max_rows)
        data, direction = data.subset(keep), direction[keep]
    ev_all = Evaluator(data.q, direction)
    nominal = ev_all.predict([robot])[0]
    unsolved = np.flatnonzero(~nominal.converged)
    solved = np.setdiff1d(np.arange(len(data)), unsolved)
    noise = estimate_noise(data.q[solved], direction[solved], (data.tips_mm - nominal.tips_mm)[solved],
                           data.tubes)
    selector = Selector(data, robot, opt, direction, nominal, q_file, direction_file, progress)

    def without(split: Split, drop: np.ndarray) -> Split:
        return replace(split, train=np.setdiff1d(split.train, np.union1d(unsolved, drop)),
                       heldout=np.setdiff1d(split.heldout, unsolved))

    main = opt.split(len(data))
    resamples = [main.resample(opt.seed + r) for r in range(1, opt.resamples + 1)]
    sel = selector.select(without(main, unsolved), [without(s, unsolved) for s in resamples])
    extended = _extended(ev_all, sel, nominal)
    outliers = _outliers(data, extended, unsolved, opt.outlier_mads)
    refit = bool(np.intersect1d(outliers, sel.split.train).size)
    if refit:
        sel = selector.select(without(main, outliers), [without(s, outliers) for s in resamples])
        extended = _extended(ev_all, sel, nominal)
        outliers = _outliers(data, extended, unsolved, opt.outlier_mads)
    diag = Diagnosis(data=data, rows_in_file=rows_in_file, robot=robot, options=opt, direction=direction,
                     selection=sel, unsolved=unsolved, nominal=nominal, extended=extended,
                     outliers=outliers, outliers_refit=refit, noise=noise)
    from ctrplan.calibration.where import where_analysis

    diag.where = where_analysis(diag)
    if sel.chosen is not None and sel.ties and opt.experiment_rows > 0:
        selector.progress(f"experiment: {opt.experiment_rows} configurations that separate the ties")
        diag.experiment = separating_rows(robot, (sel.chosen.name, sel.chosen.fit.robot),
                                          [(t.name, t.fit.robot) for t in sel.ties], data.tubes,
                                          opt.experiment_rows, seed=opt.seed)
    diag.seconds = time.perf_counter() - t0
    diag.solves = ev_all.solves + selector.solves
    return diag


def _extended(ev_all: Evaluator, sel: Selection, nominal: Prediction) -> Prediction:
    if sel.chosen is None:
        return nominal
    return ev_all.predict([sel.chosen.fit.robot], guess=nominal.initial_state)[0]


def _outliers(data: MeasuredData, pred: Prediction, unsolved: np.ndarray, mads: float = 8.0) -> np.ndarray:
    err = np.nanmean(np.linalg.norm(data.tips_mm - pred.tips_mm, axis=-1), axis=1)
    ok = np.isfinite(err)
    med = np.median(err[ok])
    mad = 1.4826 * np.median(np.abs(err[ok] - med))
    thr = max(med + mads * mad, 3.0 * med)
    return np.setdiff1d(np.flatnonzero(ok & (err > thr)), unsolved)


__all__ = ["Diagnosis", "diagnose", "error_stats", "write_outputs"]


def write_outputs(diag: Diagnosis, out_dir: str | Path) -> list[Path]:
    """Write the extended robot file, ``report.json`` and ``report.txt`` into ``out_dir`` (created if
    needed; the residual plots are `ctrplan.viz.diagnosis_plots.write_plots`). Every file is written
    atomically, after the diagnosis is complete."""
    from ctrplan.base.dataio import atomic_write, output_dir

    out = output_dir(out_dir)
    j = diag.to_json()
    cause = " + ".join(diag.causes) if diag.causes else "none"
    comment = (f"Extended robot written by `ctrplan diagnose` from {diag.data.source}\n"
               f"base robot: {diag.robot.name}; cause: {cause}\n"
               f"held-out tip error {j['nominal']['mean_mm']:.3f} -> {j['extended']['mean_mm']:.3f} mm "
               f"({j['gain_pct']:.1f} % lower), {j['heldout_rows']} held-out rows")
    paths = []
    if diag.cause != "undetermined":      # nothing identified: no extended robot
        paths.append(out / "extended_robot.yaml")
        diag.extended_robot.save(paths[-1], comment)
    if diag.experiment is not None:
        paths.append(out / "experiment.csv")
        diag.experiment.write_csv(paths[-1], diag.robot.joint_names)
    with atomic_write(out / "report.json") as fh:
        json.dump(j, fh, indent=2, allow_nan=False)
        fh.write("\n")
    paths.append(out / "report.json")
    with atomic_write(out / "report.txt") as fh:
        fh.write(diag.summary() + "\n")
    paths.append(out / "report.txt")
    return paths
