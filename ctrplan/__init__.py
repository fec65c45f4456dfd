"""ctrplan: motion planning for concentric-tube robots.

Kinematics backends (exact Cosserat-rod shooting, PINN surrogate, hybrid) return full backbones;
FCL checks them against scene meshes inside OMPL planners over the snap-free actuation space.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("ctrplan")
except PackageNotFoundError:  # running from a source tree
    __version__ = "0.0.0+src"

from ctrplan.errors import DomainError, InputError
from ctrplan.robot import JointDomain, Loads, Robot, Tube

__all__ = ["DomainError", "InputError", "JointDomain", "Loads", "Robot", "Tube", "__version__"]
