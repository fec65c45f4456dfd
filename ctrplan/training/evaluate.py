"""Accuracy of a PINN against the exact Cosserat model on unseen configurations (paper IV-A), and
the calibrated error bound the planner uses as the surrogate's safety margin.

The evaluation configurations come from their own seed stream (`EVAL_SEED`), which no training
sampler uses, so they are never seen in training; the calibration configurations of `error_bound`
from another one (`CALIBRATION_SEED`), used nowhere else.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from ctrplan.base.errors import InputError
from ctrplan.kinematics.backbone import Backbone
from ctrplan.kinematics.base import Backend
from ctrplan.kinematics.cosserat import CosseratBackend
from ctrplan.model.robot import Robot
from ctrplan.training.budget import MIN_EVAL_CONFIGURATIONS, now
from ctrplan.training.target import ACCURACY_TARGET, TARGET_STATISTIC, meets, tail

EVAL_SEED = 918_273_645
#: Seed of the calibration configurations of `error_bound` (used nowhere else).
CALIBRATION_SEED = 555_012_907
#: Arc-length regions (fractions of l1) with a bound each.
REGIONS = ((0.0, 0.25), (0.25, 0.5), (0.5, 0.75), (0.75, 1.0))
#: Coverages (probability that a configuration's error in a region is within its bound) calibrated.
COVERAGES = (0.5, 0.8, 0.9, 0.95, 0.99)
#: Configurations of the calibration of a model's error bound (`calibrate`).
CALIBRATION_CONFIGURATIONS = 5000
#: Configurations compared per chunk when a deadline may cut a comparison short.
COMPARE_CHUNK = MIN_EVAL_CONFIGURATIONS


def conformal_quantile(scores: np.ndarray, coverage: float) -> float:
    """Split-conformal quantile of n calibration scores: the ceil((n + 1) coverage)-th smallest,
    so that a new exchangeable score is at most it with probability >= ``coverage`` (inf when n is
    too small for that coverage)."""
    scores = np.sort(np.ravel(scores))
    k = math.ceil((len(scores) + 1) * coverage)
    return float(scores[k - 1]) if k <= len(scores) else math.inf


@dataclass(frozen=True)
class Comparison:
    """Backbones of one set of configurations from a surrogate and from the exact model.

    Configurations the exact solver could not solve have no truth to compare with: every statistic
    leaves them out, and `unsolved` says how many there were and where they lie."""

    predicted: Backbone
    exact: Backbone

    @property
    def solved(self) -> np.ndarray:
        """(B,) the exact solver converged (a surrogate's prediction there is compared)."""
        return self.exact.converged

    @property
    def normalised_error_pct(self) -> np.ndarray:
        """|p_pred - p_exact| / s * 100 (B_solved, N-1), at every backbone point after s = 0."""
        ok = self.solved
        d = np.linalg.norm(self.predicted.positions_mm[ok] - self.exact.positions_mm[ok], axis=-1)
        return 100.0 * d[:, 1:] / self.exact.s_mm[ok, 1:]

    def unsolved(self) -> dict:
        """How many configurations the exact solver could not solve, and where (joints, mm/rad)."""
        bad = ~self.solved
        q = self.exact.q[bad]
        return {"count": int(bad.sum()), "of": len(self.exact),
                "joints": [[round(float(v), 4) for v in row] for row in q[:20]]}

    def metrics(self) -> dict:
        """Backbone error (% of arc length), tip errors of tubes 1…N (mm, and tube 1's in % of its arc
        length), u_z RMSE (1/m), RMSE of the twists theta_2…N (rad; 0 for one tube), orientation error
        (deg) along the whole backbone and at the tip of tube 1, over the configurations
        the exact solver solved (`unsolved` lists the others). Every value is finite: a surrogate
        that returns non-finite states where a truth exists counts as `nonfinite_predictions`."""
        ok = self.solved
        if not ok.any():
            raise InputError(f"the exact solver solved none of the {len(ok)} evaluation configurations: "
                             f"nothing to compare with (check the robot's domain with `ctrplan stability`)")
        n = self.exact.n_tubes
        pred, exact = self.predicted, self.exact
        finite = np.isfinite(pred.state[ok]).all(axis=(1, 2))
        e = self.normalised_error_pct
        tip = np.linalg.norm(pred.tips_mm[ok] - exact.tips_mm[ok], axis=-1)  # (B, N)
        pq, eq = pred.quaternions[ok], exact.quaternions[ok]
        angle = np.degrees(2 * np.arccos(np.clip(np.abs((pq * eq).sum(-1)), 0, 1)))
        ps, es = pred.state[ok], exact.state[ok]
        return _finite({
            "configurations": int(ok.sum()),
            "unsolved": self.unsolved(),
            "nonfinite_predictions": int((~finite).sum()),
            "backbone_error_pct": {"mean": float(e.mean()), "max": float(e.max()),
                                   "p95": float(np.percentile(e, 95))},
            "tip_error_mm": {f"tube{i + 1}": tail(tip[:, i]) for i in range(n)},
            "tip_error_pct_length": tail(100.0 * tip[:, 0] / exact.tube_ends_mm[ok, 0]),
            "u_z_rmse_1_per_m": float(np.sqrt(((ps[..., 2:2 + n] - es[..., 2:2 + n]) ** 2).mean()) * 1e3),
            "theta_rmse_rad": float(np.sqrt(((ps[..., 3 + n:2 + 2 * n] - es[..., 3 + n:2 + 2 * n]) ** 2
                                             ).mean())) if n > 1 else 0.0,
            "orientation_error_deg": tail(angle),
            "tip_orientation_error_deg": tail(angle[:, -1]),
        })


def _finite(obj):
    """``obj`` with every non-finite float replaced by None (strict JSON has no NaN)."""
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_finite(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def compare(model: Backend, robot: Robot, n: int = 100, points: int = 100,
            seed: int = EVAL_SEED, deadline: float | None = None,
            min_n: int = MIN_EVAL_CONFIGURATIONS) -> Comparison:
    """Run ``model`` and the exact solver on ``n`` unseen configurations of the robot's domain.

    With a ``deadline`` (`budget.now` time) they run in chunks of `COMPARE_CHUNK` and stop after
    the first chunk that ends past it, once ``min_n`` are done: the comparison then covers the first
    configurations of the ``n`` only (its length says how many)."""
    q = robot.sample_joints(n, rng=seed)
    exact = CosseratBackend(robot)
    if deadline is None:
        return Comparison(predicted=model.forward(q, points), exact=exact.forward(q, points))
    parts = []
    for a in range(0, n, COMPARE_CHUNK):
        qa = q[a:a + COMPARE_CHUNK]
        parts.append((model.forward(qa, points), exact.forward(qa, points)))
        if a + len(qa) >= min_n and now() >= deadline:
            break
    return Comparison(predicted=concatenate([p for p, _ in parts]), exact=concatenate([e for _, e in parts]))


def concatenate(parts: list[Backbone]) -> Backbone:
    """Backbones of the same robot and points, one after the other."""
    if len(parts) == 1:
        return parts[0]
    values = {}
    for f in fields(Backbone):
        first = getattr(parts[0], f.name)
        values[f.name] = (np.concatenate([getattr(p, f.name) for p in parts])
                          if isinstance(first, np.ndarray) else first)
    return Backbone(**values)


def error_bound(cmp: Comparison, coverages: tuple[float, ...] = COVERAGES, seed: int | None = None) -> dict:
    """Split-conformal bounds (mm) of the backbone position error in each arc-length region of
    `REGIONS`, one per coverage: per configuration the score is the largest distance between
    predicted and exact backbone points in the region; the bound is `conformal_quantile` of the
    scores. JSON-ready, for the model card under `ctrplan.kinematics.pinn.ERROR_BOUND_KEY`."""
    d = np.linalg.norm(cmp.predicted.positions_mm - cmp.exact.positions_mm, axis=-1)  # (B, N)
    frac = cmp.exact.s_mm / cmp.exact.s_mm[:, -1:]
    ok = cmp.exact.converged & np.isfinite(d).all(axis=1)
    regions = []
    for lo, hi in REGIONS:
        inside = (frac >= lo) & ((frac < hi) | (hi == REGIONS[-1][1]))
        scores = np.where(inside, d, 0.0).max(axis=1)[ok]
        regions.append({"s_fraction": [lo, hi], "max_mm": float(scores.max()),
                        "bound_mm": [conformal_quantile(scores, c) for c in coverages]})
    return {"method": "split-conformal quantile of the largest backbone position error per region",
            "truth": "cosserat", "compared": len(ok), "configurations": int(ok.sum()),
            "points": int(d.shape[1]), "seed": seed,
            "coverages": list(coverages), "regions": regions}


def calibrate(model: Backend, robot: Robot, n: int = CALIBRATION_CONFIGURATIONS, points: int = 64,
              seed: int = CALIBRATION_SEED, deadline: float | None = None) -> dict:
    """`error_bound` of ``model`` against the exact solver on ``n`` configurations of ``seed`` (fewer
    when a ``deadline`` cuts the comparison short, see `compare`)."""
    return error_bound(compare(model, robot, n=n, points=points, seed=seed, deadline=deadline),
                       COVERAGES, seed)


def accuracy_verdict(metrics: dict, monitor_tip_mm: dict | None = None,
                     monitor_configurations: int = 0) -> dict:
    """Whether the network meets `ACCURACY_TARGET` (tube-1 tip error, mm), judged on the larger of its
    two unseen sets: the card's evaluation ``metrics`` (`Comparison.metrics`) or the monitor's last
    measurement of the same network (``monitor_tip_mm``, a `tail` over ``monitor_configurations``) --
    when a time limit cut the evaluation to a few configurations, their p99.9 is their max and says
    little about the thousands the target is set on. ``{"meets_target": bool, "accuracy_target":
    {the target, "measured": the values compared, "tip_mm": the tail judged, "configurations",
    "judged_on": "evaluation" | "monitor"}}``."""
    tip, n, source = metrics["tip_error_mm"]["tube1"], metrics["configurations"], "evaluation"
    if monitor_tip_mm is not None and monitor_configurations > n:
        tip, n, source = monitor_tip_mm, monitor_configurations, "monitor"
    measured = {k: tip[TARGET_STATISTIC[k]] for k in ACCURACY_TARGET}
    return {"meets_target": bool(meets(tip) and not metrics.get("nonfinite_predictions")),
            "accuracy_target": {**ACCURACY_TARGET, "measured": measured, "tip_mm": dict(tip),
                                "configurations": n, "judged_on": source}}


#: Configurations with the largest tube-1 tip error that `worst_configurations` looks at.
WORST_CHECKED = 10
#: Its probe: a step of each joint (translations mm, rotations rad) ...
PROBE_STEP = {"translation_mm": 0.1, "rotation_rad": 0.01}
#: ... that moves the exact tip further than this (mm) is a jump: the exact model changes
#: equilibrium there (the robot snaps). The steepest smooth places of the shipped robots move the tip
#: about 1.4 mm for 0.01 rad (136 mm/rad, docs/benchmarks.md).
JUMP_MM = 3.0


def exact_tip_steps(robot: Robot, q: np.ndarray, tips_mm: np.ndarray, step: dict = PROBE_STEP) -> np.ndarray:
    """The largest move (mm) of the exact tube-1 tip when each free coordinate of the domain box
    (`JointDomain`) of each configuration moves by ``step`` (translations ``translation_mm``, rotations
    ``rotation_rad``) either way; inf where the exact solver does not converge there. ``q``: (k, 2N)
    configurations, mm and rad; ``tips_mm``: (k, 3) their exact tube-1 tips. A move above `JUMP_MM`
    is a jump of the exact model within ``step`` of the configuration. Shape (k,)."""
    n = robot.n_tubes
    box = robot.domain.to_box(q)
    steps = []
    for j in np.flatnonzero(~robot.domain.fixed):
        for sign in (-1.0, 1.0):
            shifted = box.copy()
            shifted[:, j] += sign * (step["rotation_rad"] if j >= n else step["translation_mm"])
            steps.append(robot.domain.from_box(shifted))
    probe = CosseratBackend(robot).forward(np.concatenate(steps), points=2, check=False)
    moved = np.linalg.norm(probe.tips_mm[:, 0] - np.tile(tips_mm, (len(steps), 1)), axis=-1)
    return np.where(probe.converged, moved, np.inf).reshape(len(steps), len(q)).max(axis=0)


#: A jump is narrowed down to a step of this many rad (times the `PROBE_STEP` ratio, mm per rad, for
#: translations): more than `JUMP_MM` across it is 3,000 mm/rad, ten times the steepest smooth places.
RESOLUTION_RAD = 0.001


def _exact_tips(robot: Robot, box: np.ndarray) -> np.ndarray:
    """Exact tube-1 tips (k, 3) mm at domain-box coordinates; NaN where the solver fails."""
    b = CosseratBackend(robot).forward(robot.domain.from_box(box), points=2, check=False)
    return np.where(b.converged[:, None], b.tips_mm[:, 0], np.nan)


def jumps_within(robot: Robot, q: np.ndarray, tips_mm: np.ndarray, radius: float) -> np.ndarray:
    """Which configurations ``q`` (k, 2N, mm and rad; exact tube-1 tips ``tips_mm`` (k, 3)) lie within
    ``radius`` rad of a rotation (or the `PROBE_STEP` ratio times it in mm of a translation) of a jump
    of the exact model: where the probe step of `exact_tip_steps` moves the tip more than `JUMP_MM`,
    it is bisected (the half where the tip moves more, each time) down to `RESOLUTION_RAD`, and the
    tip must still move more than `JUMP_MM` across that. The steep but smooth places (140-300 mm/rad)
    do not count. Bool (k,); a configuration where the solver fails on the way does not count."""
    mm_per_rad = PROBE_STEP["translation_mm"] / PROBE_STEP["rotation_rad"]
    step = {"translation_mm": mm_per_rad * radius, "rotation_rad": radius}
    moved = np.nan_to_num(exact_tip_steps(robot, q, tips_mm, step), posinf=0.0)
    screened = np.flatnonzero(moved > JUMP_MM)
    found = np.zeros(len(q), bool)
    box0, n = robot.domain.to_box(q[screened]), robot.n_tubes
    for j in np.flatnonzero(~robot.domain.fixed):
        axis = np.zeros(box0.shape[1])
        axis[j] = 1.0 if j >= n else mm_per_rad
        for sign in (-1.0, 1.0):
            lo, hi = np.zeros(len(screened)), np.full(len(screened), radius)
            t_lo, t_hi = tips_mm[screened], _exact_tips(robot, box0 + sign * np.outer(hi, axis))
            while len(screened) and hi[0] - lo[0] > RESOLUTION_RAD:
                mid = (lo + hi) / 2
                t_mid = _exact_tips(robot, box0 + sign * np.outer(mid, axis))
                left = np.linalg.norm(t_mid - t_lo, axis=1) >= np.linalg.norm(t_hi - t_mid, axis=1)
                hi, t_hi = np.where(left, mid, hi), np.where(left[:, None], t_mid, t_hi)
                lo, t_lo = np.where(left, lo, mid), np.where(left[:, None], t_lo, t_mid)
            found[screened[np.linalg.norm(t_hi - t_lo, axis=1) > JUMP_MM]] = True
    return found


def worst_configurations(cmp: Comparison, robot: Robot, k: int = WORST_CHECKED) -> dict:
    """Where the tail lives: the ``k`` solved configurations with the largest tube-1 tip error and,
    for each, the largest move of the exact tip for a `PROBE_STEP` either way of one free coordinate
    of the domain box (`exact_tip_steps`);
    ``next_to_jump`` counts those within that step of a jump of the exact model between equilibria
    (`jumps_within`: more than `JUMP_MM` across `RESOLUTION_RAD`), which no smooth surrogate follows.
    JSON-ready."""
    ok = np.flatnonzero(cmp.solved)
    err = np.linalg.norm(cmp.predicted.tips_mm[ok, 0] - cmp.exact.tips_mm[ok, 0], axis=-1)
    worst = ok[np.argsort(err)[::-1][:k]]
    q = cmp.exact.q[worst]
    moved = exact_tip_steps(robot, q, cmp.exact.tips_mm[worst, 0])
    jumps = jumps_within(robot, q, cmp.exact.tips_mm[worst, 0], PROBE_STEP["rotation_rad"])
    rows = [{"q": [round(float(v), 4) for v in qi], "tip_error_mm": round(float(e), 4),
             "exact_tip_step_mm": None if not np.isfinite(m) else round(float(m), 3)}
            for qi, e, m in zip(q, np.sort(err)[::-1][:k], moved, strict=True)]
    return {"checked": len(rows), "next_to_jump": int(jumps.sum()), "probe_step": PROBE_STEP,
            "jump_mm": JUMP_MM, "resolution_rad": RESOLUTION_RAD, "configurations": rows}
