"""The finished designs of a study and their order: the best design (never below the base design) and
the Pareto front, from the study's records alone (see `ctrplan.design.outputs`)."""

from __future__ import annotations

from dataclasses import dataclass

import optuna

from ctrplan.design.record import DesignRecord
from ctrplan.design.study import NOMINAL, RECORD, dominates, finished_trials, ranking_key
from ctrplan.design.task import DesignTask


@dataclass(frozen=True)
class Design:
    """A finished trial: its number (None: the base design) and evaluation record."""

    trial: int | None
    record: DesignRecord


def designs_of(study: optuna.Study) -> list[Design]:
    """The study's finished trials, by number."""
    return [Design(t.number, DesignRecord.from_json(t.user_attrs[RECORD])) for t in finished_trials(study)]


def nominal_of(study: optuna.Study) -> Design | None:
    record = study.user_attrs.get(NOMINAL)
    return None if record is None else Design(None, DesignRecord.from_json(record))


def ranked(designs: list[Design], task: DesignTask) -> list[Design]:
    """The feasible designs, best first (objectives in order; ties by trial number)."""
    feasible = [d for d in designs if d.record.feasible]
    return sorted(feasible, key=lambda d: (ranking_key(d.record, task.objectives), d.trial))


def best_design(order: list[Design], nominal: Design | None, task: DesignTask) -> Design | None:
    """The best design: the first of the ranked trials ``order`` if it beats the base design
    ``nominal`` in the task's objective order, else the base design (when feasible; a tie keeps the
    base design: nothing was gained)."""
    top = order[0] if order else None
    if nominal is None or not nominal.record.feasible:
        return top
    if top is not None and ranking_key(top.record, task.objectives) < ranking_key(nominal.record,
                                                                                   task.objectives):
        return top
    return nominal


def pareto_front(designs: list[Design], task: DesignTask) -> list[Design]:
    """The feasible designs no other feasible design dominates, best first."""
    feasible = ranked(designs, task)
    return [d for d in feasible
            if not any(dominates(o.record, d.record, task.objectives) for o in feasible)]
