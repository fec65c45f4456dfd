"""Measured tips for few-shot fine-tuning (paper stage b): which rows train, which are held out,
and the observations the PINN is trained on.

The rows are split as `ctrplan diagnose` splits them (`ctrplan.calibration.split.split_rows`: a
fraction held out in contiguous blocks, or the last rows); the ``shots`` are the first training rows in
acquisition order -- what a user who measured that many configurations has, and what `diagnose` on
the first rows of a file fits (on the hjhdog1 data, 20 runs spread over the training rows made
`diagnose` name bending stiffness instead of the heat-set curve: 3.24 against 2.14 mm on the last
rows); the last `VALIDATION_FRACTION` of the shots validate the stages of `ctrplan.training.finetune`.
Rows outside the snap-free domain -- which the reader accepts and flags -- are used neither for
training nor in the held-out error: the PINN and its collocation points cover the snap-free domain
only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ctrplan.base.errors import InputError
from ctrplan.calibration.data import MeasuredData
from ctrplan.calibration.split import split_rows
from ctrplan.model.motion import Motion
from ctrplan.model.robot import Robot
from ctrplan.training.trainer import Observations


@dataclass(frozen=True)
class FewShot:
    """Measured data split for fine-tuning; row indices are 0-based into ``data``, sorted."""

    data: MeasuredData
    motion: Motion              # the motion history of every row, from the full sequence
    shots: np.ndarray           # training rows used
    heldout: np.ndarray         # held-out rows inside the snap-free domain
    train_rows: int             # training rows inside the domain (shots were drawn from these)
    heldout_fraction: float
    seed: int
    heldout_last: bool = False  # the last rows held out (else contiguous blocks drawn with seed)

    @property
    def excluded(self) -> np.ndarray:
        """Rows outside the snap-free domain (not used)."""
        return np.flatnonzero(self.data.outside_domain)


def split_shots(data: MeasuredData, shots: int | None = None, heldout_fraction: float = 0.25,
                seed: int = 0, heldout_last: bool = False) -> FewShot:
    """Hold out rows as `diagnose` does (same defaults): contiguous blocks, or the last rows with
    ``heldout_last``; the shots are the first ``shots`` training rows (all if None)."""
    if shots is not None and shots < 1:
        raise InputError(f"shots: must be >= 1, got {shots}")
    split = split_rows(len(data), heldout_fraction, last=heldout_last, seed=seed)
    train, heldout = split.train, split.heldout
    inside = ~data.outside_domain
    train, heldout = train[inside[train]], heldout[inside[heldout]]
    shots = len(train) if shots is None else shots
    if shots > len(train) or not shots:
        raise InputError(f"shots: {shots} requested but {data.source} has {len(train)} training rows "
                         f"inside the snap-free domain ({len(heldout)} held out with heldout_fraction "
                         f"{heldout_fraction:g})")
    return FewShot(data=data, motion=data.motion(),
                   shots=train[:shots], heldout=heldout,
                   train_rows=len(train), heldout_fraction=heldout_fraction, seed=seed,
                   heldout_last=heldout_last)


#: Share of the shots (the last ones in acquisition order) kept apart to choose between the stages.
VALIDATION_FRACTION = 0.2


def validation_split(fs: FewShot) -> tuple[np.ndarray, np.ndarray]:
    """The shots split into rows to fit and validation rows (the last `VALIDATION_FRACTION` of them,
    at least one; none when there are fewer than 5 shots)."""
    k = int(round(VALIDATION_FRACTION * len(fs.shots))) if len(fs.shots) >= 5 else 0
    return fs.shots[:len(fs.shots) - k], fs.shots[len(fs.shots) - k:]


def mechanics_joints(robot: Robot, fs: FewShot, rows: np.ndarray, alone: bool = False) -> np.ndarray:
    """Joints (R, 2N) the mechanics of ``robot`` sees for ``rows`` (its joint offsets not applied): the
    robot's calibration maps the reported joints (backlash, windup, a learned lag) in the order of the
    whole sequence, or with ``alone`` of the rows by themselves -- as `ctrplan fk` sees a file of them."""
    return robot.calibration.mechanics_joints(fs.data.q[rows], None if alone else fs.motion.subset(rows))


def model_joints(robot: Robot, fs: FewShot, rows: np.ndarray, alone: bool = False) -> np.ndarray:
    """Joints (R, 2N) the model sees for ``rows``: `mechanics_joints`, then the joint offsets (mm, rad)."""
    return robot.apply_offset(mechanics_joints(robot, fs, rows, alone))


def sensor_offset_mm(robot: Robot) -> np.ndarray | None:
    """The tracked point's offset (3,) mm in the tip frame of tube 1, if the calibration has one."""
    if not robot.calibration.needs_tip_rotation:
        return None
    return robot.calibration.values("sensor_offset", 3)


def observations(robot: Robot, fs: FewShot, rows: np.ndarray) -> Observations:
    """Training observations of ``rows`` (shots) for `trainer.train`: the model's joints, the measured
    tips in the robot frame (NaN for tubes that were not measured) and the sensor offset, all from the
    robot's calibration."""
    tips = robot.calibration.to_robot_frame(fs.data.tips_mm[rows])
    return Observations(model_joints(robot, fs, rows), tips, sensor_offset_mm(robot))
