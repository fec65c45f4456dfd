"""The experiment that tells tied explanations apart: configurations where the named model and the
models it ties with predict the most different tips (`diagnose --out` writes them as
``experiment.csv`` when there are ties).

Configurations are drawn in the robot's planning domain (snap-free) and kept only where every model
solves them and is stable -- no tip jumps under a small step of every joint (a snap nearby) -- and
are listed in the order to measure them: the directions of motion that order gives (they matter for
lags such as backlash) are the ones the predictions use.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ctrplan.calibration.predict import Evaluator
from ctrplan.model.motion import Motion
from ctrplan.model.robot import Robot

#: Configurations drawn per row asked for (the best of them are kept).
POOL_PER_ROW = 50
#: A step of every joint (mm for beta, rad for alpha) to look for a snap nearby.
PROBE_STEP = (0.2, 0.02)
#: A tip that moves more than this times the typical motion under the probe step is near a snap.
JUMP_FACTOR = 10.0


@dataclass(frozen=True)
class Experiment:
    """Configurations to measure next (in this order), and how far apart the tied models put them."""

    q: np.ndarray                 # (n, 2N) joints, mm / rad
    difference_mm: np.ndarray     # (n,) largest tip distance, named model vs a tie (measured tubes)
    versus: tuple[str, ...]       # (n,) the tie that row separates most from the named model
    named: str
    ties: tuple[str, ...]

    def to_json(self) -> dict:
        d = self.difference_mm
        spread = {"min": float(d.min()), "median": float(np.median(d)), "max": float(d.max())}
        return {"rows": int(len(self.q)), "named": self.named, "ties": list(self.ties),
                "file": "experiment.csv", "difference_mm": spread}

    def write_csv(self, path: str | Path, joint_names: tuple[str, ...]) -> None:
        """``experiment.csv``: the joint columns of the measured-data format, ``difference_mm`` and
        ``versus`` (written atomically)."""
        from ctrplan.base.dataio import atomic_write

        with atomic_write(path) as fh:
            fh.write(",".join([*joint_names, "difference_mm", "versus"]) + "\n")
            for q, d, v in zip(self.q, self.difference_mm, self.versus, strict=True):
                fh.write(",".join([*(f"{x:.6f}" for x in q), f"{d:.4f}", v]) + "\n")


def separating_rows(base: Robot, named: tuple[str, Robot], ties: list[tuple[str, Robot]],
                    tubes: tuple[int, ...], n: int = 20, seed: int = 0) -> Experiment:
    """``n`` configurations of the domain of ``base`` where the named model (name, robot) and each
    tied one predict the most different tips of the measured ``tubes``; each tie gets its share of
    the rows (round robin, the largest difference first)."""
    rng = np.random.default_rng(seed)
    models = [named[1]] + [r for _, r in ties]
    pool = base.sample_joints(POOL_PER_ROW * n, rng)
    diff, ok = _differences(pool, models, tubes)
    order: list[int] = []
    taken = ~ok
    for k in range(n):
        col = diff[:, k % len(ties)]
        free = np.flatnonzero(~taken)
        if not free.size:
            break
        i = int(free[np.argmax(col[free])])
        order.append(i)
        taken[i] = True
    q = pool[np.sort(order)]                    # measured in the order drawn
    diff, _ = _differences(q, models, tubes)    # with the directions this order gives
    best = np.argmax(diff, axis=1)
    return Experiment(q=q, difference_mm=diff[np.arange(len(q)), best],
                      versus=tuple(ties[b][0] for b in best), named=named[0],
                      ties=tuple(t for t, _ in ties))


def _differences(q: np.ndarray, models: list[Robot], tubes: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Per row of ``q`` (in measuring order) and tie: the largest tip distance over ``tubes`` between
    ``models[0]`` and that tie (R, ties), mm; and whether every model solves the row and is stable."""
    motion = Motion.of(q)
    step = np.r_[np.full(q.shape[1] // 2, PROBE_STEP[0]), np.full(q.shape[1] // 2, PROBE_STEP[1])]
    preds = Evaluator(q, motion).predict(models)
    probes = Evaluator(q + step, motion).predict(models, guess=preds[0].initial_state)
    t = list(tubes)
    tips = np.stack([p.tips_mm[:, t] for p in preds])                         # (M, R, T, 3)
    moved = np.linalg.norm(np.stack([p.tips_mm[:, t] for p in probes]) - tips, axis=-1).max(axis=(0, 2))
    ok = np.all([p.converged for p in [*preds, *probes]], axis=0) & np.isfinite(moved)
    ok &= moved <= JUMP_FACTOR * np.median(moved[ok]) if ok.any() else ok
    diff = np.linalg.norm(tips[1:] - tips[:1], axis=-1).max(axis=2).T         # (R, ties)
    return np.where(ok[:, None], diff, 0.0), ok
