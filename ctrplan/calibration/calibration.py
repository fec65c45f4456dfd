"""The extended robot file: `Robot.to_dict()` plus a top-level ``calibration`` mapping (written only
when the `Calibration` is not the identity); see `ctrplan.calibration.model`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ctrplan.calibration.model import CALIBRATION_KEY, Calibration
from ctrplan.dataio import atomic_write
from ctrplan.robot import BUILTIN_ROBOTS, Robot, robot_from_yaml
from ctrplan.yamlio import YamlDoc, load_yaml

__all__ = ["CALIBRATION_KEY", "Calibration", "extended_robot_dict", "load_extended_robot",
           "write_extended_robot"]


def load_extended_robot(spec: str | Path | None) -> tuple[Robot, Calibration]:
    """Load a robot file that may carry a ``calibration`` mapping (the extended robot file written
    by ``ctrplan diagnose``); built-in names and plain robot files give an identity calibration."""
    if spec is None or str(spec) in BUILTIN_ROBOTS:
        return Robot.load(spec), Calibration()
    doc = load_yaml(spec)
    calib = Calibration.from_doc(doc)
    rest = {k: v for k, v in doc.data.items() if k != CALIBRATION_KEY}
    robot = robot_from_yaml(YamlDoc(data=rest, path=doc.path, lines=doc.lines))
    return robot, calib


def extended_robot_dict(robot: Robot, calibration: Calibration | None = None) -> dict[str, Any]:
    """`Robot.to_dict()` plus the ``calibration`` mapping when it is not the identity."""
    d = robot.to_dict()
    if calibration is not None and not calibration.is_identity:
        d[CALIBRATION_KEY] = calibration.to_dict()
    return d


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

