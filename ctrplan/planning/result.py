"""What a plan found out, as typed records built once when each step ends: `PlanResult` (the verdict,
the path, its exact validation) and `PlanWork` (how it got there: margins, compile time, counters, the
search's goal sampling and budget, the exact goal correction, the repair). `PlanResult.to_json` is
the ``ctrplan plan --json`` document (docs/cli.md); the writers of `ctrplan.viz` render a result and
compute nothing of their own.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from ctrplan.kinematics.backbone import Backbone
from ctrplan.planning.failure import FailureAnalysis
from ctrplan.planning.goal import GoalStats
from ctrplan.planning.validate import ValidatedPath, Validation
from ctrplan.planning.validity import Counters


@dataclass(frozen=True)
class BudgetUse:
    """How much of its work budget a search used (`ctrplan.planning.budget.SearchBudget`): states
    allowed and evaluated, the wall-clock stop and the time taken (s), whether the clock cut it short,
    and what the clock was (``time limit`` of a plan, or a ``guard``)."""

    max_states: int
    states: int
    guard_s: float
    elapsed_s: float
    cut_short: bool
    clock: str = "guard"

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class SearchTimings:
    """Seconds of a search's stages (None: the stage did not run) and the states the shortcut
    checked."""

    goal_sampling_s: float
    search_s: float | None = None
    simplify_s: float | None = None
    simplify_states: int | None = None

    def to_json(self) -> dict[str, Any]:
        return {k: v for k, v in asdict(self).items() if v is not None}


@dataclass(frozen=True)
class SearchRecord:
    """One search's goal sampling statistics, stage timings and budget use."""

    goal_stats: GoalStats
    timings: SearchTimings
    budget: BudgetUse

    def goal_sampling_json(self) -> dict[str, Any]:
        return {**asdict(self.goal_stats), **self.timings.to_json()}


@dataclass(frozen=True)
class ExactGoal:
    """The exact goal correction (`ctrplan.planning.planner.exact_goal`): whether it appended a
    state, and its time (s)."""

    appended: bool
    time_s: float


@dataclass(frozen=True)
class RepairRecord:
    """A repair of a path that failed exact validation: the shared work budget of its searches
    (states allowed and used, whether a guard cut one short), its time (s) and kinematics calls, the
    first validation's report, and why it failed (None: it succeeded)."""

    max_states: int
    states: int
    cut_short: bool
    time_s: float
    kinematics_calls: int
    first_validation: Validation
    failure: str | None = None


@dataclass(frozen=True)
class PlanWork:
    """How a plan got to its verdict: the search's capsule margin (mm) and where it comes from
    (`ctrplan.planning.model.planning_backend`), the set-up time (s, outside the planning time and
    its limit: kernel compilation, the collision world's first use, the start check), the search's
    counters, and -- where the plan got that far -- the search record, the exact goal correction, the
    first exact validation's time (s), the repair, and how the clock bounded the plan
    (`ctrplan.planning.budget.clock_record`)."""

    planning_margin_mm: float
    margin_source: dict
    compile_s: float
    counters: Counters
    search: SearchRecord | None = None
    exact_goal: ExactGoal | None = None
    validation_time_s: float | None = None
    repair: RepairRecord | None = None
    clock: dict | None = None

    def to_json(self) -> dict[str, Any]:
        """The ``details`` of the plan document."""
        doc: dict[str, Any] = {"planning_margin_mm": self.planning_margin_mm,
                               "surrogate_margin": self.margin_source, "compile_s": self.compile_s,
                               "counters": asdict(self.counters)}
        if self.search is not None:
            doc["goal_sampling"] = self.search.goal_sampling_json()
            doc["budget"] = self.search.budget.to_json()
        if self.exact_goal is not None:
            doc["exact_goal"] = asdict(self.exact_goal)
        if self.validation_time_s is not None:
            doc["validation_time_s"] = self.validation_time_s
        if self.repair is not None:
            r = self.repair
            doc["repair_budget"] = {"max_states": r.max_states, "states": r.states, "cut_short": r.cut_short}
            doc["repair_time_s"] = r.time_s
            doc["first_validation"] = r.first_validation.to_json()
            if r.failure is not None:
                doc["repair"] = r.failure
        if self.clock is not None:
            doc["clock"] = self.clock
        return doc


@dataclass(frozen=True)
class PlanResult:
    """Everything `ctrplan.planning.plan` found out; `to_json` gives the CLI document (docs/cli.md).

    ``path``: the waypoints (K, 2N), mm and rad (empty without one); ``dense``: the exactly validated
    path (its dense states, exact backbones, report and, when measured, clearances), None when no
    path was found; ``start``: the exact backbone of the start (what a figure shows without a path);
    ``work``: how the plan got there (None for a result built from a stored path); ``failure``: why
    the search found no path -- what blocked the goal candidates and path attempts, with
    suggestions (`ctrplan.planning.failure`; None when it found one or was not asked). Lengths in
    mm, scene frame; times in s.
    """

    solved: bool
    planner: str
    backend: str
    scene: str
    target_mm: np.ndarray
    goal_tolerance_mm: float
    base_pose: np.ndarray
    path: np.ndarray
    status: str = ""
    message: str = ""
    seed: int | None = None
    time_limit_s: float = 0.0
    max_states: int = 0
    planning_time_s: float = 0.0
    kinematics_calls: int = 0
    cut_short: bool = False
    dense: ValidatedPath | None = None
    start: Backbone | None = None
    work: PlanWork | None = None
    failure: FailureAnalysis | None = None

    @property
    def validated(self) -> Validation | None:
        """The exact validation's report of the path (None without a path)."""
        return None if self.dense is None else self.dense.report

    @property
    def tip_mm(self) -> np.ndarray | None:
        """The exact tip at the end of the validated path (3,), scene frame, mm."""
        return None if self.dense is None else np.asarray(self.dense.report.tip_mm)

    @property
    def states(self) -> int:
        """States the search evaluated (0 without a search)."""
        search = None if self.work is None else self.work.search
        return 0 if search is None else search.budget.states

    def to_json(self) -> dict:
        return {
            "solved": bool(self.solved),
            "planner": self.planner,
            "backend": self.backend,
            "planning_time_s": round(float(self.planning_time_s), 4),
            "kinematics_calls": int(self.kinematics_calls),
            "path": np.asarray(self.path, dtype=float).tolist(),
            "tip_mm": None if self.tip_mm is None else self.tip_mm.tolist(),
            "target_mm": np.asarray(self.target_mm, dtype=float).tolist(),
            "goal_tolerance_mm": float(self.goal_tolerance_mm),
            "base_pose": np.asarray(self.base_pose, dtype=float).tolist(),
            "validated": None if self.validated is None else self.validated.to_json(),
            "status": self.status,
            "message": self.message,
            "seed": self.seed,
            "time_limit_s": self.time_limit_s,
            "max_states": int(self.max_states),
            "cut_short": bool(self.cut_short),
            "scene": self.scene,
            "failure": None if self.failure is None else self.failure.to_json(),
            "details": {} if self.work is None else self.work.to_json(),
        }
