"""The kinematics backend interface shared by the Cosserat solver, the PINN and the hybrid."""

from __future__ import annotations

from abc import ABC, abstractmethod
from functools import lru_cache

import numpy as np

from ctrplan.errors import InputError
from ctrplan.kinematics.backbone import Backbone
from ctrplan.robot import Robot

DEFAULT_POINTS = 64


@lru_cache(maxsize=64)
def _uniform_fractions(n: int) -> np.ndarray:
    frac = np.linspace(0.0, 1.0, n)
    frac.flags.writeable = False
    return frac


def arc_fractions(points: int | np.ndarray) -> np.ndarray:
    """Output arc lengths as fractions of l1: ``points`` uniform samples in [0, 1], or the given
    ascending fractions (N,)."""
    if np.isscalar(points):
        n = int(points)
        if n < 2:
            raise InputError(f"points: need at least 2 backbone points, got {n}")
        return _uniform_fractions(n)
    frac = np.asarray(points, dtype=float).ravel()
    if frac.size < 1 or not np.all(np.isfinite(frac)) or frac.min() < 0 or frac.max() > 1 \
            or np.any(np.diff(frac) < 0):
        raise InputError("points: arc fractions must be ascending values in [0, 1]")
    return frac


def outer_radius_along(robot: Robot, s_mm: np.ndarray, ends_mm: np.ndarray) -> np.ndarray:
    """Outer radius (mm) of the outermost tube present at each arc length; s (B, N), ends (B, 3)."""
    radii = robot.outer_radii_mm
    out = np.full(s_mm.shape, radii[0])
    for i in (1, 2):
        out = np.where(s_mm <= ends_mm[:, i:i + 1] + 1e-9, radii[i], out)
    return out


class Backend(ABC):
    """Turns joint configurations into backbones. Batched: q is (6,) or (B, 6); output has B rows.

    Implementations keep the robot (immutable model) apart from any per-call workspace.
    """

    name: str = "backend"

    def __init__(self, robot: Robot):
        self.robot = robot

    @abstractmethod
    def forward(self, q: np.ndarray, points: int | np.ndarray = DEFAULT_POINTS, *,
                check: bool = True) -> Backbone:
        """Backbones of configurations q (mm, rad) at ``points`` arc lengths (count or fractions of l1).

        With ``check``, joints are validated against the robot (`Robot.check_joints`).
        """

    def describe(self) -> dict:
        """Settings that shape this backend's backbones (JSON-ready), reported next to its timings."""
        return {}

    def tips(self, q: np.ndarray, *, check: bool = True) -> np.ndarray:
        """Tube tip positions (B, 3, 3), mm."""
        return self.forward(q, points=2, check=check).tips_mm
