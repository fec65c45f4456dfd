"""Shared fixtures: the nominal robot, a Cosserat backend and the independent reference cases."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from ctrplan.kinematics import CosseratBackend
from ctrplan.robot import Robot

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"


@pytest.fixture(scope="session")
def robot() -> Robot:
    return Robot.nominal()


@pytest.fixture(scope="session")
def cosserat(robot) -> CosseratBackend:
    return CosseratBackend(robot)


@pytest.fixture(scope="session")
def reference() -> dict:
    path = SHARED / "reference" / "cosserat_cases.json"
    if not path.exists():
        pytest.fail(f"reference cases not found at {path} (../shared must sit beside the repo)")
    return json.loads(path.read_text())
