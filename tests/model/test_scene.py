"""Scene files: the shipped scenes load; malformed ones fail with the key and the line."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import trimesh

from ctrplan.base.errors import InputError
from ctrplan.scene.loader import load_scene
from ctrplan.scene.objects import PlannerSettings, TargetRegion
from tests.paths import SCENES

GOOD = """\
name: tiny
robot: nominal
base_pose:
  position: [0, 0, 0]
  rotation: {rpy_deg: [0, 0, 0]}
obstacles:
  - {name: ball, sphere: {center: [20, -38, 150], radius: 5}}
  - {name: slab, box: {center: [0, 60, 100], size: [10, 10, 10]}}
  - {name: rod, cylinder: {center: [60, 0, 100], radius: 2, length: 30, axis: [0, 1, 0]}}
  - {name: pin, capsule: {center: [-60, 0, 100], radius: 2, length: 30}}
target: {point: [37.2, -27.2, 181.6], tolerance_mm: 3}
start: [-80, -65, -10, 0, 0, 0]
planner: {time_limit_s: 5, points: 30, margin_mm: 0.1}
"""


def write(tmp_path: Path, text: str, name: str = "scene.yaml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def test_shipped_scenes_load():
    sb = load_scene(SCENES / "skullbase.yaml")
    names = {o.name for o in sb.obstacles}
    for part in ("nasal_septum", "inferior_turbinate", "middle_turbinate", "sphenoid_face",
                 "sphenoid_sinus", "sellar_wall", "right_internal_carotid", "left_internal_carotid",
                 "optic_chiasm"):
        assert part in names
    assert all(o.kind == "mesh" and len(o.faces) > 0 for o in sb.obstacles)
    # the target (pituitary) lies ~76-85 mm behind the nasal spine, between the carotids
    assert 76.0 < sb.target.center[2] < 86.0
    assert sb.target.kind == "ellipsoid"
    # base in front of the face, robot frame z roughly along the approach (posterior)
    assert sb.base_pose[2, 3] < -50.0 and sb.base_pose[2, 2] > 0.8
    for name in ("open", "pipe", "skullbase_strict"):
        sc = load_scene(SCENES / f"{name}.yaml")
        assert sc.start.shape == (6,)


def test_good_scene_fields(tmp_path):
    sc = load_scene(write(tmp_path, GOOD))
    assert sc.name == "tiny"
    assert [o.kind for o in sc.obstacles] == ["sphere", "box", "cylinder", "capsule"]
    rod = sc.obstacles[2]
    assert np.allclose(rod.pose[:3, 2], [0, 1, 0])  # local z = the given axis
    assert sc.target.tolerance_mm == 3.0
    assert sc.settings == PlannerSettings(time_limit_s=5.0, points=30, margin_mm=0.1)
    assert np.allclose(sc.to_robot(sc.to_scene(np.array([1.0, 2.0, 3.0]))), [1, 2, 3])
    merged = sc.merged_obstacles()
    assert len(merged.faces) > 100


def test_base_pose_and_mesh_transform(tmp_path):
    m = trimesh.creation.box(extents=[2, 2, 2])
    m.export(tmp_path / "cube.stl")
    text = GOOD.replace("rotation: {rpy_deg: [0, 0, 0]}",
                        "rotation: {axis_angle_deg: {axis: [0, 0, 1], angle: 90}}")
    text = text.replace("  - {name: ball,",
                        "  - {name: cube, mesh: cube.stl, position: [5, 0, 0], scale: 2}\n  - {name: ball,")
    sc = load_scene(write(tmp_path, text))
    assert np.allclose(sc.base_pose[:3, :3] @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    cube = sc.obstacles[0]
    assert np.allclose(cube.bounds, [[3, -2, -2], [7, 2, 2]])


def test_ellipsoid_target():
    t = TargetRegion(np.zeros(3), np.array([3.0, 2.0, 1.0]), np.eye(3), "ellipsoid")
    assert t.contains(np.array([2.9, 0, 0])) and not t.contains(np.array([0, 2.1, 0]))
    assert math.isclose(float(t.distance(np.array([5.0, 0, 0]))), 2.0)
    assert float(t.distance(np.array([0.0, 0.5, 0.2]))) == 0.0
    pts = t.sample(500, np.random.default_rng(0))
    assert t.contains(pts).all()
    assert t.tolerance_mm == 1.0


@pytest.mark.parametrize(("edit", "needle"), [
    (lambda s: s.replace("robot: nominal", "robot: nominal\nrobott: x"), ":3: robott: unknown key"),
    (lambda s: s.replace("radius: 5}", "radius: -5}"), ":7: obstacles[0].sphere.radius: must be > 0"),
    (lambda s: s.replace("start: [-80, -65, -10, 0, 0, 0]", "start: [-80, -65, -10, 0, 0]"),
     ":12: start: expected a list of 6 numbers"),
    (lambda s: s.replace("start: [-80, -65, -10, 0, 0, 0]", "start: [-80, -65, -12, 4, 0, 0]"),
     ":12: start: outside the snap-free domain"),  # alpha1 = 4 rad is inside: a full turn wraps
    (lambda s: s.replace("tolerance_mm: 3}", "tolerance: 3}"), ":11: target.tolerance: unknown key"),
    (lambda s: s.replace("{rpy_deg: [0, 0, 0]}", "{matrix: [[1, 0, 0], [0, 2, 0], [0, 0, 1]]}"),
     ":5: base_pose.rotation.matrix: not a rotation matrix"),
    (lambda s: s.replace("target: {point: [37.2, -27.2, 181.6]", "target: {point: [0, 0, 400]"),
     ":11: target: out of reach"),
    (lambda s: s.replace("{time_limit_s: 5,", "{planner: [rrt], time_limit_s: 5,"),
     ":13: planner.planner: expected a planner name, got ['rrt']"),
    (lambda s: s.replace("{time_limit_s: 5,", "{surrogate_coverage: 1.0, time_limit_s: 5,"),
     ":13: planner.surrogate_coverage: must be below 1"),
    (lambda s: s.replace("start: [-80, -65, -10, 0, 0, 0]", "start: [-80, -65, -10, 0, 0, 0"),
     "malformed YAML"),
    (lambda s: s.replace("  - {name: slab", "  - {name: ball"), ":8: obstacles[1].name: duplicate"),
    (lambda s: s.replace("robot: nominal", "robot: nominal\nrobot: other"),
     ":3: robot: duplicate key (first on line 2)"),
])
def test_malformed_scenes_name_key_and_line(tmp_path, edit, needle):
    p = write(tmp_path, edit(GOOD))
    with pytest.raises(InputError) as exc:
        load_scene(p)
    assert needle in str(exc.value)
    assert str(p) in str(exc.value)


def test_missing_mesh_names_key_and_line(tmp_path):
    text = GOOD.replace("  - {name: ball,", "  - {name: septum, mesh: meshes/nope.stl}\n  - {name: ball,")
    with pytest.raises(InputError, match=r":7: obstacles\[0\]\.mesh: mesh file not found: .*nope\.stl"):
        load_scene(write(tmp_path, text))


def test_missing_scene_file(tmp_path):
    with pytest.raises(InputError, match="file not found"):
        load_scene(tmp_path / "absent.yaml")


def test_joint_limits(tmp_path):
    text = GOOD + "joint_limits: {alpha1_deg: [-30, 30], beta3_mm: [-10, -5]}\n"
    sc = load_scene(write(tmp_path, text))
    lo, hi = sc.joint_box
    assert np.isclose(lo[3], -math.pi / 6) and np.isclose(hi[3], math.pi / 6)
    assert lo[0] == -10 and hi[0] == -5
    bad = GOOD + "joint_limits: {alpha1_deg: [-300, 30]}\n"
    with pytest.raises(InputError, match=r"joint_limits\.alpha1_deg: must lie inside"):
        load_scene(write(tmp_path, bad, "b.yaml"))
    outside = GOOD + "joint_limits: {alpha1_deg: [10, 30]}\n"
    with pytest.raises(InputError, match="start: outside the scene's joint_limits"):
        load_scene(write(tmp_path, outside, "c.yaml"))
