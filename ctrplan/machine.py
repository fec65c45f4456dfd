"""The machine a run measures on, and how a process runs on it: a description of the machine (for
benchmark and design records) and pinning to one core with single-threaded numba, torch and BLAS."""

from __future__ import annotations

import os
import platform
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

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


def limit_threads() -> Callable[[], None]:
    """numba, torch and BLAS to one thread in this process; returns a function that restores them."""
    import numba
    import torch

    numba_threads, torch_threads = numba.get_num_threads(), torch.get_num_threads()
    numba.set_num_threads(1)
    torch.set_num_threads(1)
    blas = threadpool_limits(limits=1)  # BLAS threads would only fight over the one core

    def restore() -> None:
        blas.restore_original_limits()
        numba.set_num_threads(numba_threads)
        torch.set_num_threads(torch_threads)

    return restore


@contextmanager
def single_core() -> Iterator[int | None]:
    """Pin this process to one CPU core and numba/torch/BLAS to one thread; restore all on exit.

    Yields the core number, or None where CPU affinity is not supported (macOS, Windows).
    """
    affinity = os.sched_getaffinity(0) if hasattr(os, "sched_setaffinity") else None
    core = max(affinity) if affinity else None
    if core is not None:
        os.sched_setaffinity(0, {core})
    restore_threads = limit_threads()
    try:
        yield core
    finally:
        restore_threads()
        if affinity:
            os.sched_setaffinity(0, affinity)
