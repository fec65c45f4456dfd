"""Which measured rows train a model and which are held out -- one split for `diagnose` and few-shot
fine-tuning (`ctrplan.training.fewshot`).

Rows are sequences (neighbouring rows are alike), so a random row split would leak: rows are held out
in contiguous blocks drawn at random (``--heldout FRACTION``), or as the last rows in acquisition order
(``--heldout-last FRACTION``: what a user who evaluates on future data wants). Either holds out
``round(FRACTION * rows)`` rows exactly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ctrplan.base.errors import InputError

BLOCKS = 10


@dataclass(frozen=True)
class Split:
    """Row indices (sorted, 0-based) that train and that are held out, and how they were drawn."""

    train: np.ndarray
    heldout: np.ndarray
    fraction: float
    last: bool = False
    seed: int = 0

    def describe(self) -> str:
        if self.last:
            return f"the last {len(self.heldout)} rows in acquisition order held out"
        return f"{len(self.heldout)} rows held out in contiguous blocks (seed {self.seed})"

    def resample(self, seed: int) -> Split:
        """Another split for a stability check: other blocks of all rows; with ``last``, blocks of the
        training rows only, so that the rows held out last are never fitted."""
        if self.last:
            inner = split_rows(len(self.train), self.fraction, seed=seed)
            return Split(self.train[inner.train], self.train[inner.heldout], self.fraction, seed=seed)
        n = len(self.train) + len(self.heldout)
        return split_rows(n, self.fraction, seed=seed)


def split_rows(n: int, fraction: float = 0.25, *, last: bool = False, blocks: int = BLOCKS,
               seed: int = 0) -> Split:
    """Hold out ``round(fraction * n)`` of ``n`` rows (at least 1, at most n - 1): the last ones with
    ``last``, else contiguous blocks: ``blocks`` equal blocks are taken in an order drawn with ``seed``
    until enough rows are held out, the surplus cut from the end of the last block taken."""
    if not 0.0 < fraction < 1.0:
        raise InputError(f"heldout fraction must be in (0, 1), got {fraction}")
    if n < 2:
        raise InputError(f"cannot hold out rows of {n} row(s)")
    h = int(min(n - 1, max(1, round(fraction * n))))
    if last:
        heldout = np.arange(n - h, n)
    else:
        parts = np.array_split(np.arange(n), int(max(2, min(blocks, n // 5 if n >= 10 else 2))))
        taken: list[np.ndarray] = []
        for b in np.random.default_rng(seed).permutation(len(parts)):
            taken.append(parts[b][:h - sum(len(t) for t in taken)])
            if sum(len(t) for t in taken) >= h:
                break
        heldout = np.sort(np.concatenate(taken))
    return Split(np.setdiff1d(np.arange(n), heldout), heldout, float(fraction), last, seed)


def contiguous_subsample(n: int, rows: int, runs: int = 20) -> np.ndarray:
    """``rows`` indices of ``range(n)`` as ``runs`` contiguous runs spread evenly over the sequence."""
    runs = max(1, min(runs, rows))
    sizes = np.full(runs, rows // runs)
    sizes[: rows % runs] += 1
    starts = np.linspace(0, n - sizes.max(), runs).astype(int)
    return np.unique(np.concatenate([np.arange(a, a + k) for a, k in zip(starts, sizes, strict=True)]))
