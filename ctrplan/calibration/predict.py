"""Predicting measured tips of fixed rows for any number of robot models (`Evaluator`): each model's
calibration maps the reported joints (with their motion history) to the joints its mechanics sees, the
Cosserat backend solves the mechanics -- models that share it in one batched call -- and the calibration
maps the solved tips to what the tracker sees; a robot whose values differ between measurement
sessions predicts each session's rows with its own (`View`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from ctrplan.kinematics import CosseratBackend
from ctrplan.kinematics.cosserat import SolverSettings
from ctrplan.model.measurement import Calibration
from ctrplan.model.motion import Motion
from ctrplan.model.robot import Robot

#: The solver of fits: RK4 steps twice the default (4 mm where two tubes are curved, 8 mm elsewhere),
#: 2.4 times faster; the tips move by about 1e-4 mm (7e-5 mm over 1,307 rows of a real robot, 1.7e-4 mm
#: on the nominal one), a thousandth of a tracker's noise. The errors a diagnosis reports are of the
#: default solver (what `fk` computes).
FIT_SOLVER = SolverSettings(step_multi_mm=4.0, step_single_mm=8.0)
#: The solver of a fit's trials: a row whose warm start fails is not retried cold (it keeps its last
#: prediction in the fit, whose warm starts follow the solution): under a load a cold start is a
#: continuation, and the trial forces of one tip-force fit on real data cost 90 s of cold solves.
TRIAL_SOLVER = replace(FIT_SOLVER, retry_cold=False)


@dataclass
class Prediction:
    """Predicted tips of a set of rows under one model."""

    tips_mm: np.ndarray          # (n, 3, 3) what the tracker sees, measurement frame
    robot_tips_mm: np.ndarray    # (n, 3, 3) solved tube tips, robot frame
    converged: np.ndarray        # (n,)
    initial_state: np.ndarray    # (n, 15)
    tip_rotation: np.ndarray     # (n, 3, 3) tip frame R(l1) of tube 1, robot frame

    def subset(self, idx: np.ndarray) -> Prediction:
        return Prediction(tips_mm=self.tips_mm[idx], robot_tips_mm=self.robot_tips_mm[idx],
                          converged=self.converged[idx], initial_state=self.initial_state[idx],
                          tip_rotation=self.tip_rotation[idx])


@dataclass(frozen=True)
class View:
    """What a prediction of one model on the rows of an `Evaluator` consists of, in parts of rows that
    one robot predicts (one part; one per measurement session for a robot whose values differ between
    sessions): per part its rows, the mechanics solved (joint offsets zeroed), the joints that mechanics
    sees on those rows (offsets added) and the rest of the calibration (tip and frame sides)."""

    parts: tuple[tuple[np.ndarray, Robot, np.ndarray, Calibration], ...]

    def joints(self, n_rows: int) -> np.ndarray:
        """The joints (R, 2N) the mechanics sees on every row."""
        out = np.empty((n_rows, self.parts[0][2].shape[1]))
        for rows, _, qj, _ in self.parts:
            out[rows] = qj
        return out

    def same_but_joints(self, other: View) -> bool:
        """Whether ``other`` differs from this view in the joints only (same mechanics and calibration)."""
        return len(self.parts) == len(other.parts) and all(
            np.array_equal(a[0], b[0]) and a[1] == b[1] and a[3] == b[3]
            for a, b in zip(self.parts, other.parts, strict=True))

    def shifted(self, joint: int, step: float) -> View:
        """This view with joint ``joint`` moved by ``step`` (mm or rad) on every row."""
        parts = []
        for rows, mech, qj, calib in self.parts:
            moved = qj.copy()
            moved[:, joint] += step
            parts.append((rows, mech, moved, calib))
        return View(tuple(parts))


class Evaluator:
    """Predicts measured tips of fixed rows (reported joints in acquisition order plus their motion
    history, which names each row's measurement session) for any number of robot models, batching the
    solves of each mechanics; with the solver ``settings`` (default: `FIT_SOLVER`, what fits use)."""

    def __init__(self, q: np.ndarray, motion: Motion, settings: SolverSettings | None = None):
        self.q = np.asarray(q, dtype=float)
        self.motion = motion
        self.settings = FIT_SOLVER if settings is None else settings
        self.solves = 0
        self.calls = 0

    def __len__(self) -> int:
        return self.q.shape[0]

    def view(self, robot: Robot) -> View:
        """The `View` of ``robot`` on these rows (a part per session for a robot with `Robot.sessions`
        and rows that name theirs)."""
        sessions = self.motion.sessions
        if not robot.sessions or sessions is None:
            groups = [(np.arange(len(self.q)), robot)]
        else:
            groups = [(np.flatnonzero(sessions == s), robot.for_session(str(s))) for s in np.unique(sessions)]
        parts = []
        for rows, r in groups:
            mech = r.mechanics.with_changes(joint_offset=(0.0,) * r.n_joints, name="")
            qj = r.calibration.mechanics_joints(self.q[rows], self.motion.subset(rows))
            qj = qj + np.asarray(r.joint_offset)
            parts.append((rows, mech, qj, r.calibration.without("joints")))
        return View(tuple(parts))

    def predict(self, models: Sequence[Robot], guess: np.ndarray | None = None,
                settings: SolverSettings | None = None) -> list[Prediction]:
        return self.predict_views([self.view(robot) for robot in models], guess, settings)

    def predict_views(self, views: Sequence[View], guess: np.ndarray | None = None,
                      settings: SolverSettings | None = None) -> list[Prediction]:
        """`predict` of models given as `View`s (``settings``: the solver's, this once)."""
        groups: dict[Robot, list] = {}
        plan = []
        for view in views:
            for rows, mech, qj, calib in view.parts:
                # parts that differ only in the joints they see share one batched solve
                g = groups.setdefault(mech, [])
                key = rows.tobytes() + qj.tobytes()
                j = next((i for i, (k, *_) in enumerate(g) if k == key), None)
                if j is None:  # a new set of rows and joints for this mechanics: solve it
                    g.append((key, rows, qj))
                    j = len(g) - 1
                plan.append((mech, j, calib))
        solved: dict[Robot, list] = {}
        for mech, g in groups.items():
            stack = np.concatenate([qj for *_, qj in g], axis=0)
            tiled = None if guess is None else np.concatenate([guess[rows] for _, rows, _ in g])
            bb = CosseratBackend(mech, settings or self.settings).forward(stack, points=2, check=False,
                                                                          guess=tiled)
            self.solves += len(stack)
            self.calls += 1
            cuts = np.cumsum([0] + [len(rows) for _, rows, _ in g])
            solved[mech] = [(rows, bb.tips_mm[a:b], bb.converged[a:b], bb.initial_state[a:b],
                             bb.rotations[a:b, -1]) for (_, rows, _), a, b in zip(g, cuts[:-1], cuts[1:],
                                                                                  strict=True)]
        out, k = [], 0
        for view in views:
            n, ns = len(self.q), view.parts[0][1].n_states
            nt = view.parts[0][1].n_tubes
            pred = Prediction(tips_mm=np.full((n, nt, 3), np.nan), robot_tips_mm=np.full((n, nt, 3), np.nan),
                              converged=np.zeros(n, dtype=bool), initial_state=np.full((n, ns), np.nan),
                              tip_rotation=np.full((n, 3, 3), np.nan))
            for _ in view.parts:
                mech, j, calib = plan[k]
                k += 1
                rows, tips, conv, init, rot = solved[mech][j]
                pred.tips_mm[rows] = calib.tracked_tips(tips, rot)
                pred.robot_tips_mm[rows], pred.converged[rows] = tips, conv
                pred.initial_state[rows], pred.tip_rotation[rows] = init, rot
            out.append(pred)
        return out
