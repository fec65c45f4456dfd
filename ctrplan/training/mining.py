"""Hard-example mining: fresh exact solutions where the network is currently worst.

DeepXDE's residual-based adaptive refinement adds collocation points where the PDE residual is
largest. Here the exact solver is cheap enough to score the network by its real error instead: every
`Mining.every` optimiser steps, `Mining.candidates` fresh random configurations are solved densely
(`ctrplan.training.rounds`: here, or ahead on a second core), the network's tube-1 tip is compared
with the exact one, and the worst `Mining.keep` of them join a pool that supplies `Mining.share` of
every supervised batch (all candidates solved densely cost 4.7 CPU-s a round of 20,000 on design_1,
tips first and the worst densely after 4.9). Where a CTR is
hardest to learn -- tubes nearly opposed at their largest overlap, next to the elastic-stability
boundary, where the shape changes over a few hundredths of a radian -- is found, not guessed.

The candidates are fresh configurations the network has never seen, so the error distribution of a
round is also an honest running estimate of the tail on unseen configurations (`Round.tip_mm`).
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
import torch

from ctrplan.kinematics.pinn_net import PinnNet
from ctrplan.model.robot import Robot
from ctrplan.training import target
from ctrplan.training.rounds import RoundSolver, RoundSource

#: A tip orientation error of this many degrees scores like 1 mm of tip position error.
DEG_PER_MM = 3.0


@dataclass(frozen=True)
class Mining:
    """How hard examples are found: rounds ``every`` optimiser steps (with a worker process on a core of
    its own solving them, `ctrplan.training.rounds`: at least ``every`` steps apart, a round taken when
    the worker has solved it, unless ``wait_for_worker``), ``candidates`` fresh configurations scored
    per round -- ``worker_candidates`` with the worker -- (a share ``edge_share`` of them with translations
    drawn near their limits, as the exact pool's; then a round's tail is no longer one of uniform
    configurations), the worst ``keep`` of them kept in a pool of at most ``pool`` configurations
    (newest kept), which supplies ``share`` of every supervised batch.

    ``worker_candidates`` 60,000 (and ``keep`` 2,000, the 10 % of 20,000 of the one-core recipe):
    on design_1, 20 minutes on 2 cores (`--threads 2`, wall clock, the machine otherwise idle), the
    worker busy 83 % of the time, p99.9 / max 0.824 / 1.761 mm against 0.944 / 5.404 with 20,000; on
    one core the same rounds would take three quarters of the run.

    ``share`` 0.97: on design_3, 20 CPU-minutes of one thread, tube-1 tip p99.9 / max on
    `eval-model --n 5000` fell monotonically with it -- 0.657 / 1.052 mm (0.5), 0.626 / 1.024 (0.75),
    0.550 / 0.861 (0.9), 0.495 / 0.708 (0.97) -- the mean unchanged (0.126-0.133 mm)."""

    every: int = 1000
    candidates: int = 20_000
    worker_candidates: int = 60_000
    keep: int = 2000
    pool: int = 40_000
    share: float = 0.97
    edge_share: float = 0.0  # candidates with translations near their limits (`samples.pool_joints`)
    wait_for_worker: bool = False  # wait for a round the worker has not solved (else take it when ready)

    def __post_init__(self) -> None:
        counts = {"every": self.every, "candidates": self.candidates,
                  "worker_candidates": self.worker_candidates, "keep": self.keep, "pool": self.pool}
        for name, value in counts.items():
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a whole number >= 1, got {value!r}")
        if self.keep > min(self.candidates, self.worker_candidates):
            raise ValueError(f"keep ({self.keep}) must not exceed the candidates of a round")
        for name, value in {"share": self.share, "edge_share": self.edge_share}.items():
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {value!r}")


@dataclass(frozen=True)
class Round:
    """One mining round: at optimiser ``step``, tube-1 tip error (mm) and tip orientation error (deg)
    of the network on ``candidates`` fresh configurations (tails), and how many the exact solver
    could not solve (left out)."""

    step: int
    candidates: int
    tip_mm: dict
    orientation_deg: dict
    unsolved: int

    def to_json(self) -> dict:
        return {"step": self.step, "candidates": self.candidates, "tip_mm": self.tip_mm,
                "orientation_deg": self.orientation_deg, "unsolved": self.unsolved}


def tail(x: np.ndarray) -> dict:
    """mean, p99, p99.9 and max of ``x`` (any shape; `ctrplan.training.target.tail`), rounded for the card."""
    return {k: round(v, 4) for k, v in target.tail(x).items()}


def tip_errors(net: PinnNet, q: np.ndarray, tips_mm: np.ndarray, quats: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
    """Tube-1 tip position error (B,) mm and tip orientation error (B,) deg of ``net`` against exact
    tips (B, 3) and tip quaternions (B, 4) for joints q (B, 2N) (offsets applied)."""
    dev = next(net.parameters()).device
    ip = net.i_p
    with torch.no_grad():
        x = net(torch.ones(len(q), device=dev), torch.as_tensor(q, dtype=torch.float32, device=dev))
    x = x.double().cpu().numpy()
    pos = np.linalg.norm(x[:, ip:ip + 3] - tips_mm, axis=1)
    dot = np.abs((x[:, ip + 3:ip + 7] * quats).sum(-1))
    return pos, np.degrees(2 * np.arccos(np.clip(dot, 0.0, 1.0)))


class HardExamples:
    """The pool of hard configurations (joints (H, 2N) and dense exact states (H, P, 2N + 9) on the
    training device) and the rounds that filled it. Inside `solving` the rounds' candidates come
    from a `RoundSource` (with ``worker``: solved ahead in a process of its own)."""

    def __init__(self, robot: Robot, mining: Mining, points: int, seed: int, device: torch.device,
                 worker: bool = False):
        self.robot, self.mining, self.points, self.device = robot, mining, points, device
        candidates = mining.worker_candidates if worker else mining.candidates
        self.solver = RoundSolver(robot, candidates, points, seed, mining.edge_share)
        self.worker = worker
        self.source: RoundSource | None = None
        self._due = 0          # the first optimiser step at which the next round may be mined
        self.q = torch.empty((0, 2 * robot.n_tubes), device=device)
        self.x = torch.empty((0, points, robot.n_states), device=device)
        self.rounds: list[Round] = []
        self.seconds = 0.0     # wall seconds the optimiser spent on mining (waiting included)
        self.solve_cpu_s = 0.0  # CPU seconds the rounds took to solve, wherever they ran
        self.waited_s = 0.0    # wall seconds the optimiser waited for rounds (inline: solving them)

    def __len__(self) -> int:
        return self.q.shape[0]

    @contextmanager
    def solving(self, step: int) -> Iterator[None]:
        """Mining rounds available inside, the first the one due after optimiser step ``step``;
        a worker (if any) is stopped on leaving."""
        first = step // self.mining.every + 1
        self.source = RoundSource(self.solver, first, self.worker)
        self._due = first * self.mining.every
        try:
            yield
        finally:
            self.waited_s += self.source.waited_s
            self.source.close()
            self.source = None

    def due(self, step: int) -> bool:
        """Whether a round is to be mined at optimiser ``step``: at least `Mining.every` steps after the
        last one (the first at the multiple after `solving`'s step) and ready -- solved, or
        `Mining.wait_for_worker` says to wait for it (inside `solving`)."""
        return step >= self._due and (self.mining.wait_for_worker or self.source.ready())

    def mine(self, net: PinnNet, step: int) -> Round:
        """Score the next round's fresh candidates (at optimiser ``step``), add the worst to the pool,
        return the round's statistics (inside `solving`)."""
        t0 = time.perf_counter()
        solved = self.source.next()
        self.solve_cpu_s += solved.cpu_s
        ip, tip = net.i_p, solved.states[:, -1].astype(np.float64)
        q = self.robot.apply_offset(solved.q)
        pos, ang = tip_errors(net, q, tip[:, ip:ip + 3], tip[:, ip + 3:ip + 7])
        worst = np.argsort(pos + ang / DEG_PER_MM)[-max(1, self.mining.keep):]
        pool, dev = self.mining.pool, self.device
        self.q = torch.cat([torch.as_tensor(q[worst], dtype=torch.float32, device=dev), self.q])[:pool]
        self.x = torch.cat([torch.as_tensor(solved.states[worst], device=dev), self.x])[:pool]
        rnd = Round(step=step, candidates=len(pos), tip_mm=tail(pos), orientation_deg=tail(ang),
                    unsolved=solved.unsolved)
        self.rounds.append(rnd)
        self._due = step + self.mining.every
        self.seconds += time.perf_counter() - t0
        return rnd

    def draw(self, n: int, g: torch.Generator) -> torch.Tensor:
        """``n`` pool rows (with replacement): indices (n,) into ``q`` and ``x``."""
        return torch.randint(0, len(self), (n,), generator=g, device=self.device)
