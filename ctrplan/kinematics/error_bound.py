"""A surrogate's calibrated backbone position error bound, as its model card stores it
(``ctrplan.training.evaluate.error_bound`` writes it; `Backend.error_bound` reads it): bounds (mm) by
arc-length region of the backbone and coverage. Read here, below the planning layer, which plans with
them as capsule margins."""

from __future__ import annotations

import math

import numpy as np

from ctrplan.base.errors import InputError


def region_bounds_mm(bound: dict, coverage: float) -> list[float]:
    """The bound (mm) of every region at ``coverage``; `InputError` naming ``surrogate_coverage``
    if the card has no bound at that coverage."""
    covs = bound["coverages"]
    hits = [i for i, c in enumerate(covs) if math.isclose(c, coverage)]
    if not hits:
        raise InputError(f"surrogate_coverage: the model card has error bounds at coverages "
                         f"{', '.join(f'{c:g}' for c in covs)} only, not {coverage:g}")
    return [r["bound_mm"][hits[0]] for r in bound["regions"]]


def region_margins_mm(bound: dict, coverage: float, s_fraction: np.ndarray) -> np.ndarray:
    """The bound (mm) at ``coverage`` of the region each arc fraction (any shape) falls in."""
    out = np.zeros(np.shape(s_fraction))
    for r, b in zip(bound["regions"], region_bounds_mm(bound, coverage), strict=True):
        lo, hi = r["s_fraction"]
        out = np.where((s_fraction >= lo) & (s_fraction <= hi), np.maximum(out, b), out)
    return out
