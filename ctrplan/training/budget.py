"""The time limit of a whole training run: exact data, training, evaluation and calibration.

`ctrplan train --time-limit MIN` bounds the command, not only its optimiser steps. The phases share
the limit in order: the exact pool may take up to `DATA_SHARE` of it (then solving stops and the
pool is what was solved by then, at least one chunk); the optimiser runs until what is left is the
time the evaluation and calibration need at their full sizes (estimated from the rate at which the
exact solver solved the pool, at most `EVAL_SHARE` of the limit); the evaluation and calibration
then get that rest, in proportion to their sizes, and stop early on a smaller set (at least
`MIN_EVAL_CONFIGURATIONS` each). Whatever the limit cut is recorded (`TimeBudget.cuts`) for the
model card and the summary line.

The limit is read on one clock for the whole run (`now`): the wall clock by default, or with `ctrplan
train --clock cpu` the CPU time of the process (`time.process_time`, all its threads), so that a run
on a machine shared with other jobs gets the work it was given rather than what the others left it.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Literal

#: The clocks a time limit can be read on: seconds of wall time, or CPU seconds of this process.
CLOCKS = {"wall": time.monotonic, "cpu": time.process_time}
_clock: list[str] = ["wall"]


def use_clock(name: Literal["wall", "cpu"]) -> None:
    """Read every training time limit, deadline and time-to-target of this process on ``name``."""
    if name not in CLOCKS:
        raise ValueError(f"clock {name!r}: one of {', '.join(CLOCKS)}")
    _clock[0] = name


def clock_name() -> str:
    """The clock `now` reads ("wall" or "cpu")."""
    return _clock[0]


def now() -> float:
    """Seconds on the training clock (`use_clock`); only differences mean anything."""
    return CLOCKS[_clock[0]]()

#: Share of the limit the exact pool may take.
DATA_SHARE = 0.3
#: Largest share of the limit kept back for the evaluation and calibration.
EVAL_SHARE = 0.2
#: Evaluation and calibration configurations solved even when the time is up (at coverage 0.99 the
#: conformal bound needs 99).
MIN_EVAL_CONFIGURATIONS = 100
#: Time per configuration of evaluation and calibration, in exact solutions of the pool: the exact
#: solve at more backbone points, the network's prediction and the statistics.
EVAL_COST_PER_SOLUTION = 2.0


@dataclass
class TimeBudget:
    """A time limit (s on the clock `now` reads; None: none) for a run started at ``start`` (`now`)
    that ends by comparing the model with the exact solver on ``eval_configurations`` configurations."""

    limit_s: float | None
    eval_configurations: int = 0
    start: float = field(default_factory=now)
    cuts: list[str] = field(default_factory=list)
    wall_start: float = field(default_factory=time.monotonic)
    cpu_start: float = field(default_factory=time.process_time)

    def elapsed_s(self) -> float:
        return now() - self.start

    def left_s(self) -> float:
        """Seconds left (inf without a limit; never negative)."""
        return math.inf if self.limit_s is None else max(self.limit_s - self.elapsed_s(), 0.0)

    def data_deadline(self) -> float | None:
        """When solving the exact pool must stop (`now` time), or None."""
        return None if self.limit_s is None else self.start + DATA_SHARE * self.limit_s

    def training_s(self, solutions_per_s: float) -> float | None:
        """Seconds the optimiser may run from now: what is left less the time the evaluation needs
        at ``solutions_per_s`` exact solutions a second (at most `EVAL_SHARE` of the limit)."""
        if self.limit_s is None:
            return None
        reserve = EVAL_COST_PER_SOLUTION * self.eval_configurations / max(solutions_per_s, 1e-9)
        return max(self.left_s() - min(reserve, EVAL_SHARE * self.limit_s), 0.0)

    def phase_deadline(self, share: float) -> float | None:
        """The deadline of a phase that may take ``share`` of the time left, or None."""
        return None if self.limit_s is None else now() + share * self.left_s()

    def cut(self, what: str) -> None:
        """Record that the limit cut ``what`` short (e.g. "exact data: 3,072 of 100,000 solutions")."""
        self.cuts.append(what)

    def to_json(self) -> dict:
        """The card's record: the limit, the clock it was read on, the whole run's time so far on it,
        its wall and CPU seconds, and what the limit cut."""
        return {"limit_s": self.limit_s, "clock": clock_name(), "elapsed_s": round(self.elapsed_s(), 1),
                "wall_s": round(time.monotonic() - self.wall_start, 1),
                "cpu_s": round(time.process_time() - self.cpu_start, 1), "cut": list(self.cuts)}
