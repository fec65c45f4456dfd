"""Benchmarks: the paper's experiments as reproducible commands.

Shared by every benchmark: the summary statistics of per-call times. The description of the machine
and pinning to one core are `ctrplan.base.machine`; the executors `ctrplan.base.parallel`.
"""

from __future__ import annotations

import numpy as np


def timing_stats(times_ms: np.ndarray) -> dict[str, float]:
    """``min/median/p90/p99/max`` (ms) of per-call times (n,), and the tail ratio p99/median."""
    p = np.percentile(times_ms, [0, 50, 90, 99, 100])
    keys = ("min_ms", "median_ms", "p90_ms", "p99_ms", "max_ms")
    stats = {k: round(float(v), 4) for k, v in zip(keys, p, strict=True)}
    stats["p99_over_median"] = round(float(p[3] / p[1]), 3)
    return stats
