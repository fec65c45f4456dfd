"""Fixtures shared by the test directories: the nominal robot, its Cosserat backend and shipped PINN, the
skull-base scene, the independent reference cases and a private cache.

The suite is arranged by the package a test guards: `tests/<package>/test_<topic>.py` with package one
of model, kinematics, collision, stability, planning, calibration, training, design, bench, viz and
cli (the commands end to end); basenames are unique across the tree (pytest's default import mode).
Fixtures that only one directory uses live in that directory's `conftest.py`; repository paths come
from `tests/paths.py`; `tests/independent/` and `tests/data/` are shared by all. The suite's habit:
every safety or science function gets a test that a sign, index, bound or unit error would fail,
with its expectation from physics, a closed form or an independent computation
(`tests/independent/`), never from the output of the code under test; `scripts/mutations.py` applies
such one-line bugs and checks that a test fails.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

# as the command line does (`ctrplan.cli`), before torch loads its OpenMP runtime: on the shared 2-core
# machine spinning OpenMP threads made a 300-step training test take 183 s instead of 13 s
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import pytest

from ctrplan.kinematics import CosseratBackend
from ctrplan.model.robot import Robot
from ctrplan.scene.loader import load_scene
from ctrplan.scene.objects import Scene
from tests.paths import SCENES

#: 52 solved cases from an independent solver (docs/design.md §1: tips, u_z(0), some backbones; nominal, with
#: gravity, with a tip force), copied into the repository so the tests need nothing beside it.
REFERENCE = Path(__file__).resolve().parent / "data" / "cosserat_cases.json"


@pytest.fixture(scope="session")
def robot() -> Robot:
    return Robot.nominal()


@pytest.fixture(scope="session")
def cosserat(robot) -> CosseratBackend:
    return CosseratBackend(robot)


@pytest.fixture(scope="module")
def pinn(robot):
    """The shipped PINN of the nominal robot (one per test module: a backend keeps per-use state)."""
    from ctrplan.kinematics.pinn import PinnBackend

    return PinnBackend.load(None, robot)


@pytest.fixture(scope="module")
def skullbase() -> Scene:
    return load_scene(SCENES / "skullbase.yaml")


@pytest.fixture(scope="session")
def reference() -> dict:
    return json.loads(REFERENCE.read_text())


@pytest.fixture()
def private_cache(tmp_path, monkeypatch) -> Path:
    """Stability certificates and distance grids in this test's own cache, never the user's."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    return tmp_path / "cache"
