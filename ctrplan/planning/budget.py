"""Search budgets: work decides a verdict, wall-clock time only guards it.

A search (goal sampling by inverse kinematics, the OMPL planner, re-planning in a repair) is budgeted
in **states**: configurations the kinematics backend evaluates for it (IK seeds and iterations, state
and edge checks; cached states count once). The count is the same on any machine, so with a seed the
same search reaches the same verdict and path however loaded the machine is. A **wall-clock guard**
stops a search that runs far longer than its budget should take (a slow or overloaded machine); a
result it cut short says so (`SearchBudget.cut_short`), and only such a result depends on machine
speed.

Defaults keep today's time budgets: a time limit of S seconds buys S times the planning backend's
registered rate (`ctrplan.kinematics.registry.BackendKind.reference_states_per_s`: what this project's
reference machine, 2 cores, checks per second of search),
and the guard fires at ``GUARD_FACTOR x S``.
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
    (read from ``count()``, e.g. a checker's ``counters.kinematics_calls``), and a wall-clock guard of
    ``guard_s`` seconds from construction.

    `exhausted` is what a search asks between steps; work is checked first, so a verdict that the
    work budget decides never depends on time. `cut_short` is True once the guard stopped a search
    whose work budget was not used up.
    """

    max_states: int
    guard_s: float
    count: Callable[[], int]
    start_states: int = 0
    t0: float = field(default_factory=time.perf_counter)
    cut_short: bool = False

    @classmethod
    def start(cls, max_states: int, guard_s: float, count: Callable[[], int]) -> SearchBudget:
        return cls(int(max_states), float(guard_s), count, int(count()))

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
            text += (f"; cut short by the wall-clock guard of {self.guard_s:g} s: this result depends on "
                     f"the machine's speed and load")
        return text

    def to_json(self) -> dict:
        return {"max_states": self.max_states, "states": self.used(), "guard_s": round(self.guard_s, 4),
                "elapsed_s": round(self.elapsed(), 4), "cut_short": self.cut_short}
