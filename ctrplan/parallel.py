"""Run independent jobs in this process, over local worker processes, or on a Ray cluster.

Each job is a picklable spec handed to a module-level function. `open_pool` gives an executor that
takes jobs one at a time (`Pool.submit`) and hands back whichever finishes first (`Pool.next_done`),
for callers that choose the next job from earlier results (an optimiser); `run_jobs` runs a fixed list
and returns the results in spec order, so a run is the same document whichever executor ran it.
Every worker runs single-threaded (numba, torch, BLAS) and local workers are pinned one per core, so
per-job timings are one-core timings. Workers ignore Ctrl-C: the caller gets it and `open_pool` stops
them, so an interrupted run ends with one line, not one traceback per worker.
"""

from __future__ import annotations

import gc
import multiprocessing as mp
import os
import signal
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from contextlib import ExitStack, contextmanager
from typing import Any, TypeVar

from ctrplan.errors import InputError
from ctrplan.machine import limit_threads, single_core

Spec = TypeVar("Spec")
Job = Callable[[Any], dict]
Tick = Callable[[int, int], None]


def _quiet_tick(_done: int, _total: int) -> None:
    return None


def _pin_worker(cores: Any) -> None:
    """Process-pool initializer: ignore Ctrl-C (the parent stops the pool), take one core off the
    queue, pin to it, go single-threaded."""
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


class Pool(ABC):
    """Jobs in flight on some executor. `submit` returns the job's number (0, 1, … in submission
    order); `next_done` blocks until a job has finished and returns its number and result (a job's
    exception is raised there)."""

    def __init__(self) -> None:
        self.submitted = 0
        self.pending = 0

    def submit(self, fn: Job, spec: Any) -> int:
        number = self.submitted
        self._start(number, fn, spec)
        self.submitted += 1
        self.pending += 1
        return number

    def next_done(self) -> tuple[int, dict]:
        if not self.pending:
            raise RuntimeError("next_done: no job in flight")
        number, result = self._finish_one()
        self.pending -= 1
        return number, result

    @abstractmethod
    def _start(self, number: int, fn: Job, spec: Any) -> None: ...

    @abstractmethod
    def _finish_one(self) -> tuple[int, dict]: ...


class InlinePool(Pool):
    """Jobs run in this process, one at a time, when their result is asked for."""

    def __init__(self) -> None:
        super().__init__()
        self._queue: deque[tuple[int, Job, Any]] = deque()

    def _start(self, number: int, fn: Job, spec: Any) -> None:
        self._queue.append((number, fn, spec))

    def _finish_one(self) -> tuple[int, dict]:
        number, fn, spec = self._queue.popleft()
        return number, fn(spec)


class LocalPool(Pool):
    """Jobs on ``workers`` spawned processes, each pinned to its own core (round robin if there are
    more workers than cores: `check_workers` keeps the CLI from asking for that)."""

    def __init__(self, workers: int) -> None:
        super().__init__()
        cores = available_cores()
        ctx = mp.get_context("spawn")  # no fork of a process that holds OMPL, numba and torch threads
        cores_queue = ctx.Queue()
        for k in range(workers):
            cores_queue.put(cores[-1 - k % len(cores)])
        self.executor = ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_pin_worker,
                                            initargs=(cores_queue,))
        self._futures: dict[Future, int] = {}

    def _start(self, number: int, fn: Job, spec: Any) -> None:
        self._futures[self.executor.submit(fn, spec)] = number

    def _finish_one(self) -> tuple[int, dict]:
        done, _ = wait(self._futures, return_when=FIRST_COMPLETED)
        future = min(done, key=self._futures.__getitem__)
        return self._futures.pop(future), future.result()

    def close(self, ok: bool) -> None:
        """Wait for the workers to exit after a normal end; stop them at once otherwise."""
        if ok:
            self.executor.shutdown(wait=True)
            return
        for process in list((self.executor._processes or {}).values()):  # no public way before 3.14
            process.terminate()
        self.executor.shutdown(wait=True, cancel_futures=True)
        # free its queues' semaphores now: after Ctrl-C the CLI leaves with os._exit, skipping the
        # finalisers, and multiprocessing's resource tracker would report them as leaked
        self.executor = None
        self._futures.clear()
        gc.collect()


class RayPool(Pool):
    """Jobs as Ray tasks of one CPU each on the cluster ``ray`` is connected to."""

    def __init__(self) -> None:
        import ray

        super().__init__()
        self.ray = ray
        self.task = ray.remote(num_cpus=1)(_ray_call)
        self._refs: dict[Any, int] = {}

    def _start(self, number: int, fn: Job, spec: Any) -> None:
        self._refs[self.task.remote(fn, spec)] = number

    def _finish_one(self) -> tuple[int, dict]:
        ready, _ = self.ray.wait(list(self._refs), num_returns=1)
        ref = ready[0]
        return self._refs.pop(ref), self.ray.get(ref)

    def cancel(self) -> None:
        for ref in self._refs:
            self.ray.cancel(ref, force=True)


def _ray_call(fn: Job, spec: Any) -> dict:
    limit_threads()
    return fn(spec)


@contextmanager
def _ray_session(address: str, workers: int | None) -> Iterator[None]:
    """Connected to the Ray cluster at ``address`` inside (``local``: a private local instance with
    ``workers`` CPUs, default all cores); a connection made here is closed on exit."""
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
        yield
    finally:
        if started:
            ray.shutdown()


@contextmanager
def open_pool(workers: int = 1, ray_address: str | None = None) -> Iterator[Pool]:
    """A `Pool`: Ray tasks if ``ray_address`` (``auto``, ``HOST:PORT``, ``ray://HOST:PORT``, or
    ``local`` for a private local instance with ``workers`` CPUs), else ``workers`` local processes,
    else (``workers == 1``) this process pinned to one core. Jobs still in flight when the block
    ends by an exception (Ctrl-C) are stopped."""
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    with ExitStack() as stack:
        if ray_address:
            stack.enter_context(_ray_session(ray_address, workers if workers > 1 else None))
            pool: Pool = RayPool()
        elif workers > 1:
            pool = LocalPool(workers)
        else:
            stack.enter_context(single_core())
            pool = InlinePool()
        ok = False
        try:
            yield pool
            ok = True
        finally:
            if isinstance(pool, LocalPool):
                pool.close(ok)
            elif isinstance(pool, RayPool) and not ok:
                pool.cancel()


def run_jobs(fn: Callable[[Spec], dict], specs: Sequence[Spec], *, workers: int = 1,
             ray_address: str | None = None, tick: Tick = _quiet_tick) -> list[dict]:
    """``fn`` over ``specs`` on the executor of `open_pool`; results in spec order."""
    results: list[dict | None] = [None] * len(specs)
    with open_pool(workers, ray_address) as pool:
        for spec in specs:
            pool.submit(fn, spec)
        for done in range(1, len(specs) + 1):
            number, result = pool.next_done()
            results[number] = result
            tick(done, len(specs))
    return results  # type: ignore[return-value]

