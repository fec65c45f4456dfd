"""The trainer in small named steps (issue 10): data, losses, optimiser, schedule, `Trainer`."""

from __future__ import annotations

import inspect

import pytest
import torch

from ctrplan.kinematics.pinn_net import PinnNet
from ctrplan.training.recipes import get_recipe
from ctrplan.training.trainer import (
    CosineSchedule,
    Trainer,
    TrainingData,
    make_optimizer,
    new_net,
    train,
)

TINY = dict(steps=20, collocation=64, boundary=32, dense_configs=100, dense_batch=256, dense_points=9)


def test_schedule_warms_up_decays_and_fits_the_time_limit():
    s = CosineSchedule(lr=1e-3, lr_final=1e-5, steps=101, warmup_steps=10)
    assert s(0, 0.0) == pytest.approx(1e-4)           # warm-up: 1/10 of the cosine value
    assert s(9, 0.0) == pytest.approx(s.lr_final + 0.5 * (1e-3 - 1e-5) * (1 + torch.cos(
        torch.tensor(torch.pi * 9 / 100)).item()))
    assert s(100, 0.0) == pytest.approx(1e-5)
    timed = CosineSchedule(lr=1e-3, lr_final=1e-5, steps=10_000, time_limit_s=60.0)
    assert timed(1, 60.0) == pytest.approx(1e-5)      # the time limit ends the schedule first


def test_optimiser_follows_the_recipe():
    params = [torch.nn.Parameter(torch.zeros(3))]
    assert isinstance(make_optimizer(get_recipe("fast"), params), torch.optim.Adam)
    assert isinstance(make_optimizer(get_recipe("polish"), params), torch.optim.LBFGS)


def test_trainer_object_form_equals_train(tmp_path, robot):
    recipe = get_recipe("fast", **TINY)
    one_call = train(robot, recipe, tmp_path / "a", seed=4)

    torch.manual_seed(4)
    data = TrainingData.build(robot, recipe, 4, torch.device("cpu"))
    net = new_net(robot, recipe, data)
    assert net.harmonics == recipe.harmonics and net.n_inputs > PinnNet(robot).n_inputs
    result = Trainer(robot, data, net).compile(recipe, seed=4).train(tmp_path / "b").finish(tmp_path / "b")

    assert result.steps == one_call.steps == 20
    for (k, v), w in zip(result.net.state_dict().items(), one_call.net.state_dict().values(), strict=True):
        assert torch.equal(v, w), k
    assert (tmp_path / "b.safetensors").exists() and (tmp_path / "b.json").exists()
    assert result.card["samples"] == one_call.card["samples"]


def test_train_is_short():
    assert len(inspect.getsource(train).splitlines()) <= 40
    assert all(len(inspect.getsource(m).splitlines()) <= 40
               for m in (Trainer.train, Trainer.finish, TrainingData.build))


def test_cli_train_with_a_time_limit_reports_its_last_step_and_leaves_no_checkpoint(tmp_path, capsys,
                                                                                   monkeypatch):
    """`--time-limit 0.05` (3 s): the progress line ends at the step the card records (not at the
    last multiple of 10) against the limit, and the checkpoint is gone once the model is written."""
    import json
    import re

    from ctrplan.cli.app import main

    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("TTY_COMPATIBLE", "1")  # rich draws the bar as on a terminal
    monkeypatch.setenv("COLUMNS", "200")
    small = [f"--set={k}={v}" for k, v in TINY.items() if k != "steps"]
    assert main(["train", "--name", "tiny", "--time-limit", "0.05", "--threads", "1", *small]) == 0
    card = json.loads((tmp_path / "models" / "tiny.json").read_text())
    err = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", capsys.readouterr().err)
    shown = re.findall(r"(\d+) steps in \d+:\d\d of 0:03", err)
    assert shown and int(shown[-1]) == card["steps"] > 0
    assert sorted(p.name for p in (tmp_path / "models").iterdir()) == ["tiny.json", "tiny.safetensors"]


def test_a_mining_worker_trains_the_same_network(tmp_path, robot):
    """Mining rounds solved ahead in a worker process (a real spawned process) are the rounds solved
    inline: the same candidates, the same hard examples, the same network bit for bit (when the
    optimiser waits for the worker's rounds)."""
    recipe = get_recipe("fast", **TINY, mining={"every": 5, "candidates": 300, "worker_candidates": 300,
                                                 "keep": 30, "wait_for_worker": True})
    inline = train(robot, recipe, tmp_path / "a", seed=4)
    worker = train(robot, recipe, tmp_path / "b", seed=4, mining_worker=True)
    for (k, v), w in zip(worker.net.state_dict().items(), inline.net.state_dict().values(), strict=True):
        assert torch.equal(v, w), k
    mined = worker.card["mining"]
    assert mined["solved_in"] == "a worker process"
    assert inline.card["mining"]["solved_in"] == "the training process"
    assert mined["rounds"] == 4 and mined["hard_pool"] == 4 * 30 and mined["solve_cpu_s"] > 0
    assert mined["history"] == inline.card["mining"]["history"]


def test_rounds_the_worker_has_not_solved_are_taken_late_never_early(tmp_path, robot):
    """By default the optimiser does not wait for the worker: each round is mined once it is due and
    solved -- in order, never before its step, at least `Mining.every` steps after the one before --
    and inline (always solved) exactly every `Mining.every` steps."""
    mining = {"every": 5, "candidates": 300, "worker_candidates": 2000, "keep": 30}
    recipe = get_recipe("fast", **{**TINY, "steps": 60}, mining=mining)
    inline = train(robot, recipe, tmp_path / "a", seed=4).card["mining"]
    assert [r["step"] for r in inline["history"]] == list(range(5, 61, 5))
    worker = train(robot, recipe, tmp_path / "b", seed=4, mining_worker=True).card["mining"]
    steps = [r["step"] for r in worker["history"]]
    assert worker["rounds"] == len(steps) <= 12 and worker["hard_pool"] == 30 * len(steps)
    assert all(b - a >= 5 for a, b in zip([0, *steps], steps, strict=False))
