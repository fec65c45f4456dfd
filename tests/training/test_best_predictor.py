"""The few-shot stage's choice of physics (`finetune.best_predictor`): the diagnosis of the shots also
fits the causes `diagnose` tries only when named, as one more cause of the set it names, and the
validation shots choose. Data from the independent planar elastica (`tests/independent/elastica.py`)
under a follower force the default candidates cannot express, seen through a shifted tracker."""

from __future__ import annotations

import math

import numpy as np

from ctrplan.calibration import DiagnoseOptions, diagnose, read_measured
from ctrplan.calibration.data import write_measured_csv
from ctrplan.training.fewshot import split_shots, validation_split
from ctrplan.training.finetune import FEWSHOT_DIAGNOSIS, best_predictor
from tests.model.test_follower_force import FOLLOWER_N, lab_tip, one_tube

SHIFT_MM = np.array([1.5, -1.0, 0.5])      # the tracker's origin, off the robot's


def lab_data(tmp_path):
    rng = np.random.default_rng(5)
    q = np.column_stack([rng.uniform(-20.0, 0.0, 60), rng.uniform(-math.pi, math.pi, 60)])
    tips = np.array([lab_tip(b, a) for b, a in q]) + SHIFT_MM + rng.normal(0.0, 0.05, (len(q), 3))
    path = tmp_path / "lab.csv"
    write_measured_csv(path, q, tips[:, None, :])
    return read_measured(path, one_tube())


def test_the_validation_shots_choose_a_cause_diagnose_does_not_try(tmp_path):
    robot = one_tube()
    fs = split_shots(lab_data(tmp_path), heldout_fraction=0.2, heldout_last=True)
    fit, val = validation_split(fs)
    options = DiagnoseOptions(candidates=("registration",), resamples=1, also_fit=FEWSHOT_DIAGNOSIS.also_fit)
    diag = diagnose(fs.data.subset(fit), robot, options, motion=fs.motion.subset(fit))
    assert "follower_force" in FEWSHOT_DIAGNOSIS.also_fit
    assert diag.causes == ("registration",), diag.summary()
    extra = [c for c in diag.selection.candidates if "follower_force" in c.causes]
    assert [(c.causes, c.reference) for c in extra] == [(("registration", "follower_force"), "registration")]
    chosen, record = best_predictor(diag, fs, val, lambda _msg: None)
    errors = record["validation_mean_mm"]
    assert record["kept"] == "registration+follower_force", record
    assert errors["registration+follower_force"] < 0.5 * errors["registration"], errors
    np.testing.assert_allclose(chosen.loads.tip_follower_force_n, FOLLOWER_N, atol=2e-3)
