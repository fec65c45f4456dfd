"""Run independent benchmark jobs in this process, over local worker processes, or on a Ray cluster.

Each job is a picklable spec handed to a module-level function; results come back in spec order, so a
run is the same document whichever executor ran it. Every worker runs single-threaded (numba, torch,
BLAS) and local workers are pinned one per core, so per-run timings are one-core timings.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any, TypeVar

from ctrplan.bench import limit_threads, single_core
from ctrplan.errors import InputError

Spec = TypeVar("Spec")
Tick = Callable[[int, int], None]


def _quiet_tick(_done: int, _total: int) -> None:
    return None


def _pin_worker(cores: Any) -> None:
    """Process-pool initializer: take one core off the queue, pin to it, go single-threaded. Ctrl-C
    is the parent's to handle (it ends the workers), so a worker ignores it."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    core = cores.get()
    if core is not None and hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {core})
    limit_threads()


def available_cores() -> list[int]:
    """Cores this process may run on."""
    if hasattr(os, "sched_getaffinity"):
        return sorted(os.sched_getaffinity(0))
    return list(range(os.cpu_count() or 1))


def check_workers(workers: int, ray_address: str | None = None) -> None:
    """`InputError` unless ``workers`` is 1 .. the number of cores (any number >= 1 on Ray)."""
    if workers < 1:
        raise InputError(f"workers: need at least 1, got {workers}")
    cores = len(available_cores())
    if not ray_address and workers > cores:
        raise InputError(f"workers: {workers} workers but only {cores} cores available "
                         f"(one run per core keeps the timings honest)")


def run_local(fn: Callable[[Spec], dict], specs: Sequence[Spec], workers: int,
              tick: Tick = _quiet_tick) -> list[dict]:
    """``fn`` over ``specs`` on ``workers`` spawned processes, each pinned to its own core (round robin
    if there are more workers than cores: `check_workers` keeps the CLI from asking for that)."""
    cores = available_cores()
    ctx = mp.get_context("spawn")  # no fork of a process that holds OMPL, numba and torch threads
    queue = ctx.Queue()
    for k in range(workers):
        queue.put(cores[-1 - k % len(cores)])
    results: list[dict | None] = [None] * len(specs)
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_pin_worker,
                             initargs=(queue,)) as pool:
        try:
            futures = {pool.submit(fn, spec): i for i, spec in enumerate(specs)}
            for done, future in enumerate(as_completed(futures), 1):
                results[futures[future]] = future.result()
                tick(done, len(specs))
        except BaseException:  # Ctrl-C or a failed run: stop now, not after every queued run
            _terminate(pool)
            raise
    return results  # type: ignore[return-value]


def _terminate(pool: ProcessPoolExecutor) -> None:
    """End a pool's workers at once: running runs are killed, queued ones cancelled."""
    for proc in list((pool._processes or {}).values()):  # no public way before Python 3.14
        proc.terminate()
    pool.shutdown(wait=True, cancel_futures=True)


def _ray_call(fn: Callable[[Spec], dict], spec: Spec) -> dict:
    limit_threads()
    return fn(spec)


def run_ray(fn: Callable[[Spec], dict], specs: Sequence[Spec], address: str, workers: int | None = None,
            tick: Tick = _quiet_tick) -> list[dict]:
    """``fn`` over ``specs`` as Ray tasks of one CPU each.

    ``address`` is a Ray cluster address (``auto``, ``HOST:PORT``, ``ray://HOST:PORT``), or ``local``
    to start a private local instance with ``workers`` CPUs (default: all cores) for this call.
    """
    try:
        import ray
    except ImportError:
        raise InputError("ray: Ray is not installed (pip install -e \".[ray]\")") from None
    started = not ray.is_initialized()
    if started:
        kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False,
                                  "configure_logging": False}
        if address == "local":
            kwargs["num_cpus"] = workers or len(available_cores())
        else:
            kwargs["address"] = address
        try:
            ray.init(**kwargs)
        except (ConnectionError, RuntimeError, ValueError) as exc:
            raise InputError(f"ray: cannot connect to the Ray cluster {address!r} ({exc})") from None
    try:
        task = ray.remote(num_cpus=1)(_ray_call)
        refs = [task.remote(fn, spec) for spec in specs]
        index = {ref: i for i, ref in enumerate(refs)}
        results: list[dict | None] = [None] * len(specs)
        pending = list(refs)
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            for ref in ready:
                results[index[ref]] = ray.get(ref)
            tick(len(specs) - len(pending), len(specs))
        return results  # type: ignore[return-value]
    finally:
        if started:
            ray.shutdown()


def run_jobs(fn: Callable[[Spec], dict], specs: Sequence[Spec], *, workers: int = 1,
             ray_address: str | None = None, tick: Tick = _quiet_tick) -> list[dict]:
    """``fn`` over ``specs``: on Ray if ``ray_address``, else on ``workers`` local processes, else
    (``workers == 1``) in this process pinned to one core."""
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    if ray_address:
        return run_ray(fn, specs, ray_address, workers if workers > 1 else None, tick)
    if workers > 1:
        return run_local(fn, specs, workers, tick)
    results = []
    with single_core():
        for i, spec in enumerate(specs, 1):
            results.append(fn(spec))
            tick(i, len(specs))
    return results
