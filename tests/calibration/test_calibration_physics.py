"""The diagnosis library against hand calculations: Poisson's ratio in the `stiffness_ratio` cause,
and the significance test a cause must pass on held-out rows (a mean gain alone is not enough)."""

from __future__ import annotations

import numpy as np
import pytest

from ctrplan.calibration.selection import compare  # the held-out significance test
from ctrplan.model.causes.base import make_effect
from ctrplan.model.robot import Robot


def test_stiffness_ratio_is_poissons_ratio_nu_equal_e_over_2g_minus_1():
    """Table I: E = 50 GPa, G = 19.23 GPa, so nu = 50 / (2 * 19.23) - 1 = 0.300052 (docs/design.md §1,
    Dupont et al. 2010); the cause at that value is the robot file itself, and nu = 0.5 gives
    G = E / 3 = 16.667 GPa."""
    robot, effect = Robot.nominal(), make_effect("stiffness_ratio")
    nu = effect.values(robot)
    assert nu == pytest.approx([0.300052], abs=1e-6)
    same = effect.with_values(robot, nu)
    assert [t.shear_modulus_mpa for t in same.tubes] == pytest.approx([19230.0] * 3)
    assert effect.derived(robot, nu)["torsional_stiffness_change_pct"] == pytest.approx(0.0)
    half = effect.with_values(robot, np.array([0.5]))
    assert [t.shear_modulus_mpa for t in half.tubes] == pytest.approx([50e3 / 3] * 3)


def test_a_mean_gain_is_not_significant_when_most_rows_get_worse():
    """50 held-out rows at 1 mm. Candidate A fixes 10 rows (0 mm) and makes 40 worse (1.05 mm): mean
    gain 1 - 42/50 = 16 %, but the signed ranks say otherwise: the 40 small losses take ranks 1-40,
    the 10 gains ranks 41-50, W+ = 455 below its null mean 1275/2, so the one-sided p > 0.5.
    Candidate B is better on every row by 0.1 mm: W+ = 1275, the largest possible."""
    ref = np.ones((50, 1))
    a = np.r_[np.zeros(10), np.full(40, 1.05)][:, None]
    gain, p, beats = compare(a, ref, alpha=0.01, min_gain=0.05)
    assert gain == pytest.approx(0.16) and p > 0.5 and not beats
    b = np.full((50, 1), 0.9)
    gain, p, beats = compare(b, ref, alpha=0.01, min_gain=0.05)
    assert gain == pytest.approx(0.1) and p < 1e-6 and beats
