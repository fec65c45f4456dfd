"""Fitting a candidate effect to measured tips: batched Cosserat solves, warm starts, cheap
finite-difference Jacobians, least squares, uncertainty and BIC.

A model is one `Robot`: its mechanics solved by the Cosserat backend, its calibration mapping the
reported joints to the mechanics and the solved tips to the tracker (`ctrplan.model.measurement`).

Cost model: a Jacobian costs one batched forward call per parameter that changes the mechanics
(curvature, stiffness, loads: the kernel takes robot parameters per call); parameters that only
change the joints the mechanics sees (joint offsets, latency, backlash, friction, windup) act through
d tips / d q, one batched call per joint they move (the chain rule: a friction of nine slip elements
on three moving joints costs three calls, not nine); tip and frame perturbations (sensor offset,
registration) need no solve at all. A trial the solver cannot solve (a joint offset that pulls a
tube behind the plate, a NaN) is a row without a solution: it keeps its last prediction, and the
trust region shrinks back from it. Every solve is warm-started
from the solution of the same row at the current parameters (`Backbone.initial_state`), so Newton
needs 1-3 steps.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from ctrplan.calibration.predict import TRIAL_SOLVER, Evaluator, Prediction, View
from ctrplan.model.causes.base import CONFIDENCE_Z, Effect, Param
from ctrplan.model.robot import Robot

FD_STEP = 1e-3  # finite-difference step in units of each parameter's typical scale
JOINT_STEP = 1e-4  # finite-difference step of a joint (mm or rad) for parameters that act through the joints
FIT_TOL = 1e-5  # relative tolerance of least squares on the cost and on the parameter step
#: The Jacobian is reused while the parameters stay this close (typical deviations) to where it was
#: computed: the last steps of a fit are short, the model is smooth on that scale.
JAC_REUSE = 0.1
#: A direction of the scaled Jacobian with a relative singular value below this is not resolved.
RESOLVED_SV = 1e-6
#: A parameter known no better than this many typical lab deviations (``Param.scale``) is not resolved.
RESOLVED_SCALES = 10.0


@dataclass
class FitResult:
    """A fitted effect. Parameters in file units; ``std`` from ``s^2 (J^T J)^-1``. ``params`` are the
    effect's own (their hard bounds); ``lower``/``upper`` the bounds the fit kept to, tightened by
    limits the rows set (e.g. joint offsets that keep every row physical)."""

    effect: Effect
    params: list[Param]
    lower: np.ndarray
    upper: np.ndarray
    x0: np.ndarray
    x: np.ndarray
    std: np.ndarray
    robot: Robot                 # the fitted model (its calibration included)
    rss: float
    n_residuals: int
    bic: float
    nfev: int
    njev: int
    success: bool
    message: str
    seconds: float = 0.0
    identifiable: np.ndarray = field(default=None)  # type: ignore[assignment]
    #: parameters held at their base value, with the reason (e.g. the joint never moves)
    fixed: dict[str, str] = field(default_factory=dict)
    #: parameters (or quantities derived from them) outside what a real robot can have -> why
    implausible: dict[str, str] = field(default_factory=dict)
    #: outside the plausible range, but the confidence interval overlaps it -> value and interval
    edge: dict[str, str] = field(default_factory=dict)
    #: the plausible ranges' sources of the checks in ``implausible`` and ``edge``
    sources: dict[str, str] = field(default_factory=dict)
    #: readable quantities derived from ``x``; None where the interval of ``x`` reaches a singularity
    derived: dict[str, float | None] = field(default_factory=dict)
    #: free parameters at a bound of the fit that the data push past it -> why
    pushed: dict[str, str] = field(default_factory=dict)
    cov: np.ndarray | None = None   # covariance of ``x`` (file units; inf where not resolved)

    @property
    def name(self) -> str:
        return self.effect.name

    @property
    def k(self) -> int:
        """Number of fitted (free) parameters."""
        return len(self.params) - len(self.fixed)

    def at_bound(self) -> list[str]:
        """Free parameters the data pushed to a bound of the fit (their std is not meaningful)."""
        return [p.name for p, v, lo, hi in zip(self.params, self.x, self.lower, self.upper, strict=True)
                if p.name not in self.fixed and min(abs(v - lo), abs(v - hi)) < 1e-4 * p.scale]

    def unresolved(self) -> list[str]:
        """Free parameters the rows do not resolve (rank-deficient or ill-conditioned Jacobian)."""
        return [p.name for p, ok in zip(self.params, self.identifiable, strict=True)
                if p.name not in self.fixed and not ok]

    @property
    def rms_mm(self) -> float:
        return float(np.sqrt(self.rss / max(self.n_residuals, 1)))

    def parameters(self) -> dict[str, dict]:
        """Per parameter: value, std, nominal (base) value, unit, plausible range; ``fitted: false``
        with the reason, ``at_bound`` or ``implausible`` (the reason) where they apply."""
        out = {}
        bound = set(self.at_bound())
        for p, v, s, v0, ok in zip(self.params, self.x, self.std, self.x0, self.identifiable, strict=True):
            out[p.name] = {"value": float(v), "std": float(s) if np.isfinite(s) and ok else None,
                           "nominal": float(v0), "unit": p.unit,
                           "plausible": None if p.plausible is None else [p.plausible.low, p.plausible.high]}
            if p.name in self.implausible:
                out[p.name]["implausible"] = self.implausible[p.name]
            if p.name in self.fixed:
                out[p.name].update(fitted=False, reason=self.fixed[p.name], std=None)
            elif p.name in bound:
                out[p.name].update(at_bound=True, std=None)  # pushed to its limit: std not meaningful
                if p.name in self.pushed:
                    out[p.name]["pushed"] = self.pushed[p.name]
            if p.name not in self.fixed and not ok:
                out[p.name]["resolved"] = False
            if p.name in self.edge:
                out[p.name]["at_edge"] = self.edge[p.name]
        return out


def bic(rss: float, n: int, k: int) -> float:
    """Bayesian information criterion of a Gaussian least-squares fit."""
    return float(n * np.log(max(rss, 1e-300) / n) + k * np.log(n))


def residual_vector(measured: np.ndarray, pred: Prediction, tubes: Sequence[int],
                    fallback: np.ndarray | None = None) -> np.ndarray:
    """Stacked residuals measured - predicted over the measured tubes (mm). Rows that did not
    converge take the ``fallback`` prediction (the last converged one) so the fit stays smooth."""
    tips = pred.tips_mm
    if fallback is not None and not pred.converged.all():
        tips = np.where(pred.converged[:, None, None], tips, fallback)
    t = list(tubes)
    return (measured[:, t, :] - tips[:, t, :]).reshape(-1)


def fit_effect(effect: Effect, base_robot: Robot, ev: Evaluator,
               measured: np.ndarray, tubes: Sequence[int], nominal: Prediction,
               x_start: np.ndarray | None = None, max_nfev: int = 30,
               fixed: dict[str, str] | None = None,
               limits: dict[str, tuple[float, float]] | None = None) -> FitResult:
    """Least-squares fit of ``effect`` to ``measured`` (n, 3, 3) on the rows of ``ev``.

    ``nominal`` is the base model's prediction on these rows (warm starts, fallback).
    ``x_start`` overrides the starting parameters (e.g. from a single-cause fit).
    ``fixed``: parameter name -> why the data cannot see it; held at its base value, not fitted.
    ``limits``: parameter name -> (lower, upper) tighter than the effect's own (e.g. joint offsets
    that keep every row physically valid).
    """
    import time

    t0 = time.perf_counter()
    params = effect.params(base_robot)
    limits = limits or {}
    lower = np.array([max(p.lower, limits.get(p.name, (-np.inf, np.inf))[0]) for p in params])
    upper = np.array([min(p.upper, limits.get(p.name, (-np.inf, np.inf))[1]) for p in params])
    fixed = {k: v for k, v in (fixed or {}).items() if k in {p.name for p in params}}
    x0 = effect.values(base_robot)
    free = np.array([p.name not in fixed for p in params])
    scale = np.array([p.scale for p in params])
    start = x0.copy() if x_start is None else np.asarray(x_start, dtype=float).copy()
    if x_start is None:
        t = list(tubes)
        g = effect.initial_guess(base_robot, nominal.robot_tips_mm[:, t].reshape(-1, 3),
                                 measured[:, t].reshape(-1, 3))
        if g is not None:
            start = g
    # free parameters start strictly inside their bounds (trf does not leave a bound it starts on);
    # fixed ones stay at their base value
    start = np.where(free, np.clip(start, lower + 1e-3 * scale, upper - 1e-3 * scale), x0)
    problem = _Problem(effect, base_robot, ev, measured, tubes, nominal, start, np.flatnonzero(free), scale)
    idx = problem.idx
    bounds = (((lower - start) / scale)[idx], ((upper - start) / scale)[idx])
    res = least_squares(problem.fun, np.zeros(len(idx)), jac=problem.jac, bounds=bounds, method="trf",
                        x_scale=1.0, ftol=FIT_TOL, xtol=FIT_TOL, gtol=1e-10, max_nfev=max_nfev)
    r, _ = problem.evaluate(res.x)
    fit = _result(effect, base_robot, params, problem.phys(res.x), r, res, idx, scale)
    fit.lower, fit.upper, fit.x0, fit.fixed = lower, upper, x0, fixed
    fit.seconds = time.perf_counter() - t0
    fit.pushed = _pushed(fit, res.jac, r, idx, scale)
    return fit


class _Problem:
    """The least-squares problem of `fit_effect` in scaled coordinates ``z`` of the free parameters
    ``idx`` (``x = start + scale * z``): residuals and finite-difference Jacobians, each solve
    warm-started from the last converged one (rows that fail take the last converged prediction),
    recent residuals cached, a Jacobian reused while ``z`` stays within `JAC_REUSE`."""

    def __init__(self, effect: Effect, base_robot: Robot, ev: Evaluator, measured: np.ndarray,
                 tubes: Sequence[int], nominal: Prediction, start: np.ndarray, idx: np.ndarray,
                 scale: np.ndarray):
        self.effect, self.base_robot, self.ev = effect, base_robot, ev
        self.measured, self.tubes, self.start, self.idx, self.scale = measured, tubes, start, idx, scale
        self.guess = nominal.initial_state.copy()
        self.fallback = nominal.tips_mm.copy()
        self.cache: dict[bytes, tuple[np.ndarray, Prediction]] = {}
        self.near_jac: tuple[np.ndarray, np.ndarray] | None = None

    def phys(self, z: np.ndarray) -> np.ndarray:
        """Parameters (file units) at scaled free coordinates ``z``."""
        x = self.start.copy()
        x[self.idx] += self.scale[self.idx] * z
        return x

    def evaluate(self, z: np.ndarray) -> tuple[np.ndarray, Prediction]:
        key = np.asarray(z, dtype=float).tobytes()
        hit = self.cache.get(key)
        if hit is None:
            model = self.effect.with_values(self.base_robot, self.phys(z))
            pred = self.ev.predict([model], guess=self.guess, settings=TRIAL_SOLVER)[0]
            t = list(self.tubes)
            ok = pred.converged & np.isfinite(pred.tips_mm[:, t]).all(axis=(1, 2))
            self.guess[ok] = pred.initial_state[ok]
            r = residual_vector(self.measured, pred, self.tubes, self.fallback)
            bad = ~np.isfinite(r)
            if bad.any():   # a trial whose prediction has no number there: those rows keep the last one
                r[bad] = (self.measured[:, t] - self.fallback[:, t]).reshape(-1)[bad]
            self.fallback[ok] = pred.tips_mm[ok]
            if len(self.cache) > 8:
                self.cache.pop(next(iter(self.cache)))
            hit = self.cache[key] = (r, pred)
        return hit

    def fun(self, z: np.ndarray) -> np.ndarray:
        return self.evaluate(z)[0]

    def jac(self, z: np.ndarray) -> np.ndarray:
        near = self.near_jac
        if near is not None and np.max(np.abs(np.asarray(z) - near[0]), initial=0.0) < JAC_REUSE:
            return near[1]
        r, pred = self.evaluate(z)
        guess = np.where(pred.converged[:, None], pred.initial_state, self.guess)
        fallback = np.where(pred.converged[:, None, None], pred.tips_mm, self.fallback)
        ev = self.ev
        base = ev.view(self.effect.with_values(self.base_robot, self.phys(z)))
        views = []
        for j in range(len(self.idx)):
            zj = np.array(z, dtype=float)
            zj[j] += FD_STEP
            views.append(ev.view(self.effect.with_values(self.base_robot, self.phys(zj))))
        # a parameter that changes only the joints the mechanics sees (offsets, latency, backlash,
        # friction) acts through d tips / d q: one solve per joint that moves, not one per parameter
        by_joints = [j for j, v in enumerate(views) if base.same_but_joints(v)]
        solved = [j for j in range(len(views)) if j not in by_joints]
        J = np.empty((r.size, len(self.idx)))
        trials = ev.predict_views([views[j] for j in solved], guess=guess, settings=TRIAL_SOLVER)
        for j, pj in zip(solved, trials, strict=True):
            J[:, j] = (residual_vector(self.measured, pj, self.tubes, fallback) - r) / FD_STEP
        if by_joints:
            q0 = base.joints(len(ev))
            dq = {j: views[j].joints(len(ev)) - q0 for j in by_joints}
            moved = sorted({c for j in by_joints for c in np.flatnonzero(np.abs(dq[j]).max(axis=0) > 0)})
            d_res = self._joint_derivatives(base, moved, r, guess, fallback)
            for j in by_joints:
                J[:, j] = sum((d_res[c] * dq[j][:, c, None]).reshape(-1) for c in moved) / FD_STEP \
                    if moved else 0.0
        J[~np.isfinite(J)] = 0.0
        self.near_jac = (np.array(z, dtype=float), J)
        return J

    def _joint_derivatives(self, base: View, joints: list[int], r: np.ndarray, guess: np.ndarray,
                           fallback: np.ndarray) -> dict[int, np.ndarray]:
        """d residual / d q_c (R, T * 3) per row, for each joint c of ``joints``, of the model whose
        `View` is ``base``: one batched solve per joint, a forward step of `JOINT_STEP` (mm or rad)."""
        probes = self.ev.predict_views([base.shifted(c, JOINT_STEP) for c in joints], guess=guess,
                                       settings=TRIAL_SOLVER)
        rows = len(self.ev)
        return {c: ((residual_vector(self.measured, pc, self.tubes, fallback) - r)
                    / JOINT_STEP).reshape(rows, -1) for c, pc in zip(joints, probes, strict=True)}


def _result(effect: Effect, base_robot: Robot, params: list[Param], x: np.ndarray, r: np.ndarray, res,
            idx: np.ndarray, scale: np.ndarray) -> FitResult:
    """The `FitResult` of a least-squares solution ``res`` (scaled free parameters ``idx``) at ``x``
    (file units) with residual ``r``: covariance, resolved parameters, plausibility, derived values,
    BIC. (Bounds, base values, held parameters and timing are the caller's.)"""
    rss, n, k = float(r @ r), r.size, len(idx)
    cov_free, ident_free = _uncertainty(res.jac, rss, n, k)
    cov = np.zeros((len(params), len(params)))
    cov[np.ix_(idx, idx)] = cov_free * np.outer(scale[idx], scale[idx])
    ident = np.zeros(len(params), dtype=bool)
    ident[idx] = ident_free
    free = np.zeros(len(params), dtype=bool)
    free[idx] = True
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    std[~free] = np.nan
    verdicts = effect.plausibility(base_robot, x, cov)
    none = np.full(len(params), np.nan)
    return FitResult(derived=_derived(effect, base_robot, x, std, free), effect=effect, params=params,
                     lower=none, upper=none, x0=none, x=x, std=std, robot=effect.with_values(base_robot, x),
                     rss=rss, n_residuals=n, bic=bic(rss, n, k), nfev=res.nfev, cov=cov,
                     njev=res.njev or 0, success=bool(res.success), message=str(res.message),
                     identifiable=ident,
                     implausible={c: v.reason() for c, v in verdicts.items() if v.implausible},
                     edge={c: v.reason() for c, v in verdicts.items() if not v.implausible},
                     sources={c: v.check.plausible.source for c, v in verdicts.items()})


def _pushed(fit: FitResult, J: np.ndarray, r: np.ndarray, idx: np.ndarray, scale: np.ndarray,
            z: float = CONFIDENCE_Z) -> dict[str, str]:
    """Free parameters at a bound of the fit where the data ask for a value past it: the unconstrained
    Gauss-Newton step from the fit (scaled Jacobian ``J`` of the free parameters ``idx``, residual
    ``r``) leaves the bound by more than ``z`` standard deviations. (A parameter that merely touches
    a bound its true value sits at -- a joint offset at the edge of what keeps the rows physical --
    is not pushed, nor one held at its base value on a bound: a backlash of 0 is no backlash.)"""
    bound = set(fit.at_bound())
    if not bound:
        return {}
    step = np.linalg.lstsq(J, -r, rcond=None)[0] * scale[idx]
    out = {}
    for j, i in enumerate(idx):
        p, v = fit.params[i], fit.x[i]
        if p.name not in bound or abs(v - fit.x0[i]) < 1e-4 * p.scale:
            continue    # (held at its base value on a bound -- no backlash at all -- the cause is absent)
        side = -1.0 if abs(v - fit.lower[i]) <= abs(v - fit.upper[i]) else 1.0
        sd = fit.std[i]
        if side * step[j] > z * sd or not np.isfinite(sd):
            out[p.name] = (f"held at its bound {v:.4g} {p.unit}; the data ask for about "
                           f"{v + step[j]:.4g} {p.unit} (+- {sd:.2g})")
    return out


def _derived(effect: Effect, robot: Robot, x: np.ndarray, std: np.ndarray, free: np.ndarray,
             z: float = CONFIDENCE_Z) -> dict[str, float | None]:
    """`Effect.derived` at ``x``; a quantity is None (not determined) when it is not finite, or
    disappears or is not finite somewhere in the confidence interval of a parameter (e.g. a drive
    stiffness G J / d for a transmission length d within its uncertainty of 0)."""
    out: dict[str, float | None] = dict(effect.derived(robot, x))
    for i in np.flatnonzero(free):
        step = std[i] if np.isfinite(std[i]) else RESOLVED_SCALES * effect.params(robot)[i].scale
        for sign in (-1.0, 1.0):
            xi = x.copy()
            xi[i] += sign * z * step
            near = effect.derived(robot, xi)
            for k, v in out.items():
                if v is not None and (not np.isfinite(v) or k not in near or not np.isfinite(near[k])
                                      or (not np.isfinite(std[i]) and near[k] != v)):
                    out[k] = None
    return out


def _uncertainty(J: np.ndarray, rss: float, n: int, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Covariance (scaled units) ``s^2 (J^T J)^-1`` and which parameters the rows resolve: none with
    weight on a direction of relative singular value < `RESOLVED_SV` (rank-deficient or
    ill-conditioned), none known no better than `RESOLVED_SCALES` typical deviations. Rows and
    columns of unresolved parameters are inf."""
    s2 = rss / max(n - k, 1)
    U, sv, Vt = np.linalg.svd(J, full_matrices=False)
    ok = sv > RESOLVED_SV * sv.max() if sv.size and sv.max() > 0 else np.zeros_like(sv, dtype=bool)
    inv = np.where(ok, 1.0 / np.where(ok, sv, 1.0) ** 2, 0.0)
    cov = (Vt.T * inv) @ Vt * s2
    weak = (np.abs(Vt[~ok]) > 1e-3).any(axis=0) if (~ok).any() else np.zeros(k, dtype=bool)
    weak |= np.sqrt(np.clip(np.diag(cov), 0.0, None)) > RESOLVED_SCALES
    cov[weak, :] = np.inf
    cov[:, weak] = np.inf
    return cov, ~weak


@dataclass
class PartnerScore:
    """A score test of adding a partner effect to a fit (`partner_scores`): the linearised training RSS
    with it, and the partner's linearised values (file units) with their covariance."""

    rss: float
    x: np.ndarray
    cov: np.ndarray
    step: np.ndarray       # the linearised step in the fit's scaled units (x = x0 + scale * step)

    def beyond(self, effect: Effect, robot: Robot, limits: dict[str, tuple[float, float]],
               z: float = CONFIDENCE_Z) -> list[str]:
        """The partner's parameters the linearised fit puts past a hard bound (or a limit the rows set)
        by more than ``z`` standard deviations, and its implausible checks: fitting it is futile."""
        sd = np.sqrt(np.clip(np.diag(self.cov), 0.0, None))
        out = []
        for p, v, s in zip(effect.params(robot), self.x, sd, strict=True):
            lo, hi = limits.get(p.name, (-np.inf, np.inf))
            if v + z * s < max(p.lower, lo) or v - z * s > min(p.upper, hi):
                out.append(p.name)
        return out + list(effect.implausible(robot, self.x, self.cov))


def partner_scores(fit: FitResult, partners: Sequence[Effect], ev: Evaluator, measured: np.ndarray,
                   tubes: Sequence[int], guess: Prediction) -> list[PartnerScore]:
    """The score test of adding each partner effect to the fitted ``fit``: one finite-difference
    Jacobian of the partner's parameters at the fitted model (`_Problem.jac`: a batched solve per
    mechanical parameter, per moving joint for the joint-side ones), then linear least squares on the
    fit's residual. A lower linearised RSS is better."""
    out = []
    for p_eff in partners:
        params = p_eff.params(fit.robot)
        x0 = p_eff.values(fit.robot)
        scale = np.array([p.scale for p in params])
        problem = _Problem(p_eff, fit.robot, ev, measured, tubes, guess, x0, np.arange(len(params)), scale)
        r, _ = problem.evaluate(np.zeros(len(params)))
        J = problem.jac(np.zeros(len(params)))
        delta, *_ = np.linalg.lstsq(J, -r, rcond=None)
        rl = r + J @ delta
        cov, _ = _uncertainty(J, float(rl @ rl), r.size, len(params))
        out.append(PartnerScore(float(rl @ rl), x0 + delta * scale, cov * np.outer(scale, scale), delta))
    return out


def linearised_errors(fit: FitResult, partner: Effect, score: PartnerScore, ev: Evaluator,
                      measured: np.ndarray, tubes: Sequence[int], guess: Prediction) -> np.ndarray:
    """Tip errors (R, T) mm on the rows of ``ev`` (NaN for unmeasured tubes) of ``fit`` with ``partner``
    added at its linearised step ``score.step`` (`partner_scores`): what the fit of the pair would
    give there, to first order -- one Jacobian of the partner on these rows."""
    params = partner.params(fit.robot)
    scale = np.array([p.scale for p in params])
    problem = _Problem(partner, fit.robot, ev, measured, tubes, guess, partner.values(fit.robot),
                       np.arange(len(params)), scale)
    zero = np.zeros(len(params))
    r, _ = problem.evaluate(zero)
    res = (r + problem.jac(zero) @ score.step).reshape(len(ev), len(tubes), 3)
    out = np.full(measured.shape[:2], np.nan)
    out[:, list(tubes)] = np.linalg.norm(res, axis=-1)
    return out
