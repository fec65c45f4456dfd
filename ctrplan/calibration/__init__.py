"""Measured data: show what the model gets wrong, name the physical cause, extend the model, measure
the gain (``ctrplan diagnose``).

Modules: `data` (readers, split), `model` (`Calibration`: registration and backlash), `calibration`
(the extended robot file), `effects` (candidate causes), `fit` (batched least squares), `diagnosis`
(selection and report), `where` and `plots` (where the error grows), `synthetic` (data with a hidden
cause), `study` (confusion table).

Attributes are imported lazily so that `ctrplan.robot` may import `ctrplan.calibration.model`.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "CAUSES": "effects",
    "Calibration": "model",
    "DiagnoseOptions": "diagnosis",
    "Diagnosis": "diagnosis",
    "MeasuredData": "data",
    "diagnose": "diagnosis",
    "extended_robot_dict": "calibration",
    "load_extended_robot": "calibration",
    "make_effect": "effects",
    "motion_direction": "model",
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
    value = getattr(importlib.import_module(f"ctrplan.calibration.{module}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(list(globals()) + __all__)
