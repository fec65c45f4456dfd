"""Kinematics backends: joints in, full backbones out (`Backbone`)."""

from ctrplan.kinematics.backbone import STATE_NAMES, STATE_UNITS, Backbone
from ctrplan.kinematics.base import Backend
from ctrplan.kinematics.cosserat import CosseratBackend, SolverSettings

__all__ = ["BACKENDS", "make_backend", "STATE_NAMES", "STATE_UNITS", "Backbone", "Backend", "CosseratBackend", "SolverSettings"]


def make_backend(name: str, robot=None, **kwargs) -> Backend:
    """Backend by name: ``cosserat`` (exact), ``pinn`` (shipped surrogate), ``hybrid``."""
    from ctrplan.errors import InputError

    if name == "cosserat":
        return CosseratBackend(robot, **kwargs)
    raise InputError(f"--backend: unknown backend {name!r} (available: {', '.join(BACKENDS)})")


BACKENDS = ("cosserat",)
