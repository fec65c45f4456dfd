"""Generated measured data with a hidden cause, for examples, demos and the README.

`generate` draws a sequence of configurations (a random walk, as a lab acquires them), hidden causes
with the magnitude a lab would see (`Effect.draw`, for every cause of the library), solves the true
model with ctrplan's own prediction path and adds tracker noise. The true parameters come back with
the data so a diagnosis can be scored. Tests of `diagnose` use data made apart from this code
(``tests/independent``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ctrplan.calibration.data import MeasuredData
from ctrplan.calibration.predict import Evaluator
from ctrplan.kinematics.cosserat import SolverSettings
from ctrplan.model.causes.base import make_effect
from ctrplan.model.motion import Motion
from ctrplan.model.robot import Robot


@dataclass
class Synthetic:
    """Generated data and its hidden truth."""

    data: MeasuredData
    cause: str
    robot: Robot                              # the true model (its calibration included)
    truth: dict = field(default_factory=dict)  # parameter name -> true value
    noise_mm: np.ndarray | None = None        # (R, T, 3) the noise that was added
    clean_tips_mm: np.ndarray | None = None   # (R, T, 3) noiseless measurements


def random_walk(n: int, robot: Robot, rng: np.random.Generator, margin_mm: float = 3.0) -> np.ndarray:
    """``n`` configurations (n, 2N) acquired as a sequence: a random walk in the snap-free box (each
    joint moves with probability 0.6 per row, reflecting at the bounds). The translations keep
    ``margin_mm`` from the bounds that tube order and the plate impose, so that the reported joints
    stay physical under zero offsets of a few mm."""
    dom, nt, lengths = robot.domain, robot.n_tubes, robot.lengths_mm
    lo, hi = dom.box_lower.copy(), dom.box_upper.copy()
    moving = hi - lo > 4 * margin_mm
    hi[0] -= margin_mm * moving[0]                       # beta_N behind the plate
    for c in range(1, nt):                               # beta_i+1 - beta_i, i = nt - c (1-based)
        if moving[c]:
            i = nt - c - 1
            lo[c] += 2 * margin_mm                       # tube order
            hi[c] = min(hi[c], lengths[i] - lengths[i + 1] - 2 * margin_mm)   # inner tube reaches furthest
    span = hi - lo
    step = np.r_[0.05 * span[:nt] + 0.5, np.full(nt, 0.5)]
    x = rng.uniform(lo, hi)
    out = np.empty((n, 2 * nt))
    for r in range(n):
        out[r] = x
        move = rng.random(2 * nt) < 0.6
        x = x + move * rng.normal(0.0, step)
        y = np.mod(x - lo, 2 * np.where(span > 0, span, 1.0))  # reflect into [lo, hi]
        x = np.where(span > 0, lo + np.where(y > span, 2 * span - y, y), lo)
    return dom.from_box(out)


def generate(n: int = 200, cause: str = "none", seed: int | None = 0, noise_mm: float = 0.1,
             robot: Robot | None = None, tubes: tuple[int, ...] | None = None) -> Synthetic:
    """Measured data of ``n`` rows of ``robot`` (nominal if None) with a hidden ``cause`` (a cause of
    the library, ``a+b`` for several, or ``none``), Gaussian noise of ``noise_mm`` per coordinate, and
    the tips of ``tubes`` (0-based; all if None) measured."""
    rng = np.random.default_rng(seed)
    robot = robot or Robot.nominal()
    truth, params = robot, {}
    for part in [] if cause == "none" else cause.split("+"):
        effect = make_effect(part)
        x = effect.draw(truth, rng)
        truth = effect.with_values(truth, x)
        params.update({p.name: float(v) for p, v in zip(effect.params(robot), x, strict=True)})
    q = random_walk(n, robot, rng)
    pred = Evaluator(q, Motion.of(q), SolverSettings()).predict([truth])[0]
    if not pred.converged.all():  # pragma: no cover - the walk stays in the snap-free domain
        raise RuntimeError("synthetic truth did not converge")
    clean = pred.tips_mm
    noise = rng.normal(0.0, noise_mm, clean.shape)
    tubes = tuple(range(robot.n_tubes)) if tubes is None else tuple(tubes)
    tips = clean + noise
    tips[:, [t for t in range(robot.n_tubes) if t not in tubes]] = np.nan
    data = MeasuredData(q=q, tips_mm=tips, tubes=tubes, lines=np.arange(2, n + 2),
                        source=f"<synthetic {cause}>", format="csv", outside_domain=np.zeros(n, dtype=bool))
    return Synthetic(data=data, cause=cause, robot=truth, truth=params, noise_mm=noise, clean_tips_mm=clean)
