"""Fixtures of the planning tests: the open scene and an exact (Cosserat) backend of its robot."""

from __future__ import annotations

import pytest

from ctrplan.kinematics import CosseratBackend
from ctrplan.model.robot import Robot
from ctrplan.scene.loader import load_scene
from ctrplan.scene.objects import Scene
from tests.paths import SCENES


@pytest.fixture(scope="module")
def open_scene() -> Scene:
    return load_scene(SCENES / "open.yaml")


@pytest.fixture(scope="module")
def exact() -> CosseratBackend:
    """The exact backend of the nominal robot (the open scene's robot), one per test module."""
    return CosseratBackend(Robot.nominal())
