"""Measured data: show what the model gets wrong, name the physical cause, extend the model, measure
the gain (``ctrplan diagnose``).

Modules: `data` (readers, split), `calibration` (the extended robot file), `effects` (candidate
causes), `fit` (batched least squares), `noise` (measurement noise from the data alone), `diagnosis`
(selection, stability and report), `where` and `plots` (where the error grows), `synthetic` (data with
a hidden cause), `study` (confusion table).

The fitted `Calibration` (registration, backlash, sensor offset, torsional windup) lives with the robot
model in `ctrplan.measurement`.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "CAUSES": "effects",
    "Calibration": "ctrplan.measurement",
    "DiagnoseOptions": "diagnosis",
    "Diagnosis": "diagnosis",
    "MeasuredData": "data",
    "diagnose": "diagnosis",
    "extended_robot_dict": "calibration",
    "load_extended_robot": "calibration",
    "make_effect": "effects",
    "motion_direction": "ctrplan.measurement",
    "read_measured": "data",
    "split_blocks": "data",
    "write_crl_csv": "data",
    "write_extended_robot": "calibration",
    "write_measured_csv": "data",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'ctrplan.calibration' has no attribute {name!r}")
    path = module if "." in module else f"ctrplan.calibration.{module}"
    value = getattr(importlib.import_module(path), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(list(globals()) + __all__)
