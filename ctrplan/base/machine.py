"""The machine a run measures on, and how a process runs on it: a description of the machine (for
benchmark and design records) and pinning to one core (or a few) with numba on as many threads and
torch and BLAS on one."""

from __future__ import annotations

import os
import platform
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
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


def limit_threads(numba_threads: int = 1) -> Callable[[], None]:
    """torch and BLAS to one thread in this process, numba to ``numba_threads`` (at most the threads
    it was started with, ``NUMBA_NUM_THREADS``); returns a function that restores them."""
    import numba
    import torch

    numba_before, torch_before = numba.get_num_threads(), torch.get_num_threads()
    numba.set_num_threads(min(numba_threads, numba.config.NUMBA_NUM_THREADS))
    torch.set_num_threads(1)
    blas = threadpool_limits(limits=1)  # BLAS threads would only fight over the one core

    def restore() -> None:
        blas.restore_original_limits()
        numba.set_num_threads(numba_before)
        torch.set_num_threads(torch_before)

    return restore


@contextmanager
def numba_threads_at_most(n: int) -> Iterator[None]:
    """numba's parallel regions on at most ``n`` threads inside (in this thread): a region of fewer
    blocks than threads only wakes threads that find no work."""
    import numba

    before = numba.get_num_threads()
    numba.set_num_threads(max(1, min(n, before)))
    try:
        yield
    finally:
        numba.set_num_threads(before)


def _set_affinity(cores: set[int]) -> None:
    """Every thread of this process (numba's running workers too; Linux lists them in
    /proc/self/task) onto ``cores``; elsewhere the calling thread."""
    try:
        threads = [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        threads = [0]
    for tid in threads:
        with suppress(OSError):  # a thread that ended meanwhile
            os.sched_setaffinity(tid, cores)


@contextmanager
def pinned_cores(cores: int = 1) -> Iterator[list[int] | None]:
    """Pin this process, all its threads, to ``cores`` >= 1 CPU cores (the highest-numbered it may
    use), numba to as many threads (at most ``NUMBA_NUM_THREADS``; a plan's batched kinematics runs in
    blocks across them), torch and BLAS to one; restore all on exit. Yields the cores, or None where
    CPU affinity is not supported (macOS, Windows)."""
    if cores < 1:
        raise ValueError(f"cores must be >= 1, got {cores}")
    affinity = os.sched_getaffinity(0) if hasattr(os, "sched_setaffinity") else None
    chosen = sorted(affinity)[-cores:] if affinity else None
    if chosen:
        _set_affinity(set(chosen))
    restore_threads = limit_threads(len(chosen) if chosen else cores)
    try:
        yield chosen
    finally:
        restore_threads()
        if affinity:
            _set_affinity(affinity)


@contextmanager
def single_core() -> Iterator[int | None]:
    """`pinned_cores` with one core: yields the core number, or None where affinity is not supported."""
    with pinned_cores(1) as chosen:
        yield chosen[0] if chosen else None
