"""`ctrplan.base.parallel`: a pool with a context builds it once per worker and hands it to every job."""

from __future__ import annotations

import os
import time
from collections import defaultdict

import pytest

from ctrplan.base.parallel import InlinePool, LocalPool, available_cores, run_jobs


class Tally:
    """A worker's context: where it was built and how many jobs it has seen."""

    def __init__(self) -> None:
        self.pid = os.getpid()
        self.jobs = 0


def tally(context: Tally, spec: int) -> dict:
    context.jobs += 1
    return {"spec": spec, "pid": os.getpid(), "built_in": context.pid, "nth": context.jobs}


def _per_worker(records: list[dict]) -> dict[int, list[int]]:
    seen = defaultdict(list)
    for r in records:
        seen[r["pid"]].append(r["nth"])
    return dict(seen)


def test_this_process_keeps_one_context_for_every_job():
    records = run_jobs(tally, list(range(5)), context=Tally)
    assert [r["spec"] for r in records] == list(range(5))
    assert {r["pid"] for r in records} == {r["built_in"] for r in records} == {os.getpid()}
    assert [r["nth"] for r in records] == [1, 2, 3, 4, 5]


@pytest.mark.skipif(len(available_cores()) < 2, reason="needs two cores")
def test_each_worker_process_builds_its_context_once():
    records = run_jobs(tally, list(range(8)), workers=2, context=Tally)
    assert [r["spec"] for r in records] == list(range(8))  # results in spec order
    assert all(r["built_in"] == r["pid"] != os.getpid() for r in records)  # built in the worker
    per_worker = _per_worker(records)
    assert 1 <= len(per_worker) <= 2
    for counts in per_worker.values():  # one context per worker, kept from job to job
        assert sorted(counts) == list(range(1, len(counts) + 1))


STARTER = """
import sys
from ctrplan.base.parallel import LocalPool
pool = LocalPool(1)
pool.submit(abs, -1)
pool.next_done()  # the worker is up
print(*pool.executor._processes, flush=True)
sys.stdin.read()  # until killed
"""


def test_a_worker_dies_with_the_process_that_started_it():
    """A process killed outright (no Ctrl-C, no cleanup) takes its pool's worker with it: the kernel
    stops the worker (Linux), which would otherwise wait for jobs forever."""
    import signal
    import subprocess
    import sys
    import time

    if not sys.platform.startswith("linux"):
        pytest.skip("the parent-death signal is Linux's")
    starter = subprocess.Popen([sys.executable, "-c", STARTER], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                               text=True)
    worker = int(starter.stdout.readline())
    os.kill(worker, 0)  # alive
    starter.send_signal(signal.SIGKILL)
    starter.wait()
    for _ in range(100):
        try:
            os.kill(worker, 0)
        except ProcessLookupError:
            break
        time.sleep(0.1)
    else:
        os.kill(worker, signal.SIGKILL)
        pytest.fail(f"worker {worker} outlived the process that started it")


def test_ready_says_whether_a_result_waits_without_blocking():
    """`Pool.ready`: False with nothing in flight; an inline job is ready once queued; a worker's job
    once the worker has finished it (then `next_done` hands it over)."""
    inline = InlinePool()
    assert not inline.ready()
    inline.submit(tally_free, 3)
    assert inline.ready() and inline.next_done() == (0, {"spec": 3}) and not inline.ready()
    local = LocalPool(1)
    try:
        assert not local.ready()
        local.submit(tally_free, 4)
        deadline = time.monotonic() + 300   # a guard, not a timing: spawning the worker takes seconds
        while not local.ready() and time.monotonic() < deadline:
            time.sleep(0.05)
        assert local.ready() and local.next_done() == (0, {"spec": 4}) and not local.ready()
    finally:
        local.close(ok=True)


def tally_free(spec: int) -> dict:
    return {"spec": spec}
