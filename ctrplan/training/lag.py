"""Learn from the shots the direction-dependent lag of the rotation joints that the cause library's
backlash (an instant flip at each reversal) does not describe: play and hysteresis that take some travel
to build up after a reversal (`ctrplan.model.measurement.LagCorrection`, a Prandtl-Ishlinskii model whose
inputs are the direction of motion and play operators of a few radii).

The weights enter linearly through the joints, so they are fitted by Gauss-Newton on the extended
robot's Cosserat model (tip Jacobians by finite differences of the rotations), with a small ridge.
`ctrplan.training.finetune` keeps the correction only when it lowers the error on the validation shots.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ctrplan.kinematics.cosserat import CosseratBackend
from ctrplan.model.measurement import LagCorrection, play_features
from ctrplan.model.robot import Robot

#: Play radii of the correction (rad): 0 is the direction of motion (backlash); the others let the lag
#: build up over 1, 3 and 6 degrees of travel after a reversal.
RADII_RAD = (0.0, math.radians(1.0), math.radians(3.0), math.radians(6.0))
#: Largest weight (rad) a fit may give one play operator: the backlash ceiling of the cause library.
MAX_WEIGHT_RAD = 0.1
FD_STEP_RAD = 1e-4
RIDGE = 1e-6


def with_lag(robot: Robot, lag: LagCorrection | None) -> Robot:
    """``robot`` with its calibration's lag correction set to ``lag``."""
    return replace(robot, calibration=robot.calibration.with_lag(lag))


def tube1_tips(robot: Robot, mechanics_q: np.ndarray) -> np.ndarray:
    """Tube-1 tips (R, 3) mm as the tracker sees them, of the Cosserat model of ``robot`` at the joints
    its mechanics sees (R, 2N) (offsets not applied); NaN where it does not converge."""
    bb = CosseratBackend(robot.mechanics).forward(mechanics_q, points=2, check=False)
    tips = robot.calibration.tracked_tips(bb.tips_mm, bb.rotations[:, -1])[:, 0]
    return np.where(bb.converged[:, None], tips, np.nan)


def fit_lag(robot: Robot, q: np.ndarray, direction: np.ndarray, rows: np.ndarray,
            measured_mm: np.ndarray, iterations: int = 2) -> LagCorrection | None:
    """The lag correction of ``robot`` (its own calibration kept underneath) that best fits the tube-1
    tips ``measured_mm`` (R, 3) of ``rows`` of the sequence q (S, 2N) with its ``direction``; None when
    no rotation joint reverses in those rows (nothing to learn)."""
    n = q.shape[1] // 2
    phi = play_features(q[:, n:], RADII_RAD, direction[:, n:])[rows]            # (R, N, K)
    moving = [i for i in range(n) if (np.diff(np.sign(direction[rows, n + i])) != 0).any()]
    if not moving:
        return None
    weights = np.zeros((n, len(RADII_RAD)))
    for _ in range(iterations):
        model = with_lag(robot, _correction(weights))
        qm = model.calibration.mechanics_joints(q, direction)[rows]
        tips = tube1_tips(model, qm)
        columns = []
        for i in moving:
            shifted = qm.copy()
            shifted[:, n + i] += FD_STEP_RAD
            jac = (tube1_tips(model, shifted) - tips) / FD_STEP_RAD                # (R, 3) mm / rad
            columns += [(-jac * phi[:, i, k, None]).ravel() for k in range(len(RADII_RAD))]
        a = np.stack(columns, 1)
        r = (measured_mm - tips).ravel()
        ok = np.isfinite(a).all(1) & np.isfinite(r)
        if not ok.any():
            return None
        a, r = a[ok], r[ok]
        step = np.linalg.solve(a.T @ a + RIDGE * np.trace(a.T @ a) * np.eye(a.shape[1]), a.T @ r)
        weights[moving] += step.reshape(len(moving), len(RADII_RAD))
        weights = np.clip(weights, -MAX_WEIGHT_RAD, MAX_WEIGHT_RAD)
    return _correction(weights)


def _correction(weights: np.ndarray) -> LagCorrection | None:
    if not weights.any():
        return None
    return LagCorrection(tuple(RADII_RAD), tuple(tuple(float(v) for v in row) for row in weights))
