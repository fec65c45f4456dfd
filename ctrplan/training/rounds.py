"""The fresh configurations of hard-example mining, solved exactly: in the training process when a
round is due, or ahead of time in a worker process on a core of its own.

Round k's candidates are drawn from their own random stream (``seed``, k), so a round is the same
configurations whoever solves it and whenever: the worker changes where the exact solver runs, not
what the network is trained on (the recipe may give a worker more candidates per round,
`Mining.worker_candidates`). With one core the rounds are solved inline; with two or more the worker
solves the next rounds while the optimiser steps (on design_1 a quarter of a 20-minute one-core run
was mining). A round the optimiser reaches before the worker has solved it is taken when it is ready
(`RoundSource.ready`), so a machine whose exact solver is slow against its torch steps mines less often
instead of idling the optimiser; `Mining.wait_for_worker` waits for it instead (`RoundSource.waited_s`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ctrplan.base.parallel import InlinePool, LocalPool, Pool
from ctrplan.model.robot import Robot
from ctrplan.training.samples import pool_joints, solve_dense

#: Seed of the rounds' random streams (with the run's seed and the round's number).
ROUND_SEED = 20_251_125
#: Rounds a worker solves ahead of the optimiser.
AHEAD = 2


@dataclass(frozen=True)
class SolvedRound:
    """Round ``index``: its solved candidates -- joints q (C, 2N) mm/rad (offsets not applied) and
    exact states (C, P, 2N + 9) float32 at P uniform arc fractions -- how many candidates the solver
    could not solve (left out) and the CPU seconds solving took where it ran."""

    index: int
    q: np.ndarray
    states: np.ndarray
    unsolved: int
    cpu_s: float


@dataclass(frozen=True)
class RoundSolver:
    """What every round is solved for: ``candidates`` configurations of ``robot`` at ``points`` arc
    fractions, drawn from the stream of ``seed`` (`samples.pool_joints`: a share ``edge_share`` with
    translations near their limits)."""

    robot: Robot
    candidates: int
    points: int
    seed: int
    edge_share: float = 0.0

    def __call__(self, index: int) -> SolvedRound:
        t0 = time.process_time()
        rng = np.random.default_rng([self.seed, ROUND_SEED, index])
        q = pool_joints(self.robot, self.candidates, rng, self.edge_share)
        dense = solve_dense(self.robot, q, self.points)
        return SolvedRound(index=index, q=dense.q, states=dense.states.astype(np.float32),
                           unsolved=len(dense.unsolved), cpu_s=time.process_time() - t0)


class RoundSource:
    """Rounds ``first``, ``first + 1``, ... in order (`next`): solved when asked for, or with
    ``worker`` by a process of its own (`ctrplan.base.parallel.LocalPool`: one core, single-threaded)
    up to `AHEAD` rounds ahead. `close` stops the worker."""

    def __init__(self, solver: RoundSolver, first: int, worker: bool):
        self.solver, self.worker = solver, worker
        self.pool: Pool = LocalPool(1) if worker else InlinePool()
        self.next_index = self.taken = first
        self.waited_s = 0.0
        for _ in range(AHEAD if worker else 1):
            self._submit()

    def _submit(self) -> None:
        self.pool.submit(self.solver, self.next_index)
        self.next_index += 1

    def ready(self) -> bool:
        """Whether `next` would return without waiting for the worker (inline: always)."""
        return self.pool.ready()

    def next(self) -> SolvedRound:
        """The next round (waiting for the worker if it has not solved it yet)."""
        t0 = time.perf_counter()
        _, solved = self.pool.next_done()
        self.waited_s += time.perf_counter() - t0
        if solved.index != self.taken:
            raise RuntimeError(f"mining: round {solved.index} came where round {self.taken} was due")
        self.taken += 1
        self._submit()
        return solved

    def close(self) -> None:
        self.pool.close(ok=False)  # the rounds solved ahead are not needed
