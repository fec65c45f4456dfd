"""What a design is judged by, registered once: every objective a task may name, its value in a
trial record (what the study optimises and ranks), and its cell in ``designs.csv``.

The task file, the study (directions, values told to Optuna, ranking, Pareto front), the outputs
(``designs.csv``, ``report.json``) and the report (figure titles, tables) read `OBJECTIVES`. Adding
an objective: one `Criterion` here, and its field of the record (`ctrplan.design.record.DesignRecord`)
written by `ctrplan.design.evaluate`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from ctrplan.design.record import DesignRecord


@dataclass(frozen=True)
class Criterion:
    """A registered objective: ``name`` (task files, the study, the ``designs.csv`` column),
    ``description`` (report), ``value(record)`` (a number for the study) and ``column(record)``
    (the ``designs.csv`` cell: None stays empty) of a `DesignRecord`."""

    name: str
    description: str
    value: Callable[[DesignRecord], float]
    column: Callable[[DesignRecord], Any]


def _count_reached(record: DesignRecord) -> int:
    return len(record.reached)


def _record_field(name: str) -> tuple[Callable[[DesignRecord], float], Callable[[DesignRecord], Any]]:
    """(value, column) of a record field: the number (0 where the record has None: a clearance without
    any reached target), and the raw entry."""

    def value(record: DesignRecord) -> float:
        v = getattr(record, name)
        return 0.0 if v is None else float(v)

    return value, lambda record: getattr(record, name)


#: Every objective by name, in ``designs.csv`` column order; ``targets_reached`` always comes first
#: in a task.
OBJECTIVES: dict[str, Criterion] = {c.name: c for c in (
    Criterion("targets_reached", "targets reached", lambda r: float(_count_reached(r)), _count_reached),
    Criterion("max_strain", "largest pre-curvature strain of a tube, kappa * OD / 2",
              *_record_field("max_strain")),
    Criterion("total_length_mm", "sum of the tube lengths (mm)", *_record_field("total_length_mm")),
    Criterion("min_clearance_mm",
              "smallest clearance to the anatomy along the paths to the reached targets (mm)",
              *_record_field("min_clearance_mm")),
)}


@dataclass(frozen=True)
class Objective:
    """An objective of a task: a registered `Criterion` by ``name``, maximised or (``-`` in the
    file) minimised."""

    name: str
    maximize: bool = True

    @property
    def criterion(self) -> Criterion:
        return OBJECTIVES[self.name]

    @property
    def label(self) -> str:
        """As in the task file: the name, ``-`` in front when minimised."""
        return self.name if self.maximize else f"-{self.name}"

    @property
    def direction(self) -> str:
        """Optuna's study direction."""
        return "maximize" if self.maximize else "minimize"

    @property
    def axis_label(self) -> str:
        """The name and direction, e.g. ``max_strain (minimised)``."""
        return f"{self.name} ({'max' if self.maximize else 'min'}imised)"

    def value(self, record: DesignRecord) -> float:
        """The objective's value in a trial record (what the study is told)."""
        return self.criterion.value(record)

    def rank(self, record: DesignRecord) -> float:
        """Sort key, lower is better."""
        v = self.value(record)
        return -v if self.maximize else v
