"""`design` checks its configurations against each structure's own margin: the open scene's start,
whose distance to the ball is measured here with the independent point-to-sphere gap, is valid for a
design study when the ball's margin is below that distance and invalid when it exceeds it."""

from __future__ import annotations

from pathlib import Path

import pytest

from ctrplan.design.evaluate import DesignContext, _design_scene
from ctrplan.design.task import load_task
from ctrplan.kinematics import CosseratBackend
from ctrplan.model.robot import Robot
from tests.independent.geometry import sphere_gap
from tests.paths import SCENES

TASK = """\
scene: {scene}
targets:
  - {{name: goal, point: [37.2, -27.2, 181.6], tolerance_mm: 3.0}}
robot: nominal
vary:
  1: {{curvature_1_per_m: [20.0, 30.0]}}
constraints: {{max_strain: 0.08, snap_free: false}}
objectives: [targets_reached]
budget: {{trials: 1, plan_time_s: 1.0}}
"""


def task_with_ball_margin(folder: Path, margin_mm: float):
    folder.mkdir(parents=True, exist_ok=True)
    scene = (SCENES / "open.yaml").read_text().replace("- name: ball\n",
                                                      f"- name: ball\n  margin_mm: {margin_mm}\n", 1)
    (folder / "scene.yaml").write_text(scene)
    (folder / "task.yaml").write_text(TASK.format(scene="scene.yaml"))
    return load_task(folder / "task.yaml")


def test_design_checks_keep_each_structure_margin(tmp_path):
    robot = Robot.nominal()
    plain = task_with_ball_margin(tmp_path / "plain", 0.0)
    start = plain.scene.start
    bb = CosseratBackend(robot).forward(start[None], points=plain.scene.settings.points, check=False)
    gap = sphere_gap(plain.scene.to_scene(bb.positions_mm), bb.radius_mm, [43.0, -47.0, 150.0], 7.0)
    need = gap - plain.scene.settings.margin_mm   # the largest ball margin the start keeps (about)
    assert need > 2.0
    for margin, valid in ((need - 1.0, True), (need + 1.0, False)):
        task = task_with_ball_margin(tmp_path / f"m{margin:.1f}", margin)
        scene, checker = _design_scene(task, robot, DesignContext())
        assert [o.margin_mm for o in scene.obstacles if o.name == "ball"] == [pytest.approx(margin)]
        assert bool(checker.check(start[None])[0]) is valid, (margin, gap)
