"""Choosing the causes: candidates fitted on the training rows and judged on the held-out rows, cause
sets grown one cause at a time, every contender refitted on other splits, and the simplest of the best
named.

* **significant** (on a split): beats the nominal model there -- training BIC lower by more than
  ``bic_margin``, held-out mean error lower by at least ``min_gain`` with a one-sided Wilcoxon
  signed-rank test at ``alpha``, no parameter pushed to a hard bound away from its base value, and
  every parameter plausible (`effects.Param.plausible`); a fit that needs an implausible value is
  reported, never named;
* **grown**: from the best significant single (and up to ``grow_from`` - 1 next ones it does not
  beat), and from the best single that beats the nominal model only with an implausible value, the
  ``pairs`` partners a score test ranks first are added and fitted; the best one significant against
  the set it grew from is kept, up to ``max_causes`` causes;
* **contenders**: significant, against the nominal model and against the set they grew from, and not
  beaten on the main split by another contender; each is refitted on ``resamples`` other splits
  (warm-started from its main fit) and scored against the nominal model there;
* **stable**: significant on at least ``stable_fraction`` of the splits (the main one and the others);
* **beats**: one candidate beats another when its held-out errors, paired row by row over all splits,
  are lower by at least ``min_gain`` with a one-sided Wilcoxon test at ``alpha``, and its training BIC
  is not higher by more than ``bic_margin``;
* **named**: among the stable candidates that no stable candidate beats, the one with the fewest
  causes, then the lowest pooled held-out error -- never a subset a larger set beats, and a single
  cause at the noise before a pair. **Ties**: the others of its size among them whose training BIC is
  not higher by more than ``bic_margin`` (equal fits the data cannot tell apart).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from scipy import stats

from ctrplan.calibration.effects import Combined, Effect, make_effect, offset_limits
from ctrplan.calibration.fit import (
    Evaluator,
    FitResult,
    Prediction,
    bic,
    fit_effect,
    partner_scores,
    residual_vector,
)
from ctrplan.calibration.split import Split
from ctrplan.errors import InputError

if TYPE_CHECKING:
    from ctrplan.calibration.data import MeasuredData
    from ctrplan.calibration.diagnosis import DiagnoseOptions
    from ctrplan.robot import Robot


@dataclass
class Score:
    """A candidate on one split, against a reference model: its held-out errors and the tests."""

    heldout_err: np.ndarray      # (h, T) per row and tube, mm (NaN for unmeasured tubes)
    delta_bic: float             # training BIC minus the reference's
    p_value: float               # one-sided Wilcoxon on the held-out rows against the reference
    gain: float                  # relative held-out gain against the reference (pooled over tubes)
    beats: bool                  # held-out gain >= min_gain at p < alpha, and delta_bic < -bic_margin
    significant: bool            # beats, with a plausible fit inside its hard bounds


@dataclass
class Candidate:
    """A cause set fitted on the main split's training rows, and how it does on every split."""

    fit: FitResult
    main: Score                  # against ``reference`` on the main split
    nominal: Score               # against the nominal model on the main split
    reference: str = "nominal"   # nominal, or the cause set it grew from
    resamples: list[Score] = field(default_factory=list)   # against the nominal model, other splits

    @property
    def causes(self) -> tuple[str, ...]:
        return self.fit.effect.causes

    @property
    def name(self) -> str:
        """The cause set, ``a+b`` (in the order it grew)."""
        return "+".join(self.causes)

    @property
    def key(self) -> frozenset[str]:
        return frozenset(self.causes)

    @property
    def heldout_err(self) -> np.ndarray:
        return self.main.heldout_err

    @property
    def significant(self) -> bool:
        return self.main.significant

    def heldout_mean(self, tube: int | None = 0) -> float:
        """Main-split held-out mean error of tube ``tube`` (all measured tubes pooled for None), mm."""
        e = self.heldout_err if tube is None else self.heldout_err[:, tube]
        return float(np.nanmean(e))

    def pooled(self) -> np.ndarray:
        """Per-row held-out error (mean over the measured tubes) over all splits it was scored on."""
        return np.concatenate([_per_row(s.heldout_err) for s in [self.main, *self.resamples]])

    @property
    def delta_bic(self) -> float:
        """Training BIC minus the nominal model's (main split)."""
        return self.nominal.delta_bic

    def significant_splits(self) -> int:
        """Splits on which it significantly beats the nominal model."""
        return int(self.nominal.significant) + sum(s.significant for s in self.resamples)

    def to_json(self) -> dict:
        return {"cause": self.name, "causes": list(self.causes), "parameters": self.fit.parameters(),
                "derived": self.fit.derived, "implausible": self.fit.implausible,
                "heldout_mean_mm": self.heldout_mean(0), "heldout_mean_all_tubes_mm": self.heldout_mean(None),
                "bic": self.fit.bic, "delta_bic": self.delta_bic, "train_rms_mm": self.fit.rms_mm,
                "reference": self.reference, "delta_bic_vs_reference": self.main.delta_bic,
                "heldout_gain_vs_reference_pct": 100.0 * self.main.gain, "p_value": self.main.p_value,
                "significant": bool(self.significant),
                "resamples": [{"heldout_mean_mm": float(np.nanmean(s.heldout_err[:, 0])),
                               "significant": bool(s.significant)} for s in self.resamples],
                "fit_seconds": round(self.fit.seconds, 3), "converged": self.fit.success,
                "at_bound": self.fit.at_bound(), "not_fitted": self.fit.fixed}


@dataclass
class Selection:
    """What `Selector.select` found: every candidate fitted, the named one, its ties, and those left
    out (implausible: beat the nominal model with an implausible value; unstable: significant on the
    main split only)."""

    split: Split
    resample_splits: list[Split]
    nominal_bic: float
    nominal_err: np.ndarray                 # (h, T) main-split held-out errors of the nominal model
    candidates: list[Candidate]
    not_fitted: dict[str, list[str]]        # cause -> why the data cannot show any of its parameters
    chosen: Candidate | None = None
    ties: list[Candidate] = field(default_factory=list)
    unstable: list[Candidate] = field(default_factory=list)
    implausible: list[Candidate] = field(default_factory=list)

    @property
    def splits(self) -> int:
        return 1 + len(self.resample_splits)


class Selector:
    """Fits, judges and chooses candidates on the rows of ``data`` for a base ``robot``.

    ``q_file``/``direction_file``: all rows of the file (identifiability, joint-offset limits and
    physical validity look at every row, also those ``max_rows`` left out)."""

    def __init__(self, data: MeasuredData, robot: Robot, opt: DiagnoseOptions, direction: np.ndarray,
                 nominal: Prediction, q_file: np.ndarray, direction_file: np.ndarray):
        self.data, self.robot, self.opt, self.direction, self.nominal = data, robot, opt, direction, nominal
        self.q_file, self.direction_file = q_file, direction_file
        self.solves = 0

    # ---- fitting and scoring -------------------------------------------------------------------------
    def _heldout_err(self, fit: FitResult, heldout: np.ndarray) -> np.ndarray:
        """Held-out errors (h, T) of a fitted model, mm; rows it does not solve keep the nominal error."""
        nom = self.nominal.subset(heldout)
        ev = Evaluator(self.data.q[heldout], self.direction[heldout])
        pred = ev.predict([fit.robot], guess=nom.initial_state)[0]
        self.solves += ev.solves
        tips = np.where(pred.converged[:, None, None], pred.tips_mm, nom.tips_mm)
        return np.linalg.norm(self.data.tips_mm[heldout] - tips, axis=-1)


    def _fit(self, effect: Effect, split: Split, x_start: np.ndarray | None, max_nfev: int) -> FitResult:
        """Fit ``effect`` on the training rows of ``split``. Every row of the file must stay physical
        under the fitted robot: if a joint offset makes one impossible, the fit is repeated with the
        offsets bounded so that each tube keeps every row physical on its own (``share`` 1), and then
        whatever the others do (``share`` 0.5)."""
        d = self.data
        ev = Evaluator(d.q[split.train], self.direction[split.train])
        fixed = effect.unseen(self.q_file, self.direction_file, self.robot)
        limits = effect.limits(self.q_file, self.robot)
        fit = None
        for share in (None, 1.0, 0.5):
            if fit is not None and self._physical(fit.robot):
                break
            bounds = limits if share is None else limits | offset_limits(self.q_file, self.robot, share=share)
            fit = fit_effect(effect, self.robot, ev, d.tips_mm[split.train], d.tubes,
                             self.nominal.subset(split.train), x_start=x_start if fit is None else fit.x,
                             max_nfev=max_nfev, fixed=fixed, limits=bounds)
        self.solves += ev.solves
        return fit

    def _physical(self, robot: Robot) -> bool:
        """Whether every row of the file is physically possible for ``robot`` (outside the domain is)."""
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                robot.check_joints(self.q_file, allow_outside_domain=True)
        except InputError:
            return False
        return True

    def _nominal(self, split: Split) -> tuple[np.ndarray, float]:
        """The nominal model's held-out errors and training BIC on ``split``."""
        d = self.data
        r = residual_vector(d.tips_mm[split.train], self.nominal.subset(split.train), d.tubes)
        err = np.linalg.norm(d.tips_mm[split.heldout] - self.nominal.tips_mm[split.heldout], axis=-1)
        return err, bic(float(r @ r), r.size, 0)

    # ---- the main split ------------------------------------------------------------------------------
    def select(self, split: Split, resample_splits: list[Split]) -> Selection:
        """Fit every candidate on ``split``, grow cause sets, refit the significant ones on
        ``resample_splits`` and choose (see the module docstring)."""
        opt = self.opt
        nom_err, nom_bic = self._nominal(split)
        cands: dict[frozenset[str], Candidate] = {}
        not_fitted: dict[str, list[str]] = {}
        for name in opt.candidates:
            effect = make_effect(name)
            unseen = effect.unseen(self.q_file, self.direction_file, self.robot)
            if all(p.name in unseen for p in effect.params(self.robot)):
                not_fitted[name] = sorted(set(unseen.values()))
                continue
            fit = self._fit(effect, split, None, opt.max_nfev)
            score = judge(fit, self._heldout_err(fit, split.heldout), nom_err, nom_bic, self.opt)
            cands[frozenset(effect.causes)] = Candidate(fit=fit, main=score, nominal=score)
        singles = sorted((c for c in cands.values() if c.significant), key=lambda c: c.heldout_mean(None))
        seeds = singles[:1] + [c for c in singles[1:] if not beats(singles[0], c, opt, pooled=False)]
        # a single that beats the nominal model only with an implausible value may stand in for a cause
        # it lacks (a sensor offset pushed sideways by backlash): grow from the best one too; only a
        # plausible set can be named
        stand_ins = sorted((c for c in cands.values() if c.main.beats and c.fit.implausible),
                           key=lambda c: c.heldout_mean(None))
        for seed in seeds[:opt.grow_from] + stand_ins[:1]:
            self._grow(seed, split, cands, nom_err, nom_bic)
        sel = Selection(split=split, resample_splits=resample_splits, nominal_bic=nom_bic,
                        nominal_err=nom_err, candidates=list(cands.values()), not_fitted=not_fitted)
        self._resample(sel)
        choose(sel, opt)
        return sel

    def _grow(self, chosen: Candidate, split: Split, cands: dict[frozenset[str], Candidate],
              nom_err: np.ndarray, nom_bic: float) -> None:
        """Add causes to ``chosen`` one at a time while the best addition is significant against it."""
        opt, d = self.opt, self.data
        ev = Evaluator(d.q[split.train], self.direction[split.train])
        while opt.pairs > 0 and len(chosen.causes) < opt.max_causes:
            mine = {p.name for p in chosen.fit.params}
            partners = [c for c in cands.values() if len(c.causes) == 1 and c.causes[0] not in chosen.causes
                        and not mine & {p.name for p in c.fit.params}]
            if not partners:
                break
            scores = partner_scores(chosen.fit, [c.fit.effect for c in partners], ev, d.tips_mm[split.train],
                                    d.tubes, self.nominal.subset(split.train))
            self.solves += ev.solves
            order = np.argsort(scores, kind="stable")[:opt.pairs]
            ranked = [partners[i] for i in order]
            grown = []
            for partner in ranked:
                key = chosen.key | partner.key
                if key not in cands:
                    effect = Combined([chosen.fit.effect, partner.fit.effect])
                    x_start = np.concatenate([chosen.fit.x, partner.fit.x0])
                    fit = self._fit(effect, split, x_start, opt.max_nfev)
                    err = self._heldout_err(fit, split.heldout)
                    cands[key] = Candidate(fit=fit, reference=chosen.name,
                                           main=judge(fit, err, chosen.heldout_err, chosen.fit.bic, opt),
                                           nominal=judge(fit, err, nom_err, nom_bic, opt))
                grown.append(cands[key])
            better = [c for c in grown if c.significant and c.reference == chosen.name]
            if not better:
                break
            chosen = min(better, key=lambda c: c.heldout_mean(None))

    # ---- other splits --------------------------------------------------------------------------------
    def _resample(self, sel: Selection) -> None:
        """Refit the contenders on each resample split (warm-started from their main fit) and score
        them against the nominal model there."""
        good = [c for c in sel.candidates if c.nominal.significant and c.main.significant]
        contenders = [c for c in good
                      if not any(beats(o, c, self.opt, pooled=False) for o in good if o is not c)]
        for rs in sel.resample_splits:
            nom_err, nom_bic = self._nominal(rs)
            for c in contenders:
                fit = self._fit(c.fit.effect, rs, c.fit.x, self.opt.resample_nfev)
                err = self._heldout_err(fit, rs.heldout)
                c.resamples.append(judge(fit, err, nom_err, nom_bic, self.opt))


def judge(fit: FitResult, err: np.ndarray, ref_err: np.ndarray, ref_bic: float,
          opt: DiagnoseOptions) -> Score:
    """Score a fit with held-out errors ``err`` (h, T) against a reference model (its held-out errors
    on the same rows and its training BIC)."""
    gain, p, held_ok = compare(err, ref_err, opt.alpha, opt.min_gain)
    d_bic = fit.bic - ref_bic
    ok = held_ok and d_bic < -opt.bic_margin
    return Score(heldout_err=err, delta_bic=d_bic, p_value=p, gain=gain, beats=ok,
                 significant=ok and not fit.implausible and not off_limits(fit))


def choose(sel: Selection, opt: DiagnoseOptions) -> None:
    """Name the candidate of ``sel`` (see the module docstring); fill its ties, the unstable and the
    implausible candidates."""
    need = opt.stable_fraction * sel.splits - 1e-9
    stable = [c for c in sel.candidates if c.significant_splits() >= need]
    sel.unstable = [c for c in sel.candidates if c.resamples and c.significant_splits() < need]
    sel.implausible = [c for c in sel.candidates if c.nominal.beats and c.fit.implausible]
    free = [c for c in stable if not any(beats(o, c, opt) for o in stable if o is not c)]
    if not free:
        sel.chosen, sel.ties = None, []
        return
    size = min(len(c.causes) for c in free)
    best = min((c for c in free if len(c.causes) == size), key=lambda c: float(np.mean(c.pooled())))
    sel.chosen = best
    sel.ties = [c for c in free if c is not best and len(c.causes) == size
                and c.fit.bic <= best.fit.bic + opt.bic_margin]


def beats(a: Candidate, b: Candidate, opt: DiagnoseOptions, pooled: bool = True) -> bool:
    """Whether ``a`` is better than ``b``: held-out errors (paired rows of every split, or of the main
    split only) lower by at least ``min_gain`` at significance ``alpha``, training BIC not higher by
    more than ``bic_margin``."""
    if a.fit.bic > b.fit.bic + opt.bic_margin:
        return False
    ea, eb = (a.pooled(), b.pooled()) if pooled else (_per_row(a.heldout_err), _per_row(b.heldout_err))
    if ea.shape != eb.shape:
        return False
    return compare(ea[:, None], eb[:, None], opt.alpha, opt.min_gain)[2]


def off_limits(fit: FitResult) -> list[str]:
    """Parameters at a hard bound of their effect other than their base value: the model stops making
    sense there. (A limit the rows set -- a joint offset that puts a row at the edge of what is
    physical -- is not one: a robot driven to its mechanical limits sits there.)"""
    return [p.name for p, v, v0 in zip(fit.params, fit.x, fit.x0, strict=True) if p.name not in fit.fixed
            and any(abs(v - b) < 1e-4 * p.scale and abs(v0 - b) > 1e-9 for b in (p.lower, p.upper))]


def _per_row(err: np.ndarray) -> np.ndarray:
    return np.nanmean(err, axis=1)


def compare(cand_err: np.ndarray, ref_err: np.ndarray, alpha: float,
            min_gain: float) -> tuple[float, float, bool]:
    """Relative gain, p-value and whether the candidate's held-out errors (R, T) beat the reference's
    (R, T): per row the mean over tubes, a gain of at least ``min_gain`` and a one-sided Wilcoxon
    signed-rank test at ``alpha``."""
    a, b = _per_row(ref_err), _per_row(cand_err)
    gain = 1.0 - b.mean() / a.mean() if a.mean() > 0 else 0.0
    diff = a - b
    if np.allclose(diff, 0.0):
        return float(gain), 1.0, False
    # the exact null distribution where it is cheap (<= 50 rows, no zeros or ties); the normal
    # approximation otherwise
    exact = diff.size <= 50 and np.all(diff != 0) and np.unique(np.abs(diff)).size == diff.size
    try:
        p = float(stats.wilcoxon(diff, alternative="greater", method="exact" if exact else "approx").pvalue)
    except ValueError:
        p = 1.0
    return float(gain), p, bool(gain >= min_gain and p < alpha)
