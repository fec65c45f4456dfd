"""diagnose's rules and numbers where a sign or a ratio could flip unnoticed: the BIC margin a cause
must clear, the splits a cause must hold on, and the reported held-out gain.

Candidates for the rules are built from held-out errors made here (`test_diagnose_cli._candidate`:
nominal model 2 mm, noise 0.03-0.05 mm); the gain is checked against the separately written
integrator (`tests/independent/cosserat.py`) on lab data with a known hidden joint offset.

The habit these tests keep (issue 25 §5): every safety or science function gets a test that a sign,
index, bound or unit error would fail -- each rule is tested on both sides of its bound, and every
number diagnose prints is recomputed here at least once (`scripts/mutations.py` flips them).
"""

from __future__ import annotations

import numpy as np
import pytest
from test_diagnose_cli import NOMINAL_BIC, _candidate, _choose

from ctrplan.calibration import DiagnoseOptions, diagnose, read_measured
from tests.independent.cosserat import Tubes, solve
from tests.independent.lab import make

MARGIN = DiagnoseOptions().bic_margin


@pytest.mark.parametrize(("delta_bic", "named"), [(-1.5 * MARGIN, True), (-0.5 * MARGIN, False),
                                                  (0.5 * MARGIN, False)])
def test_a_cause_must_lower_the_bic_by_more_than_the_margin(delta_bic, named):
    """Held-out errors ten times lower than the nominal model's on every split, but a training BIC only
    half a margin below it (or above it): the evidence is not "very strong", nothing is named. A
    margin and a half below it: named."""
    c = _candidate("registration", NOMINAL_BIC + delta_bic, [0.2, 0.2, 0.2])
    assert c.significant is named and c.main.beats is named
    sel = _choose(c)
    assert (sel.chosen is c) is named


def test_a_better_fit_within_the_margin_still_beats_a_worse_one():
    """Two single causes, both significant everywhere: A's held-out error is half B's, its training
    BIC half a margin higher (not higher by more than the margin). A beats B: A is named and B is no
    tie."""
    b = _candidate("backlash", -9000, [0.3, 0.3, 0.3])
    a = _candidate("torsional_windup", -9000 + 0.5 * MARGIN, [0.15, 0.15, 0.15])
    sel = _choose(a, b)
    assert sel.chosen is a and sel.ties == []


def test_a_cause_significant_on_one_split_is_not_stable():
    """Significant on the main split only (2 mm on the other two, as bad as the nominal model): one
    split of three is below two thirds, so it is reported unstable and nothing is named. On two of
    three it is stable and named."""
    once = _candidate("curvature", -9000, [0.15, 1.99, 2.0])
    sel = _choose(once)
    assert once.significant_splits() == 1
    assert sel.chosen is None and sel.unstable == [once]
    twice = _candidate("curvature", -9000, [0.15, 0.15, 2.0])
    sel = _choose(twice)
    assert twice.significant_splits() == 2 and sel.chosen is twice and sel.unstable == []


def test_the_reported_gain_is_the_held_out_error_saved(tmp_path):
    """Tube 1's translation read 2.5 mm off (true beta1 = reported - 2.5 mm) on 64 random rows, only
    joint_offset a candidate. The gain diagnose reports is 1 - (extended / nominal) held-out mean tip
    error of tube 1, both recomputed here with the independent integrator (the extended model: the
    fitted offset added to beta1): about 90 %, positive -- an inverted ratio would be far below 0."""
    lab = make(64, {"beta1_offset": -2.5}, seed=7, sigma_mm=0.1, rows="random")
    lab.write_csv(tmp_path / "lab.csv")
    diag = diagnose(read_measured(tmp_path / "lab.csv"),
                    options=DiagnoseOptions(candidates=("joint_offset",), pairs=0))
    j = diag.to_json()
    assert j["causes"] == ["joint_offset"], diag.summary()
    rows = np.asarray(diag.heldout)
    q = lab.q[rows]
    shifted = q.copy()
    shifted[:, 0] += j["parameters"]["beta1_offset_mm"]["value"]
    measured = lab.tips_mm[rows, 0]
    nominal = np.linalg.norm(measured - solve(q, Tubes.paper())["tips_mm"][:, 0], axis=1).mean()
    extended = np.linalg.norm(measured - solve(shifted, Tubes.paper())["tips_mm"][:, 0], axis=1).mean()
    assert j["nominal"]["mean_mm"] == pytest.approx(nominal, abs=1e-3)
    assert j["gain_pct"] == pytest.approx(100.0 * (1.0 - extended / nominal), abs=0.2)
    assert 80.0 < j["gain_pct"] < 100.0
