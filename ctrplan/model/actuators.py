"""Joints in a controller's units: a robot file's ``actuators:`` mapping (for ``trajectory.csv``).

    actuators:                       # optional; joints not listed get no actuator column
      beta1: {counts_per_mm: 2000, offset: 50000, sign: -1, name: m_inner}   # a linear stage
      alpha1: {counts_per_rad: 651.9, offset: 0}                            # a rotary drive

Actuator value ``= sign * counts_per_unit * joint + offset`` (joint in mm for a translation, rad for a
rotation; ``counts_per_mm`` belongs to a ``betaI``, ``counts_per_rad`` to an ``alphaI``, > 0;
``sign`` 1 or -1, default 1; ``offset`` in counts, default 0); its rate is ``sign * counts_per_unit *
joint velocity`` (counts/s). ``name`` names the column (default ``<joint>_counts``; the rate column
adds ``_per_s``). How a robot is driven is not its mechanics: the fingerprint leaves it out.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

import numpy as np

from ctrplan.base.yamlio import YamlDoc

ACTUATORS_KEY = "actuators"
_COLUMN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


@dataclass(frozen=True)
class Actuator:
    """One joint's actuator: ``joint`` (index into q), counts per mm or rad, offset (counts), sign,
    and the name of its column."""

    joint: int
    counts_per_unit: float
    offset: float = 0.0
    sign: int = 1
    name: str = ""

    def position(self, q: np.ndarray) -> np.ndarray:
        """Actuator values (...,) of joints q (..., 2N)."""
        return self.sign * self.counts_per_unit * np.asarray(q)[..., self.joint] + self.offset

    def rate(self, qd: np.ndarray) -> np.ndarray:
        """Actuator rates (...,) (counts/s) of joint velocities qd (..., 2N)."""
        return self.sign * self.counts_per_unit * np.asarray(qd)[..., self.joint]

    def to_dict(self, joint_names: tuple[str, ...]) -> dict[str, Any]:
        unit = "counts_per_mm" if joint_names[self.joint].startswith("beta") else "counts_per_rad"
        return {unit: self.counts_per_unit, "offset": self.offset, "sign": self.sign, "name": self.name}


def actuators_from_yaml(doc: YamlDoc, joint_names: tuple[str, ...]) -> tuple[Actuator, ...]:
    """The ``actuators`` of a robot file (see the module docstring); errors name the key and line."""
    raw = doc.data.get(ACTUATORS_KEY)
    if raw is None:
        return ()
    keys = (ACTUATORS_KEY,)
    if not isinstance(raw, dict):
        raise doc.error(keys, "expected a mapping of joint names to actuators")
    out: list[Actuator] = []
    for joint, spec in raw.items():
        k = keys + (str(joint),)
        if joint not in joint_names:
            raise doc.error(k, f"not a joint of this robot (joints: {', '.join(joint_names)})")
        unit = "counts_per_mm" if str(joint).startswith("beta") else "counts_per_rad"
        if not isinstance(spec, dict):
            raise doc.error(k, f"expected a mapping with {unit} (and offset, sign, name)")
        allowed = {unit, "offset", "sign", "name"}
        for key in spec:
            if key not in allowed:
                raise doc.error(k + (key,), f"unknown key (allowed: {', '.join(sorted(allowed))})")
        if unit not in spec:
            raise doc.error(k, f"missing required key {unit!r}")
        scale, offset = spec[unit], spec.get("offset", 0.0)
        if not _finite(scale) or scale <= 0:
            raise doc.error(k + (unit,), f"expected a finite number > 0, got {scale!r} (the direction "
                                         f"goes in 'sign')")
        if not _finite(offset):
            raise doc.error(k + ("offset",), f"expected a finite number (counts), got {offset!r}")
        sign = spec.get("sign", 1)
        if isinstance(sign, bool) or sign not in (1, -1):
            raise doc.error(k + ("sign",), f"expected 1 or -1, got {sign!r}")
        name = spec.get("name", f"{joint}_counts")
        if not isinstance(name, str) or not _COLUMN.match(name) or name in joint_names or \
                any(a.name == name for a in out):
            raise doc.error(k + ("name",), f"expected a column name of its own (letters, digits, _), got "
                                           f"{name!r}")
        out.append(Actuator(joint_names.index(joint), float(scale), float(offset), int(sign), name))
    return tuple(sorted(out, key=lambda a: a.joint))


def _finite(value: Any) -> bool:
    return not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)
