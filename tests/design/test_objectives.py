"""Design objectives: direction, value and ranking from hand-made trial records."""

from __future__ import annotations

from ctrplan.design.objectives import OBJECTIVES, Objective
from ctrplan.design.study import dominates, ranking_key


def _record(reached: int, strain: float, length: float, clearance: float | None) -> dict:
    return {"reached": [f"t{i}" for i in range(reached)], "max_strain": strain, "total_length_mm": length,
            "min_clearance_mm": clearance}


def test_objectives_read_the_record_and_rank_by_direction():
    targets, strain = Objective("targets_reached"), Objective("max_strain", maximize=False)
    clearance = Objective("min_clearance_mm")
    a, b = _record(2, 0.05, 300.0, None), _record(2, 0.03, 310.0, 1.5)
    assert targets.value(a) == 2.0 and strain.value(b) == 0.03
    assert clearance.value(a) == 0.0 and clearance.value(b) == 1.5  # no reached path: clearance 0
    assert (targets.direction, strain.direction) == ("maximize", "minimize")
    assert strain.label == "-max_strain" and strain.axis_label == "max_strain (minimised)"
    objectives = (targets, strain)
    assert ranking_key(b, objectives) == (-2.0, 0.03) < ranking_key(a, objectives)
    assert dominates(b, a, objectives) and not dominates(a, b, objectives)
    assert not dominates(a, a, objectives)


def test_designs_csv_cells_keep_missing_values_empty():
    r = _record(1, 0.02, 250.0, None)
    assert list(OBJECTIVES)[0] == "targets_reached"
    assert [c.column(r) for c in OBJECTIVES.values()] == [1, 0.02, 250.0, None]
