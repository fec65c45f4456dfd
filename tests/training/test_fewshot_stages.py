"""`ctrplan train --measured` never writes a model worse than an earlier stage on the validation shots:
a fine-tune that ruins the network (learning rate 0.05) on real-like lab data (`lab.real_like`: fixed
joints, lag, a 9 mm / 4 deg tracker registration, tube 1 only) is reported, the better stage is written
(exit 0), the adapted model is written too, and `fk` with the written robot file reproduces the table."""

from __future__ import annotations

import contextlib
import io
import json

import numpy as np
import pytest
from safetensors.numpy import load_file

from ctrplan.cli.app import main
from tests.independent import lab

ROWS, SHOTS, HELDOUT_LAST = 150, 50, 0.3
JOINTS = ["beta1", "beta2", "beta3", "alpha1", "alpha2", "alpha3"]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("stages")
    data = lab.real_like(n=ROWS, seed=2)
    csv = tmp / "measured.csv"
    data.write_csv(csv, tubes=(0,))
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(["train", "--measured", str(csv), "--shots", str(SHOTS), "--heldout-last",
                   str(HELDOUT_LAST), "--adapt-steps", "0", "--steps", "30", "--set", "lr=0.05",
                   "--set", "dense_configs=2000",
                   "--set", "warmup_steps=0", "--threads", "1", "--out-dir", str(tmp), "--name", "ft",
                   "--json"])
    return rc, json.loads(out.getvalue()), err.getvalue(), tmp, data


def _fk_tips(tmp, q, robot, model, name) -> np.ndarray:
    configs = tmp / f"{name}.csv"
    np.savetxt(configs, q, delimiter=",", header=",".join(JOINTS), comments="", fmt="%.17g")
    out = tmp / f"{name}_fk.csv"
    args = ["fk", str(configs), "--backend", "pinn", "--model", str(model), "-o", str(out)]
    assert main(args + (["--robot", str(robot)] if robot else [])) == 0
    fk = np.genfromtxt(out, delimiter=",", names=True)
    return np.column_stack([fk["tip1_x"], fk["tip1_y"], fk["tip1_z"]])


def test_a_ruined_finetune_is_not_written_and_is_reported(run):
    rc, card, err, tmp, _ = run
    assert rc == 0
    kept = card["finetuned_on"]["kept"]
    errors = kept["validation_mean_mm"]
    assert kept["stage"] != "pinn_finetuned" and errors["pinn_finetuned"] > errors[kept["stage"]]
    assert errors[kept["stage"]] <= errors["pinn_start"]          # never worse than the start
    said = " ".join(err.split())                 # the console wraps long lines
    assert "kept: PINN" in said and "fine-tuned PINN was worse there" in said, err
    written = load_file(str(tmp / "ft.safetensors"))
    source = load_file(str(tmp / "ft_adapted.safetensors"))   # adapt 0 min: the start network, written
    assert (tmp / "ft_adapted.json").exists() and (tmp / "ft.mechanics.robot.yaml").exists()
    if kept["stage"] == "pinn_adapted":
        w = written["mlp.0.weight"]
        assert np.array_equal(w[:, :source["mlp.0.weight"].shape[1]], source["mlp.0.weight"])


def test_validation_errors_are_the_models_errors(run):
    """The start model's validation error in the card is what `fk` gives for it on those shots."""
    _, card, _, tmp, data = run
    val = np.arange(SHOTS - SHOTS // 5, SHOTS)    # the shots are the first rows; the last fifth validate
    tips = _fk_tips(tmp, data.q[val], None, "pinn_nominal", "val")
    start = np.linalg.norm(tips - data.tips_mm[val, 0], axis=1).mean()
    assert abs(start - card["finetuned_on"]["kept"]["validation_mean_mm"]["pinn_start"]) < 0.01


def test_fk_with_the_written_robot_agrees_with_train(run):
    _, card, _, tmp, data = run
    table = card["metrics"]["measured_heldout"]
    row = {m["key"]: m for m in table["models"]}[card["finetuned_on"]["kept"]["stage"]]
    tail = np.arange(ROWS - int(round(HELDOUT_LAST * ROWS)), ROWS)
    tips = _fk_tips(tmp, data.q[tail], tmp / "ft.robot.yaml", tmp / "ft.safetensors", "tail")
    err = np.linalg.norm(tips - data.tips_mm[tail, 0], axis=1)
    assert table["rows"] == len(tail)
    assert abs(err.mean() - row["mean_mm"]) < 0.01 and abs(np.percentile(err, 95) - row["p95_mm"]) < 0.02
