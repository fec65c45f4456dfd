"""The backend registry is the one list of backends: every registered name builds a backend of that
name, and the command line's help and checks name exactly the registered ones."""

from __future__ import annotations

import pytest

from ctrplan.base.errors import InputError
from ctrplan.cli.options import BackendOpt, ModelOpt, load_backend
from ctrplan.kinematics import (
    BACKEND_KINDS,
    BACKENDS,
    EXACT_MODEL,
    MODEL_BACKENDS,
    PLANNING_ORDER,
    exact_companion,
    make_backend,
)
from ctrplan.model.robot import Robot
from ctrplan.planning.budget import states_for
from tests.paths import REPO


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


def test_every_backend_has_one_exact_companion(robot, cosserat):
    """plan, roadmap, bench and design pair a backend with its exact companion from the registry: an
    exact backend of the robot is its own, a surrogate gets the exact kind its row names, anything
    else (another robot, a backend not registered) the exact model."""
    for kind in BACKEND_KINDS.values():
        if kind.exact_companion is not None:
            named = BACKEND_KINDS[kind.exact_companion]
            assert named.exact and not named.uses_model and not kind.exact
    assert exact_companion(cosserat, robot) is cosserat
    pinn = make_backend("pinn", robot)
    paired = exact_companion(pinn, robot)
    assert paired.exact and paired.name == EXACT_MODEL == "cosserat" and paired.robot is robot
    other = Robot.load(REPO / "examples" / "robots" / "two_tube.yaml")
    assert exact_companion(cosserat, other).robot is other
    assert pinn.model_card["weights_sha256"] and cosserat.model_card is None
    assert make_backend("hybrid", robot).model_card == pinn.model_card
