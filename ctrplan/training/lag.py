"""Learn from the shots the direction-dependent lag of the joints that the extended robot of the
diagnosis stage does not hold yet: the cause library's `friction` (Maxwell-slip elements, a
Prandtl-Ishlinskii operator set: `ctrplan.model.causes.measurement_side.Friction`) -- the same model
`ctrplan diagnose` fits and names, in the same place of the robot file (``calibration: friction``).

`diagnose` names friction only when it is significant on its own held-out rows; here it is fitted on
all the fit shots (least squares through the extended robot's Cosserat model, its calibration kept
underneath) and `ctrplan.training.finetune` keeps it only when the fit shots support it as `diagnose`
requires of a cause it names (`ctrplan.calibration.selection.unsupported`: every fitted element
resolved, plausible, off its bounds) and it lowers the error on the validation shots.
"""

from __future__ import annotations

import numpy as np

from ctrplan.calibration.fit import FitResult, fit_effect
from ctrplan.calibration.predict import Evaluator
from ctrplan.model.causes.base import make_effect
from ctrplan.model.motion import Motion
from ctrplan.model.robot import Robot

#: Least-squares evaluations of the fit (each costs a few batched solves of the shots).
MAX_NFEV = 12


def fit_friction(robot: Robot, q: np.ndarray, motion: Motion, tubes: tuple[int, ...],
                 measured_mm: np.ndarray) -> FitResult | None:
    """The fit of the `friction` of ``robot``'s joints to the measured tips ``measured_mm`` (R, T, 3) of
    rows with joints q (R, 2N) and their ``motion`` history (from its current friction, or none); its
    ``robot`` is ``robot`` with that friction. None when no joint reverses in those rows (nothing to
    learn)."""
    effect = make_effect("friction")
    fixed = effect.unseen(q, motion.direction, robot)
    if all(p.name in fixed for p in effect.params(robot)):
        return None
    every = Evaluator(q, motion).predict([robot])[0]
    solved = np.flatnonzero(every.converged)
    if not len(solved):
        return None
    ev, start = Evaluator(q[solved], motion.subset(solved)), every.subset(solved)
    return fit_effect(effect, robot, ev, measured_mm[solved], tubes, start, x_start=effect.values(robot),
                      max_nfev=MAX_NFEV, fixed=fixed)
