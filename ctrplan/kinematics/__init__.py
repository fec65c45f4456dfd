"""Kinematics backends: joints in, full backbones out (`Backbone`).

``make_backend(name, robot)`` builds one by name: ``cosserat`` (exact shooting solver), ``pinn``
(physics-informed surrogate; shipped: ``ctrplan/data/models/pinn_nominal``) or ``hybrid`` (PINN-seeded
shooting).
"""

from __future__ import annotations

from pathlib import Path

from ctrplan.errors import InputError
from ctrplan.kinematics.backbone import STATE_NAMES, STATE_UNITS, Backbone
from ctrplan.kinematics.base import Backend, Body
from ctrplan.kinematics.cosserat import CosseratBackend, SolverSettings
from ctrplan.robot import Robot

BACKENDS = ("cosserat", "pinn", "hybrid")


def make_backend(name: str, robot: Robot | None = None, model: str | Path | None = None) -> Backend:
    """Backend by name; ``model`` picks the PINN weights for ``pinn``/``hybrid`` (default: shipped)."""
    robot = robot or Robot.nominal()
    if name == "cosserat":
        return CosseratBackend(robot)
    if name == "pinn":
        from ctrplan.kinematics.pinn import PinnBackend

        return PinnBackend.load(model, robot)
    if name == "hybrid":
        from ctrplan.kinematics.hybrid import HybridBackend

        return HybridBackend(robot, model)
    raise InputError(f"backend: unknown backend {name!r} (available: {', '.join(BACKENDS)})")


__all__ = ["BACKENDS", "STATE_NAMES", "STATE_UNITS", "Backbone", "Backend", "Body", "CosseratBackend",
           "SolverSettings", "make_backend"]
