"""Shared fixtures: the nominal robot, a Cosserat backend and the independent reference cases.

The suite's habit: every safety or science function gets a test that a sign, index, bound or unit
error would fail, with its expectation from physics, a closed form or an independent computation
(`tests/independent/`), never from the output of the code under test; `scripts/mutations.py` applies
such one-line bugs and checks that a test fails (`tests/test_guard_*.py` hold those of issue 25).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from ctrplan.kinematics import CosseratBackend
from ctrplan.robot import Robot

#: 52 solved cases from an independent solver (docs/design.md §1: tips, u_z(0), some backbones; nominal, with
#: gravity, with a tip force), copied into the repository so the tests need nothing beside it.
REFERENCE = Path(__file__).resolve().parent / "data" / "cosserat_cases.json"


@pytest.fixture(scope="session")
def robot() -> Robot:
    return Robot.nominal()


@pytest.fixture(scope="session")
def cosserat(robot) -> CosseratBackend:
    return CosseratBackend(robot)


@pytest.fixture(scope="session")
def reference() -> dict:
    return json.loads(REFERENCE.read_text())
