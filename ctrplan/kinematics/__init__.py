"""Kinematics backends: joints in, full backbones out (`Backbone`); elastic stability of the equilibria.

``make_backend(name, robot)`` builds one by name: ``cosserat`` (exact shooting solver), ``pinn``
(physics-informed surrogate; shipped: ``ctrplan/data/models/pinn_nominal``) or ``hybrid`` (PINN-seeded
shooting). They are registered once, in `ctrplan.kinematics.registry`.
"""

from __future__ import annotations

from pathlib import Path

from ctrplan.kinematics.backbone import STATE_NAMES, STATE_UNITS, Backbone
from ctrplan.kinematics.base import Backend, Body
from ctrplan.kinematics.cosserat import CosseratBackend, SolverSettings
from ctrplan.kinematics.registry import (
    BACKEND_KINDS,
    BACKENDS,
    DEFAULT_PLANNING_BACKEND,
    EXACT_MODEL,
    MODEL_BACKENDS,
    PLANNING_ORDER,
    BackendKind,
    backend_kind,
    exact_companion,
)
from ctrplan.model.robot import Robot


def make_backend(name: str, robot: Robot | None = None, model: str | Path | None = None) -> Backend:
    """Backend by name (`BACKEND_KINDS`); ``model`` picks the PINN weights of a backend that uses one
    (default: shipped)."""
    return backend_kind(name).build(robot or Robot.nominal(), model)


__all__ = ["BACKENDS", "BACKEND_KINDS", "DEFAULT_PLANNING_BACKEND", "EXACT_MODEL", "MODEL_BACKENDS",
           "PLANNING_ORDER", "STATE_NAMES", "STATE_UNITS", "Backbone", "Backend", "BackendKind", "Body",
           "CosseratBackend", "SolverSettings", "backend_kind", "exact_companion", "make_backend"]
