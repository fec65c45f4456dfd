"""Benchmarks: the paper's experiments as reproducible commands.

Shared by every benchmark: a description of the machine, pinning to one core, and the summary
statistics of per-call times.
"""

from __future__ import annotations

import os
import platform
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits


def _version(distribution: str) -> str | None:
    try:
        return version(distribution)
    except PackageNotFoundError:
        return None


def cpu_model() -> str:
    """The CPU's model name (from /proc/cpuinfo where available)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def machine_info() -> dict[str, Any]:
    """CPU model, core count, OS and the versions that decide the timings."""
    return {
        "cpu": cpu_model(),
        "cores": os.cpu_count(),
        "platform": platform.platform(),
        "python": platform.python_version(),
        **{name: _version(name) for name in ("ctrplan", "numpy", "numba", "torch")},
    }


@contextmanager
def single_core() -> Iterator[int | None]:
    """Pin this process to one CPU core and numba/torch/BLAS to one thread; restore all on exit.

    Yields the core number, or None where CPU affinity is not supported (macOS, Windows).
    """
    import numba

    affinity = os.sched_getaffinity(0) if hasattr(os, "sched_setaffinity") else None
    core = max(affinity) if affinity else None
    numba_threads = numba.get_num_threads()
    torch = sys.modules.get("torch")  # only if a backend uses it
    torch_threads = torch.get_num_threads() if torch else None
    if core is not None:
        os.sched_setaffinity(0, {core})
    numba.set_num_threads(1)
    if torch:
        torch.set_num_threads(1)
    blas = threadpool_limits(limits=1)  # BLAS threads would only fight over the one core
    try:
        yield core
    finally:
        blas.restore_original_limits()
        if affinity:
            os.sched_setaffinity(0, affinity)
        numba.set_num_threads(numba_threads)
        if torch:
            torch.set_num_threads(torch_threads)


def timing_stats(times_ms: np.ndarray) -> dict[str, float]:
    """``min/median/p90/p99/max`` (ms) of per-call times (n,), and the tail ratio p99/median."""
    p = np.percentile(times_ms, [0, 50, 90, 99, 100])
    keys = ("min_ms", "median_ms", "p90_ms", "p99_ms", "max_ms")
    stats = {k: round(float(v), 4) for k, v in zip(keys, p, strict=True)}
    stats["p99_over_median"] = round(float(p[3] / p[1]), 3)
    return stats
