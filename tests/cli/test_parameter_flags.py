"""Library errors name their parameters; the CLI maps them to its flags (issue 10)."""

from __future__ import annotations

import pytest

from ctrplan.base.errors import InputError
from ctrplan.cli.app import main
from ctrplan.kinematics import make_backend
from ctrplan.training.fewshot import split_shots
from ctrplan.training.recipes import get_recipe


@pytest.mark.parametrize(("call", "message"), [
    (lambda: get_recipe("nope"), "recipe: unknown recipe 'nope'"),
    (lambda: get_recipe("fast", colour="red"), "overrides: unknown recipe field(s) colour"),
    (lambda: make_backend("nope"), "backend: unknown backend 'nope'"),
    (lambda: split_shots(None, 0), "shots: must be >= 1"),
])
def test_library_errors_name_the_parameter_not_a_flag(call, message):
    with pytest.raises(InputError) as info:
        call()
    assert str(info.value).startswith(message) and "--" not in str(info.value)


@pytest.mark.parametrize(("args", "start"), [
    (["train", "--recipe", "nope"], "ctrplan: error: --recipe: unknown recipe 'nope'"),
    (["train", "--set", "colour=1"], "ctrplan: error: --set: unknown recipe field(s) colour"),
    (["train", "--set", 'mining={"keep": 0.2}'],
     "ctrplan: error: --set: mining: keep must be a whole number >= 1, got 0.2"),
    (["train", "--set", 'mining={"share": 2}'], "ctrplan: error: --set: mining: share must be in [0, 1]"),
    (["bench", "kinematics", "--backend", "nope"], "ctrplan: error: --backend: unknown backend 'nope'"),
])
def test_cli_maps_parameters_to_flags(tmp_path, capsys, monkeypatch, args, start):
    monkeypatch.chdir(tmp_path)
    assert main(args) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.startswith(start) and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "models").exists() and not (tmp_path / "runs").exists()
