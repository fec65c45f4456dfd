"""The stability sweep's flags, on the two-tube pair whose snapping threshold is a closed form
(``L sqrt((1 + nu) k1 k2) = pi / 2``, Dupont et al. 2010): a snap between two sweep steps is a jump,
and a state whose equilibrium was not found is not known to be stable.

The habit these tests keep (issue 25 §5): every safety or science function gets a test that a sign,
index, bound or unit error would fail -- here a threshold taken from the wrong statistic and a
non-converged state left out of the count (`scripts/mutations.py` applies both).
"""

from __future__ import annotations

import math

import numpy as np

from ctrplan.kinematics import CosseratBackend, SolverSettings
from ctrplan.kinematics.stability import critical_length_mm, sweep_rotation
from tests.model.test_any_robot import overlapping_pair

ALPHA1 = 1.0  # rad: tube 1 stays here while tube 2 turns through [-pi, pi]: the pair passes opposed


def pair_sweep(factor: float, steps: int, **settings) -> tuple:
    """Tube 2 of the pair ``factor`` x the critical length turned across its interval with tube 1 at
    `ALPHA1`; returns the sweep and the relative rotation alpha2 - alpha1 of each step, wrapped into
    (-pi, pi]."""
    robot = overlapping_pair(factor * critical_length_mm(overlapping_pair(50.0)))
    backend = CosseratBackend(robot, SolverSettings(stability=True, **settings))
    sweep = sweep_rotation(backend, np.array([0.0, 0.0, ALPHA1, 0.0]), 1, steps)
    rel = np.angle(np.exp(1j * (sweep.q[:, 3] - sweep.q[:, 2])))
    return sweep, rel


def test_a_snap_between_two_sweep_steps_is_a_jump():
    """30 % above the critical length a full turn of one tube folds the equilibrium branch: between
    two steps of 5 deg the tip jumps by several times its typical motion, after the tubes passed
    opposed (|alpha2 - alpha1| > pi / 2). Below the critical length the motion is smooth: no jump."""
    sweep, rel = pair_sweep(1.3, 73)
    moves = np.linalg.norm(np.diff(sweep.tip_mm, axis=0), axis=1)
    k = int(np.argmax(moves)) + 1  # the step that ends the largest move
    assert moves[k - 1] > 5.0 * np.median(moves) and moves[k - 1] > 20.0  # mm: a snap, not a fast turn
    assert np.flatnonzero(sweep.jump).tolist() == [k]
    assert abs(rel[k - 1]) > math.pi / 2 and abs(rel[k]) > math.pi / 2
    smooth, _ = pair_sweep(0.9, 73)
    assert not smooth.flagged.any()


def test_a_state_whose_equilibrium_was_not_found_counts_unstable():
    """One Newton iteration cannot solve the pair away from the aligned and opposed configurations
    (the zero-torsion guess is only right there): those states have no equilibrium and no stability
    measure (NaN), and every one of them is flagged -- the domain is never certified on a guess."""
    sweep, _ = pair_sweep(0.9, 19, max_iterations=1)
    unknown = np.isnan(sweep.stability)
    assert unknown.sum() >= 15
    assert sweep.unstable[unknown].all() and sweep.flagged[unknown].all()
