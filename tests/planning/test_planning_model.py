"""The planning model: the stability decision is made once per robot and reaches every exact check
(search, repair, validation, scene check, design); the planner table is checked where a scene is
planned, naming the scene file's line."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from ctrplan.base.errors import InputError
from ctrplan.kinematics import CosseratBackend
from ctrplan.kinematics.stability import critical_length_mm
from ctrplan.model.robot import JointDomain, Robot, Tube
from ctrplan.planning import ConfigurationChecker, PlanningModel, exact_backend, plan, validate_planned_path
from ctrplan.planning.planners import PLANNERS
from ctrplan.planning.scene_check import check_scene
from ctrplan.scene.loader import load_scene

OPEN = Path(__file__).resolve().parents[2] / "scenes" / "open.yaml"
E_MPA = 50e3
G_MPA = E_MPA / (2 * 1.3)
HALF_TURN = np.array([0.0, 0.0, 0.0, math.pi])
QUARTER_TURN = np.array([0.0, 0.0, 0.0, math.pi / 4])


def _pair(length_mm: float) -> Robot:
    """Two fully overlapping curved tubes (20 1/m), no straight parts."""
    tubes = (Tube(0.4, 0.6, 0.0, length_mm, 0.02, E_MPA, G_MPA),
             Tube(0.7, 0.9, 0.0, length_mm, 0.02, E_MPA, G_MPA))
    return Robot(tubes=tubes, domain=JointDomain(((0.0, 0.0), (0.0, 0.0), (-math.pi, math.pi),
                                                  (-math.pi, math.pi))), name="pair")


@pytest.fixture()
def snapping_scene(tmp_path, monkeypatch):
    """A scene whose robot snaps at a half turn: 10 % longer than the Dupont et al. critical length
    L = pi / (2 sqrt((1 + nu) k1 k2)) (no certificate: a private certificate folder)."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    robot = _pair(1.1 * critical_length_mm(_pair(50.0)))
    (tmp_path / "pair.yaml").write_text(yaml.safe_dump(robot.to_dict()))
    path = tmp_path / "scene.yaml"
    path.write_text("name: pair\nrobot: pair.yaml\nbase_pose: {position: [0, 0, 0]}\nobstacles: []\n"
                    "target: {point: [0.0, 30.0, 70.0], tolerance_mm: 3.0}\nstart: [0, 0, 0, 0]\n")
    return load_scene(path)


def test_critical_length_is_the_closed_form():
    k = 0.02  # 1/mm
    assert critical_length_mm(_pair(50.0)) == pytest.approx(math.pi / (2 * math.sqrt(1.3 * k * k)), rel=1e-3)


def test_every_exact_check_of_an_uncertified_robot_tests_stability(snapping_scene):
    plain = CosseratBackend(snapping_scene.robot)
    assert plain.forward(HALF_TURN).stable[0]  # without the test the half turn looks fine
    model = PlanningModel.build(snapping_scene, plain)
    assert not model.stability.certified
    for checker in (ConfigurationChecker(model), ConfigurationChecker(model.exact_search())):
        assert not checker.is_valid(HALF_TURN) and checker.is_valid(QUARTER_TURN)  # search, repair
    report = validate_planned_path(model, np.stack([QUARTER_TURN, HALF_TURN])).report  # validation
    assert not report.stable and not report.ok
    assert not exact_backend(snapping_scene.robot).forward(HALF_TURN).stable[0]  # design
    problems = check_scene(replace(snapping_scene, start=HALF_TURN), reach=False).problems  # scene check
    assert [p.kind for p in problems] == ["start"] and "unstable" in problems[0].message


def test_a_certified_robot_plans_without_the_stability_test():
    scene = load_scene(OPEN)
    cosserat = CosseratBackend(scene.robot)
    model = PlanningModel.build(scene, cosserat)
    assert model.stability.certified and model.exact is cosserat and model.backend is cosserat


def test_an_unknown_planner_in_a_scene_file_is_refused_where_it_is_planned(tmp_path):
    text = OPEN.read_text().replace("planner:\n", "planner:\n  planner: prm\n")
    path = tmp_path / "open.yaml"
    path.write_text(text)
    line = text.splitlines().index("  planner: prm") + 1
    scene = load_scene(path)  # the model layer knows no planners
    needle = f"{path}:{line}: planner.planner: unknown planner 'prm' (choose from {', '.join(PLANNERS)})"
    problems = check_scene(scene, reach=False).problems
    assert [(p.kind, p.message) for p in problems] == [("planner", needle)]
    with pytest.raises(InputError) as exc:
        plan(scene, "cosserat")
    assert str(exc.value) == needle
