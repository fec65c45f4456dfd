"""The extended robot file: `Robot.to_dict()` plus a top-level ``calibration`` mapping (written only
when the `Calibration` is not the identity); see `ctrplan.measurement`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ctrplan.dataio import atomic_write
from ctrplan.measurement import CALIBRATION_KEY, Calibration
from ctrplan.robot import Robot

__all__ = ["CALIBRATION_KEY", "Calibration", "extended_robot_dict", "load_extended_robot",
           "write_extended_robot"]


def load_extended_robot(spec: str | Path | None) -> tuple[Robot, Calibration]:
    """A robot (built-in name or file, e.g. the extended robot file written by ``ctrplan diagnose``)
    and its `Calibration` (identity unless the file has a ``calibration`` mapping)."""
    robot = Robot.load(spec)
    return robot, robot.calibration


def extended_robot_dict(robot: Robot, calibration: Calibration | None = None) -> dict[str, Any]:
    """`Robot.to_dict()` with ``calibration`` (if given) in place of the robot's own."""
    return robot.with_changes(calibration=calibration or robot.calibration).to_dict()


def write_extended_robot(path: str | Path, robot: Robot, calibration: Calibration | None = None,
                         comment: str = "") -> None:
    """Write the extended robot file (atomic). ``comment`` lines go on top as YAML comments."""
    d = extended_robot_dict(robot, calibration)
    text = yaml.safe_dump(_plain(d), sort_keys=False, default_flow_style=None, width=100)
    head = "".join(f"# {ln}\n" if ln else "#\n" for ln in comment.splitlines())
    with atomic_write(path) as fh:
        fh.write(head + text)


def _plain(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, (np.floating, float)):
        return float(obj)
    if isinstance(obj, (np.integer,)):
        return int(obj)
    return obj

