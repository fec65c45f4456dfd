"""ctrplan: motion planning for concentric-tube robots.

Kinematics backends (exact Cosserat-rod shooting, PINN surrogate, hybrid) return full backbones;
FCL checks them against scene meshes inside OMPL planners over the robot's snap-free actuation space.

The small API is here (imported on first use, so ``ctrplan --version`` stays fast)::

    import ctrplan
    robot = ctrplan.Robot.nominal()
    bb = ctrplan.make_backend("cosserat", robot).forward(robot.sample_joints(8, rng=0))
    result = ctrplan.plan(ctrplan.load_scene("scenes/skullbase.yaml"), "pinn")
"""

from __future__ import annotations

import importlib
from importlib.metadata import PackageNotFoundError, version
from typing import Any

try:
    __version__ = version("ctrplan")
except PackageNotFoundError:  # running from a source tree
    __version__ = "0.0.0+src"

_API = {
    "DomainError": "ctrplan.base.errors", "InputError": "ctrplan.base.errors",
    "Robot": "ctrplan.model.robot", "Tube": "ctrplan.model.robot", "JointDomain": "ctrplan.model.robot",
    "Loads": "ctrplan.model.robot",
    "Backbone": "ctrplan.kinematics", "Backend": "ctrplan.kinematics",
    "CosseratBackend": "ctrplan.kinematics", "SolverSettings": "ctrplan.kinematics",
    "make_backend": "ctrplan.kinematics",
    "PinnBackend": "ctrplan.kinematics.pinn",
    "load_scene": "ctrplan.scene.loader", "plan": "ctrplan.planning",
    "check_domain": "ctrplan.kinematics.stability",
}

__all__ = sorted([*_API, "__version__"])


def __getattr__(name: str) -> Any:
    module = _API.get(name)
    if module is None:
        raise AttributeError(f"module 'ctrplan' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return __all__
