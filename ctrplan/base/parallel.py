"""Run independent jobs in this process, over local worker processes, or on a Ray cluster.

Each job is a picklable spec handed to a module-level function. `open_pool` gives an executor that
takes jobs one at a time (`Pool.submit`) and hands back whichever finishes first (`Pool.next_done`;
`Pool.ready` says whether one has, without waiting), for callers that choose the next job from
earlier results (an optimiser); `run_jobs` runs a fixed list and returns the results in spec order,
so a run is the same document whichever executor ran it.
Every worker runs single-threaded (numba, torch, BLAS) and local workers are pinned one per core, so
per-job timings are one-core timings; a single local worker may be given more cores (``threads``:
numba's blocked kernels use them, the latency of a job alone on the machine). Workers ignore Ctrl-C:
the caller gets it and `open_pool` stops them, so an interrupted run ends with one line, not one
traceback per worker.

What jobs share within a worker (a loaded task, a collision world) is a context object the pool
builds once per worker from a ``context`` factory and passes to every job: ``fn(context, spec)``.
"""

from __future__ import annotations

import ctypes
import gc
import multiprocessing as mp
import os
import signal
import sys
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from contextlib import ExitStack, contextmanager
from typing import Any, TypeVar

from ctrplan.base.errors import InputError
from ctrplan.base.machine import limit_threads, pinned_cores

Spec = TypeVar("Spec")
Job = Callable[[Any], dict]
#: A job of a pool with a context: ``fn(context, spec)``.
ContextJob = Callable[[Any, Any], dict]
Tick = Callable[[int, int], None]


def _quiet_tick(_done: int, _total: int) -> None:
    return None


class _Worker:
    """A worker's side of a pool with a context: builds the context once, then runs every job with it."""

    def __init__(self, context: Callable[[], Any]) -> None:
        self.context = context()

    def run(self, fn: ContextJob, spec: Any) -> dict:
        return fn(self.context, spec)


#: This process's `_Worker` when it is a worker of a `LocalPool` with a context (set by
#: `_pin_worker`): a pool process has no other place to keep state from one job to the next.
_local_worker: _Worker | None = None
#: prctl(2) option: the signal a process gets when its parent dies.
PR_SET_PDEATHSIG = 1


def _die_with_parent() -> None:
    """Linux: have the kernel stop this process when the one that started it dies -- killed, not
    only interrupted (a worker would otherwise wait for jobs forever)."""
    if sys.platform.startswith("linux"):
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGTERM)


def _pin_worker(cores: Any, context: Callable[[], Any] | None) -> None:
    """Process-pool initializer: ignore Ctrl-C (the parent stops the pool), die with the parent,
    take one core off the queue, pin to it, go single-threaded; build this worker's context (if the
    pool has one)."""
    global _local_worker
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _die_with_parent()
    core = cores.get()
    if core is not None and hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {core})
    limit_threads()
    _local_worker = None if context is None else _Worker(context)


def _run_with_context(fn: ContextJob, spec: Any) -> dict:
    """A job of a `LocalPool` with a context, in the worker process."""
    return _local_worker.run(fn, spec)


def available_cores() -> list[int]:
    """Cores this process may run on."""
    if hasattr(os, "sched_getaffinity"):
        return sorted(os.sched_getaffinity(0))
    return list(range(os.cpu_count() or 1))


def check_workers(workers: int, ray_address: str | None = None, threads: int = 1) -> None:
    """`InputError` unless ``workers`` is 1 .. the number of cores (any number >= 1 on Ray), and
    ``threads`` (cores of one job) is 1, or for a single local worker up to the number of cores and
    numba's ``NUMBA_NUM_THREADS``."""
    if workers < 1:
        raise InputError(f"workers: need at least 1, got {workers}")
    if threads < 1:
        raise InputError(f"threads: need at least 1, got {threads}")
    if threads > 1 and (workers > 1 or ray_address):
        raise InputError(f"threads: {threads} cores per run needs one local worker (--workers 1, no "
                         f"Ray): workers run on one core each")
    cores = len(available_cores())
    if not ray_address and workers > cores:
        raise InputError(f"workers: {workers} workers but only {cores} cores available "
                         f"(one run per core keeps the timings honest)")
    if threads > cores:
        raise InputError(f"threads: {threads} cores per run but only {cores} cores available")
    if threads > 1:
        import numba

        if threads > numba.config.NUMBA_NUM_THREADS:
            raise InputError(f"threads: {threads} cores per run but numba was started with "
                             f"NUMBA_NUM_THREADS={numba.config.NUMBA_NUM_THREADS}")


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
    def ready(self) -> bool:
        """Whether `next_done` would return without waiting for another process (False with nothing in
        flight)."""

    @abstractmethod
    def _start(self, number: int, fn: Job, spec: Any) -> None: ...

    @abstractmethod
    def _finish_one(self) -> tuple[int, dict]: ...

    @abstractmethod
    def close(self, ok: bool) -> None:
        """Release the executor: after a normal end (``ok``) let it finish, else stop what is in
        flight."""


class InlinePool(Pool):
    """Jobs run in this process, one at a time, when their result is asked for."""

    def __init__(self, context: Callable[[], Any] | None = None) -> None:
        super().__init__()
        self._queue: deque[tuple[int, Job, Any]] = deque()
        self._worker = None if context is None else _Worker(context)

    def ready(self) -> bool:
        """A queued job is always ready: it runs here when asked for."""
        return bool(self._queue)

    def _start(self, number: int, fn: Job, spec: Any) -> None:
        self._queue.append((number, fn, spec))

    def _finish_one(self) -> tuple[int, dict]:
        number, fn, spec = self._queue.popleft()
        return number, fn(spec) if self._worker is None else self._worker.run(fn, spec)

    def close(self, ok: bool) -> None:
        """Nothing to release: the jobs not asked for were never run."""
        self._queue.clear()


class LocalPool(Pool):
    """Jobs on ``workers`` spawned processes, each pinned to its own core (round robin if there are
    more workers than cores: `check_workers` keeps the CLI from asking for that)."""

    def __init__(self, workers: int, context: Callable[[], Any] | None = None) -> None:
        super().__init__()
        cores = available_cores()
        ctx = mp.get_context("spawn")  # no fork of a process that holds OMPL, numba and torch threads
        cores_queue = ctx.Queue()
        for k in range(workers):
            cores_queue.put(cores[-1 - k % len(cores)])
        self.executor = ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_pin_worker,
                                            initargs=(cores_queue, context))
        self._futures: dict[Future, int] = {}
        self._with_context = context is not None

    def ready(self) -> bool:
        return any(job.done() for job in self._futures)

    def _start(self, number: int, fn: Job, spec: Any) -> None:
        job = self.executor.submit(_run_with_context, fn, spec) if self._with_context else \
            self.executor.submit(fn, spec)
        self._futures[job] = number

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
    """Jobs as Ray tasks of one CPU each on the cluster ``ray`` is connected to; with a context, on
    ``workers`` Ray actors of one CPU each (each builds its context once), a job going to the actor
    with the fewest jobs in flight."""

    def __init__(self, workers: int = 1, context: Callable[[], Any] | None = None) -> None:
        import ray

        super().__init__()
        self.ray = ray
        self.task = ray.remote(num_cpus=1)(_ray_call)
        self.actors: list[Any] = []
        if context is not None:
            actor = ray.remote(num_cpus=1)(_RayWorker)
            self.actors = [actor.remote(context) for _ in range(workers)]
        self._in_flight = [0] * len(self.actors)
        self._refs: dict[Any, tuple[int, int | None]] = {}  # ref -> (job number, actor or None)

    def _start(self, number: int, fn: Job, spec: Any) -> None:
        if not self.actors:
            self._refs[self.task.remote(fn, spec)] = (number, None)
            return
        k = min(range(len(self.actors)), key=self._in_flight.__getitem__)
        self._in_flight[k] += 1
        self._refs[self.actors[k].run.remote(fn, spec)] = (number, k)

    def ready(self) -> bool:
        return bool(self._refs) and bool(self.ray.wait(list(self._refs), num_returns=1, timeout=0)[0])

    def _finish_one(self) -> tuple[int, dict]:
        ready, _ = self.ray.wait(list(self._refs), num_returns=1)
        ref = ready[0]
        number, k = self._refs.pop(ref)
        if k is not None:
            self._in_flight[k] -= 1
        return number, self.ray.get(ref)

    def close(self, ok: bool) -> None:
        """Release the actors (their CPUs); without ``ok`` stop the tasks in flight first."""
        if not ok and not self.actors:
            for ref in self._refs:
                self.ray.cancel(ref, force=True)
        for actor in self.actors:  # killing an actor also ends the jobs it still had
            self.ray.kill(actor)


class _RayWorker(_Worker):
    """A Ray actor: single-threaded, its context built once."""

    def __init__(self, context: Callable[[], Any]) -> None:
        limit_threads()
        super().__init__(context)


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
def open_pool(workers: int = 1, ray_address: str | None = None,
              context: Callable[[], Any] | None = None, threads: int = 1) -> Iterator[Pool]:
    """A `Pool`: Ray tasks if ``ray_address`` (``auto``, ``HOST:PORT``, ``ray://HOST:PORT``, or
    ``local`` for a private local instance with ``workers`` CPUs), else ``workers`` local processes,
    else (``workers == 1``) this process pinned to ``threads`` cores (`pinned_cores`; a job alone on
    the machine may use more than one, see `check_workers`). Jobs still in flight when the block
    ends by an exception (Ctrl-C) are stopped.

    With ``context`` (a picklable callable, e.g. a class) every worker builds its context once,
    ``context()``, and the pool calls each job as ``fn(context, spec)``; without, as ``fn(spec)``."""
    if workers < 1 or threads < 1 or (threads > 1 and (workers > 1 or ray_address)):
        raise ValueError(f"need workers >= 1 and threads >= 1, threads > 1 only for one local worker; got "
                         f"workers={workers}, threads={threads}, ray={ray_address!r}")
    with ExitStack() as stack:
        if ray_address:
            stack.enter_context(_ray_session(ray_address, workers if workers > 1 else None))
            pool: Pool = RayPool(workers, context)
        elif workers > 1:
            pool = LocalPool(workers, context)
        else:
            stack.enter_context(pinned_cores(threads))
            pool = InlinePool(context)
        ok = False
        try:
            yield pool
            ok = True
        finally:
            pool.close(ok)


def run_jobs(fn: Callable[..., dict], specs: Sequence[Spec], *, workers: int = 1,
             ray_address: str | None = None, context: Callable[[], Any] | None = None,
             tick: Tick = _quiet_tick, threads: int = 1) -> list[dict]:
    """``fn`` over ``specs`` on the executor of `open_pool` (with its ``context`` and ``threads``);
    results in spec order."""
    results: list[dict | None] = [None] * len(specs)
    with open_pool(workers, ray_address, context, threads) as pool:
        for spec in specs:
            pool.submit(fn, spec)
        for done in range(1, len(specs) + 1):
            number, result = pool.next_done()
            results[number] = result
            tick(done, len(specs))
    return results  # type: ignore[return-value]

