"""Calibrating a robot model from measured tips (``ctrplan diagnose``): show what the model gets
wrong, name the physical cause, extend the model, measure the gain.

Modules: `data` (readers and writers of measured data), `split` (which rows train and which are
held out), `predict` (the tips of many models on the rows, batched), `fit` (least squares), `noise`
(measurement noise from the data alone), `selection` (significance, stability and the named causes),
`diagnosis` (the procedure and its result) with its knobs in `options` and its text in `report`,
`where` (where the error grows; its plots are `ctrplan.viz.diagnosis_plots`), `synthetic` (generated
data with a hidden cause). The library of causes, each registered by its class, is
`ctrplan.model.causes`: part of the robot model (a robot's calibration holds its measurement-side
causes), below this package.

The result is one extended `ctrplan.model.robot.Robot`: its mechanics in its fields, its measurement side
in `Robot.calibration` (`ctrplan.model.measurement.Calibration` -- what "calibration" means on a robot).
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "CAUSES": "ctrplan.model.causes",
    "DEFAULT_CAUSES": "ctrplan.model.causes",
    "Calibration": "ctrplan.model.measurement",
    "DiagnoseOptions": "options",
    "Diagnosis": "diagnosis",
    "EFFECTS": "ctrplan.model.causes.base",
    "MeasuredData": "data",
    "Split": "split",
    "diagnose": "diagnosis",
    "make_effect": "ctrplan.model.causes.base",
    "Motion": "ctrplan.model.motion",
    "motion_direction": "ctrplan.model.motion",
    "read_measured": "data",
    "split_rows": "split",
    "write_crl_csv": "data",
    "write_measured_csv": "data",
    "write_outputs": "diagnosis",
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
