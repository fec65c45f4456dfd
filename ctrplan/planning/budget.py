"""Search budgets: work decides a verdict; the clock is a time limit, or only a guard.

A search (goal sampling by inverse kinematics, the OMPL planner, re-planning in a repair) is budgeted
in **states**: configurations the kinematics backend evaluates for it (IK seeds and iterations, state
and edge checks; cached states count once). The count is the same on any machine, so with a seed the
same search reaches the same verdict and path however loaded the machine is. A time limit of S
seconds buys S times the planning backend's registered rate (`BackendKind.reference_states_per_s` in
`ctrplan.kinematics.registry`: what the reference machine checks per second of search, measured by
``scripts/reference_rates.py``).

The clock then plays one of two parts (`plan`):

* **a time limit** (a plan given a time limit, the default): the whole plan ends within
  `WALL_FACTOR` x S of wall time -- the search is stopped at `SEARCH_WALL_SHARE` x S if its states
  are not used up by then, the exact validation and repair fit in the rest. On a machine as fast as
  the reference one the work budget ends the search first; when the clock does, the result says so
  and how to make it reproducible (give the work budget, ``--max-states``);
* **a guard** (a plan given a work budget and no time limit): a search runs until its states are used
  up, and only a pathologically slow machine's clock (`GUARD_FACTOR` x the time limit, given or the
  scene's) stops it.

Either way a result the clock cut short says so (`SearchBudget.cut_short`), and only such a result
depends on machine speed.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from ctrplan.base.errors import InputError
from ctrplan.kinematics.registry import reference_states_per_s

#: The wall-clock guard of a search, in multiples of its time limit: a machine up to this much slower
#: than the reference one still reaches the same verdict. The work budget already bounds a search's
#: time on any machine; the guard only stops one on a pathologically slow or overloaded machine.
#: Measured here: 2 cores shared by a dozen busy processes made the exact model's searches 8x (as
#: the machine was) to 33x (two more busy loops) slower than the reference.
GUARD_FACTOR = 30.0
#: A plan with a time limit S ends within this many times S of wall time ...
WALL_FACTOR = 1.5
#: ... its search (goal sampling and the planner) stopped by the clock at this many times S, the rest
#: left to the exact validation and a repair.
SEARCH_WALL_SHARE = 1.25


def reference_rate(backend_name: str) -> float:
    """States per second of search with a backend (by name) on the reference machine (AMD EPYC, one of
    its 2 cores per search), as its kind registers it (the exact model's rate for one not
    registered)."""
    return reference_states_per_s(backend_name)


def states_for(backend_name: str, time_s: float) -> int:
    """The work budget (states) that ``time_s`` seconds of search buy with a backend on the reference
    machine."""
    return max(1, math.ceil(time_s * reference_rate(backend_name)))


def check_max_states(value: int | None, where: str = "max_states") -> int | None:
    """``value`` if it is None or an integer >= 1; `InputError` naming ``where`` otherwise."""
    if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 1):
        raise InputError(f"{where}: must be an integer >= 1 (states), got {value!r}")
    return value


@dataclass
class SearchBudget:
    """The budget of one search: ``max_states`` new kinematics evaluations after ``start_states``
    (read from ``count()``, e.g. a checker's ``counters.kinematics_calls``), and a wall-clock stop
    ``guard_s`` seconds from construction: the plan's time limit (``time_limit``) or a guard.

    `exhausted` is what a search asks between steps; work is checked first, so a verdict that the
    work budget decides never depends on time. `cut_short` is True once the clock stopped a search
    whose work budget was not used up.
    """

    max_states: int
    guard_s: float
    count: Callable[[], int]
    start_states: int = 0
    t0: float = field(default_factory=time.perf_counter)
    cut_short: bool = False
    time_limit: bool = False

    @classmethod
    def start(cls, max_states: int, guard_s: float, count: Callable[[], int],
              time_limit: bool = False) -> SearchBudget:
        return cls(int(max_states), float(guard_s), count, int(count()), time_limit=time_limit)

    def used(self) -> int:
        """States evaluated since the search started."""
        return int(self.count()) - self.start_states

    def elapsed(self) -> float:
        return time.perf_counter() - self.t0

    def share_used(self) -> float:
        """Fraction of the work budget used."""
        return self.used() / self.max_states

    def exhausted(self) -> bool:
        """Whether the search must stop: its states are used up, or else the guard has fired
        (recorded in `cut_short`)."""
        if self.used() >= self.max_states:
            return True
        if self.elapsed() >= self.guard_s:
            self.cut_short = True
            return True
        return False

    def termination_condition(self):
        """An OMPL ``PlannerTerminationCondition`` evaluated by the planner itself between
        iterations (no timer thread: a periodic one would make the stopping point depend on
        time)."""
        from ompl import base as ob

        return ob.PlannerTerminationCondition(self.exhausted)

    def describe(self) -> str:
        """How the search ended, for messages: the states used, and the guard if it fired."""
        text = f"{self.used()} of {self.max_states} states"
        if self.cut_short:
            what = "the time limit" if self.time_limit else "the wall-clock guard"
            text += (f"; stopped by {what} after {self.guard_s:.3g} s: this result depends on the machine's "
                     f"speed and load")
        return text

    def to_json(self) -> dict:
        return {"max_states": self.max_states, "states": self.used(), "guard_s": round(self.guard_s, 4),
                "elapsed_s": round(self.elapsed(), 4), "cut_short": self.cut_short,
                "clock": "time limit" if self.time_limit else "guard"}


@dataclass(frozen=True)
class PlanClock:
    """The wall clock of a plan with a time limit: ``limit_s`` seconds from ``t0`` (perf_counter,
    after kernel compilation); the search must stop by `SEARCH_WALL_SHARE` x the limit and the plan
    by `WALL_FACTOR` x it."""

    limit_s: float
    t0: float = field(default_factory=time.perf_counter)

    def search_left(self) -> float:
        """Seconds the search may still run (>= 0)."""
        return max(0.0, self.t0 + SEARCH_WALL_SHARE * self.limit_s - time.perf_counter())

    def left(self) -> float:
        """Seconds the plan may still run (>= 0)."""
        return max(0.0, self.t0 + WALL_FACTOR * self.limit_s - time.perf_counter())

    def elapsed(self) -> float:
        return time.perf_counter() - self.t0


def clock_record(clock: PlanClock | None, time_limit_s: float, backend: str) -> dict:
    """How the clock bounded a plan: a time limit (``wall_limit_s``, and the wall time after kernel
    compilation it used) or a guard, and the reference rate its work budget was sized with."""
    return {"mode": "guard" if clock is None else "time limit", "time_limit_s": time_limit_s,
            "wall_limit_s": None if clock is None else WALL_FACTOR * clock.limit_s,
            "wall_s": None if clock is None else round(clock.elapsed(), 4),
            "reference_states_per_s": reference_rate(backend)}


def clock_message(clock: PlanClock | None, max_states: int) -> str:
    """What a plan's message adds when the clock cut a search short: that its verdict depends on the
    machine, and, for a time limit, the work budget that makes it reproducible."""
    if clock is None:
        return (" (a search was cut short by its wall-clock guard: this verdict depends on the machine's "
                "speed and load)")
    return (f" (the time limit of {clock.limit_s:g} s stopped a search before its work budget of "
            f"{max_states:,} states was used: this verdict depends on the machine's speed and load; for "
            f"a reproducible one, give the work budget instead: --max-states {max_states} without "
            f"--time-limit)")
