"""The backend registry is the one list of backends: every registered name builds a backend of that
name, and the command line's help and checks name exactly the registered ones."""

from __future__ import annotations

import pytest

from ctrplan.base.errors import InputError
from ctrplan.cli.options import BackendOpt, ModelOpt, load_backend
from ctrplan.kinematics import BACKEND_KINDS, BACKENDS, MODEL_BACKENDS, PLANNING_ORDER, make_backend
from ctrplan.planning.budget import states_for


@pytest.mark.parametrize("name", BACKENDS)
def test_every_registered_backend_builds_under_its_name(name, robot):
    assert make_backend(name, robot).name == name


def test_help_and_checks_name_the_registered_backends(robot):
    assert set(BACKENDS) == {"cosserat", "pinn", "hybrid"}
    assert sorted(PLANNING_ORDER) == sorted(BACKENDS) and PLANNING_ORDER[0] == "pinn"
    assert BackendOpt.__metadata__[0].help == "Kinematics backend: cosserat | pinn | hybrid."
    assert ModelOpt.__metadata__[0].help.startswith("PINN for the pinn and hybrid backends:")
    with pytest.raises(InputError, match=r"^--backend: unknown backend 'nope' \(available: cosserat, pinn, "
                                         r"hybrid\)$"):
        load_backend("nope", robot, None)
    for name in BACKENDS:
        if name in MODEL_BACKENDS:
            continue
        with pytest.raises(InputError, match=f"^--model: only the pinn and hybrid backends use a model, "
                                             f"not {name}$"):
            load_backend(name, robot, "pinn_nominal")


def test_a_time_limit_buys_the_registered_rate():
    # 10 s of search on the reference machine: 16,000 PINN states/s, 5,000 for the exact backends
    assert states_for("pinn", 10.0) == 160_000
    assert states_for("cosserat", 10.0) == states_for("hybrid", 10.0) == 50_000
    assert states_for("unregistered", 10.0) == 50_000  # the exact model's rate
    assert {k.uses_model for k in BACKEND_KINDS.values()} == {True, False}
