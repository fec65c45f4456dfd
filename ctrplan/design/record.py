"""The record of one design's evaluation, typed: what `ctrplan.design.evaluate` found out, what the
objectives read (`ctrplan.design.objectives`), what the study keeps in its storage (``to_json``, the
trial's user attribute ``record``; ``from_json`` reads it back) and what the outputs show.

Lengths in mm, times in s, strain as a fraction, joints in mm and rad.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Any


@dataclass(frozen=True)
class Infeasible:
    """Why a design is infeasible: the first condition it fails (``robot``, ``max_strain``,
    ``domain``, ``snap_free`` or ``start``) and the reason in words."""

    constraint: str
    message: str


@dataclass(frozen=True)
class StabilityVerdict:
    """Whether a design's joint domain is snap-free, from a ``certificate`` or a ``sweep`` (with the
    configurations ``checked``), and where it snaps if not (``example_q``, joints; ``example_reason``)."""

    snap_free: bool
    source: str
    checked: int | None = None
    example_q: list[float] | None = None
    example_reason: str | None = None


@dataclass(frozen=True)
class TargetRecord:
    """One target of a design: ``reached`` (a validated path), the ``stage`` it got to (``screen``:
    no goal configuration; ``plan``), what happened, the goal configurations the screen found, the
    planning seed, the plan's time, kinematics calls, work (``states``) and whether a wall-clock guard
    cut it short, and -- reached targets only -- the path's clearance and its joints (K, 2N)."""

    name: str
    reached: bool = False
    stage: str = "screen"
    message: str = ""
    goals: int = 0
    seed: int = 0
    planning_time_s: float | None = None
    kinematics_calls: int | None = None
    states: int | None = None
    cut_short: bool = False
    min_clearance_mm: float | None = None
    path: list[list[float]] | None = None


@dataclass(frozen=True)
class DesignTimings:
    """Seconds of an evaluation's stages (None: the stage did not run)."""

    stability_s: float | None = None
    start_s: float | None = None
    screen_s: float | None = None
    plan_s: float | None = None


@dataclass(frozen=True)
class DesignRecord:
    """One design's evaluation (see `ctrplan.design.evaluate.evaluate`): its ``parameters``, whether
    it is ``feasible`` (else why: ``infeasible``), its largest pre-curvature strain, total tube length
    (mm) and robot file (as a dict), the robot's fingerprint, the stability verdict (with
    ``snap_free`` constraints), the start (joints), every target's record, and the time (s) it took
    in all and per stage."""

    parameters: dict[str, Any]
    feasible: bool
    max_strain: float
    total_length_mm: float
    robot: dict[str, Any]
    infeasible: Infeasible | None = None
    fingerprint: str | None = None
    stability: StabilityVerdict | None = None
    start: list[float] | None = None
    targets: tuple[TargetRecord, ...] = ()
    time_s: float = 0.0
    timings: DesignTimings = DesignTimings()

    @property
    def reached(self) -> list[str]:
        """Names of the targets reached."""
        return [t.name for t in self.targets if t.reached]

    @property
    def cut_short(self) -> list[str]:
        """Names of the targets whose verdict a wall-clock guard decided (empty unless the machine was
        far slower than the reference)."""
        return [t.name for t in self.targets if t.cut_short]

    @property
    def min_clearance_mm(self) -> float | None:
        """The smallest clearance over the reached targets' paths (mm; None if none is reached)."""
        reached = [t.min_clearance_mm for t in self.targets if t.reached]
        return min(reached) if reached else None

    def target(self, name: str) -> TargetRecord:
        return next(t for t in self.targets if t.name == name)

    def to_json(self) -> dict[str, Any]:
        """The record as the study stores it (JSON types only)."""
        return {
            "parameters": dict(self.parameters), "feasible": self.feasible,
            "infeasible": None if self.infeasible is None else asdict(self.infeasible),
            "max_strain": self.max_strain, "total_length_mm": self.total_length_mm, "robot": self.robot,
            "fingerprint": self.fingerprint,
            "stability": None if self.stability is None else asdict(self.stability),
            "start": self.start, "targets": [asdict(t) for t in self.targets], "reached": self.reached,
            "cut_short": self.cut_short, "min_clearance_mm": self.min_clearance_mm, "time_s": self.time_s,
            "timings": {k: v for k, v in asdict(self.timings).items() if v is not None},
        }

    @classmethod
    def from_json(cls, doc: dict[str, Any]) -> DesignRecord:
        """The record ``to_json`` wrote (the derived lists -- reached, cut short, clearance -- are
        recomputed from the targets)."""
        own = {f.name for f in fields(cls)}
        kw = {k: v for k, v in doc.items() if k in own}
        kw["infeasible"] = None if doc["infeasible"] is None else Infeasible(**doc["infeasible"])
        kw["stability"] = None if doc["stability"] is None else StabilityVerdict(**doc["stability"])
        kw["targets"] = tuple(TargetRecord(**t) for t in doc["targets"])
        kw["timings"] = DesignTimings(**doc.get("timings", {}))
        return cls(**kw)
