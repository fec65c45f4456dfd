"""Design objectives: direction, value and ranking from hand-made trial records."""

from __future__ import annotations

from ctrplan.design.objectives import OBJECTIVES, Objective
from ctrplan.design.record import DesignRecord, TargetRecord
from ctrplan.design.study import dominates, ranking_key


def _record(reached: int, strain: float, length: float, clearances: tuple[float, ...] = ()) -> DesignRecord:
    """A feasible design that reaches ``reached`` of five targets, the paths with these clearances."""
    gaps = clearances or (1.0,) * reached
    targets = tuple(TargetRecord(f"t{i}", reached=i < reached, stage="plan",
                                 min_clearance_mm=gaps[i] if i < reached else None) for i in range(5))
    return DesignRecord({}, True, strain, length, {}, targets=targets)


def test_objectives_read_the_record_and_rank_by_direction():
    targets, strain = Objective("targets_reached"), Objective("max_strain", maximize=False)
    clearance = Objective("min_clearance_mm")
    a, b = _record(2, 0.05, 300.0, (2.5, 0.7)), _record(2, 0.03, 310.0, (1.5, 1.6))
    assert targets.value(a) == 2.0 and strain.value(b) == 0.03
    assert clearance.value(a) == 0.7 and clearance.value(b) == 1.5  # the worst reached path
    assert clearance.value(_record(0, 0.05, 300.0)) == 0.0  # no reached path: clearance 0
    assert (targets.direction, strain.direction) == ("maximize", "minimize")
    assert strain.label == "-max_strain" and strain.axis_label == "max_strain (minimised)"
    objectives = (targets, strain)
    assert ranking_key(b, objectives) == (-2.0, 0.03) < ranking_key(a, objectives)
    assert dominates(b, a, objectives) and not dominates(a, b, objectives)
    assert not dominates(a, a, objectives)


def test_designs_csv_cells_keep_missing_values_empty():
    r = _record(0, 0.02, 250.0)
    assert list(OBJECTIVES)[0] == "targets_reached"
    assert [c.column(r) for c in OBJECTIVES.values()] == [0, 0.02, 250.0, None]
