"""Design task files: the format of docs/design.md §5, bad input (one line naming file, line and key; exit 2),
the search space, and the skull-base task's targets lying in the anatomy's free space."""

from __future__ import annotations

import itertools
import math
import os
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from ctrplan.base.errors import InputError
from ctrplan.cli.app import main
from ctrplan.collision.checker import RobotCollisionChecker
from ctrplan.collision.world import CollisionWorld
from ctrplan.design.space import (
    DIAMETERS,
    distributions,
    max_strain,
    robot_dict,
    total_length_mm,
)
from ctrplan.design.task import load_task
from ctrplan.model.robot import Robot, Tube, robot_from_dict
from tests.paths import REPO

SKULLBASE_TASK = REPO / "scenes" / "skullbase_design.yaml"

TASK = """\
scene: {scene}
targets:
  - {{name: sella, ellipsoid: {{center: [-2.5, 22.0, 81.0], semi_axes_mm: [3.5, 2.5, 3.5]}}}}
  - {{name: clivus, point: [0.0, 9.0, 73.6], tolerance_mm: 2.0,
     direction: [0, 0, 1], angle_tolerance_deg: 30}}
robot: nominal
vary:
  1: {{curvature_1_per_m: [0.0, 60.0], curved_length_mm: [20.0, 120.0]}}
  2: {{curvature_1_per_m: [0.0, 30.0]}}
catalogue:
  - {{inner_diameter_mm: 0.40, outer_diameter_mm: 0.50}}
  - {{inner_diameter_mm: 0.70, outer_diameter_mm: 0.90}}
  - {{inner_diameter_mm: 1.20, outer_diameter_mm: 1.50}}
  - {{inner_diameter_mm: 1.00, outer_diameter_mm: 1.10}}
constraints: {{max_strain: 0.08, snap_free: true}}
objectives: [targets_reached, -max_strain]
budget: {{trials: 60, plan_time_s: 5.0}}
"""


@pytest.fixture()
def task_file(tmp_path: Path) -> Path:
    """The task of docs/design.md §5, in a folder beside the scenes (paths relative to the task file)."""
    folder = tmp_path / "tasks"
    folder.mkdir()
    path = folder / "task.yaml"
    path.write_text(TASK.format(scene=os.path.relpath(REPO / "scenes" / "skullbase.yaml", folder)))
    return path


def test_example_task_loads(task_file):
    task = load_task(task_file)
    assert [t.name for t in task.targets] == ["sella", "clivus"]
    assert task.targets[1].region.direction.tolist() == [0.0, 0.0, 1.0]
    assert math.degrees(task.targets[1].region.angle_tolerance_rad) == pytest.approx(30.0)
    assert [(v.tube, v.field, v.low, v.high) for v in task.vary] == [
        (1, "curvature_1_per_m", 0.0, 60.0), (1, "curved_length_mm", 20.0, 120.0),
        (2, "curvature_1_per_m", 0.0, 30.0)]
    assert [o.label for o in task.objectives] == ["targets_reached", "-max_strain"]
    assert (task.trials, task.plan_time_s, task.max_strain, task.snap_free) == (60, 5.0, 0.08, True)
    # nested sets of three stock sizes: every ordered triple of the four whose sizes nest
    sizes = [(0.4, 0.5), (1.0, 1.1), (0.7, 0.9), (1.2, 1.5)]
    nested = [c for c in itertools.combinations(sorted(sizes, key=lambda s: s[1]), 3)
              if all(a[1] <= b[0] for a, b in itertools.pairwise(c))]
    assert len(nested) == 4
    assert [[(s.inner_diameter_mm, s.outer_diameter_mm) for s in c] for c in task.diameter_sets] == \
        [list(c) for c in nested]


def test_parameters_make_robot_files(task_file):
    task = load_task(task_file)
    space = distributions(task)
    assert list(space) == ["tube1.curvature_1_per_m", "tube1.curved_length_mm", "tube2.curvature_1_per_m",
                           DIAMETERS]
    label = space[DIAMETERS].choices[1]
    params = {"tube1.curvature_1_per_m": 40.0, "tube1.curved_length_mm": 60.0, "tube2.curvature_1_per_m": 5.0,
              DIAMETERS: label}
    d = robot_dict(task, params)
    robot = robot_from_dict(d, "design")
    t1, t2, t3 = robot.tubes
    assert t1.curvature_per_mm == pytest.approx(0.040) and t1.curved_length_mm == 60.0
    assert t2.curvature_per_mm == pytest.approx(0.005)
    assert t3.curvature_per_mm == pytest.approx(Robot.nominal().tubes[2].curvature_per_mm)  # not varied
    ods = [t.outer_diameter_mm for t in robot.tubes]
    assert " ".join(f"{t.inner_diameter_mm:g}/{t.outer_diameter_mm:g}" for t in robot.tubes) == label
    # strain kappa * OD / 2 and total length from first principles
    expect = max(t.curvature_per_mm * od / 2 for t, od in zip(robot.tubes, ods, strict=True))
    assert max_strain(d) == pytest.approx(expect)
    assert total_length_mm(d) == pytest.approx(sum(t.length_mm for t in robot.tubes))
    # the base design is the base robot itself (same fingerprint)
    assert robot_from_dict(robot_dict(task, {}), "base").fingerprint == Robot.nominal().fingerprint


def _edit(path: Path, change) -> None:
    data = yaml.safe_load(path.read_text())
    change(data)
    path.write_text(yaml.safe_dump(data, sort_keys=False))


@pytest.mark.parametrize("change, key, needle", [
    (lambda d: d.update(colour="red"), "colour", "unknown key"),
    (lambda d: d.pop("targets"), "", "missing required key 'targets'"),
    (lambda d: d["vary"].update({4: {"curvature_1_per_m": [0, 1]}}), "vary.4", "tube index 1..3"),
    (lambda d: d["vary"][2].update(youngs_modulus_gpa=[10, 20]), "vary.2.youngs_modulus_gpa", "unknown key"),
    (lambda d: d["vary"][1].update(curvature_1_per_m=[50, 10]), "vary.1.curvature_1_per_m", "exceeds max"),
    (lambda d: d["vary"][1].update(curvature_1_per_m=[0, 5000]), "vary.1.curvature_1_per_m",
     "physical range"),
    (lambda d: d.update(catalogue=[{"inner_diameter_mm": 0.4, "outer_diameter_mm": 0.5}]), "catalogue",
     "no 3 sizes of the catalogue nest"),
    (lambda d: d["catalogue"][0].update(inner_diameter_mm=0.6), "catalogue[0]", "inner diameter must be <"),
    (lambda d: d.update(objectives=["-max_strain", "targets_reached"]), "objectives",
     "must be targets_reached"),
    (lambda d: d.update(objectives=["targets_reached", "speed"]), "objectives[1]",
     "unknown objective 'speed'"),
    (lambda d: d["targets"][1].update(name="sella"), "targets[1].name", "duplicate target name"),
    (lambda d: d["targets"][1].update(name="a/b"), "targets[1].name", "names a folder"),
    (lambda d: d["targets"][0].update(tolerance_mm=1.0), "targets[0]",
     "either point + tolerance_mm or ellipsoid"),
    (lambda d: d["budget"].update(trials=0), "budget.trials", "integer >= 1"),
    (lambda d: d["constraints"].update(max_strain=0.5), "constraints.max_strain", "must be in (0, 0.1]"),
    (lambda d: d.update(scene="nope.yaml"), "scene", "no such file"),
    (lambda d: d.update(robot="two_tube_nope.yaml"), "robot", "no such file"),
])
def test_bad_task_files_name_the_key_and_line(task_file, capsys, change, key, needle):
    _edit(task_file, change)
    text = task_file.read_text().splitlines()
    out = task_file.parent / "out"
    rc = main(["design", str(task_file), "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1, err
    assert needle in err and str(task_file) in err
    if key:  # "file:LINE: key: ..." and LINE is where that key (or list item) is
        m = re.search(rf":(\d+): {re.escape(key)}: ", err)
        assert m, err
        line = text[int(m.group(1)) - 1]
        last = re.split(r"[.\[]", key)[-1]
        assert line.lstrip().startswith("-") if last.endswith("]") else f"{last}:" in line, (key, line)
    assert not out.exists()


@pytest.mark.parametrize("args, needle", [
    (["--trials", "0"], "--trials: need at least 1"),
    (["--time-limit", "-1"], "--time-limit: must be a positive duration"),
    (["--workers", "64"], "--workers: 64 workers but only"),
    (["--seed", "-3"], "--seed: must be >= 0"),
    (["--storage", "nosuchdb://x"], "--storage: cannot open 'nosuchdb://x'"),
])
def test_bad_options(task_file, capsys, tmp_path, args, needle):
    rc = main(["design", str(task_file), "--out", str(tmp_path / "o"), *args])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and needle in err and len(err.splitlines()) == 1, err


def test_domain_corners_decide_tube_order():
    """Tube 2 may not reach past tube 1 anywhere in the domain: with beta2 - beta1 up to 20 mm that
    needs L1 - L2 >= 20 (closed form at the corner), whatever the rotations. A design that breaks
    it is refused by the robot loader, so it never reaches the stability sweep."""
    def robot(l2: float) -> Robot:
        from ctrplan.model.robot import JointDomain

        tubes = (Tube(0.4, 0.5, 100.0, 40.0, 0.02), Tube(0.7, 0.9, 60.0, l2 - 60.0, 0.01))
        dom = JointDomain(((-10.0, 0.0), (0.0, 20.0), (-math.pi, math.pi), (0.5, 1.0)))
        return Robot(tubes=tubes, domain=dom)

    assert robot(140.0 - 20.0).n_tubes == 2
    with pytest.raises(InputError, match="tube 2's tip past tube 1's: need beta2 - beta1 <= L1 - L2 = 19 mm"):
        robot(140.0 - 19.0)


def _crossings(origin: np.ndarray, direction: np.ndarray, triangles: np.ndarray) -> int:
    """How many triangles (T, 3, 3) the ray from ``origin`` along ``direction`` crosses
    (Moller-Trumbore)."""
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    e1, e2 = b - a, c - a
    p = np.cross(direction, e2)
    det = np.einsum("ij,ij->i", e1, p)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = origin - a
    u = np.einsum("ij,ij->i", s, p) * inv
    q = np.cross(s, e1)
    v = (q @ direction) * inv
    t = np.einsum("ij,ij->i", e2, q) * inv
    return int(np.sum(ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-9)))


def test_skullbase_targets_lie_in_the_airway():
    """Every target of the skull-base task lies inside the lofted airway (a ray from it across the
    airway -- at constant depth z, where the airway is one tube -- crosses its wall an odd number of
    times), outside the carotids and the optic apparatus, with room around it, and the nominal robot
    could be long enough to get there."""
    task = load_task(SKULLBASE_TASK)
    assert len(task.targets) >= 4 and all(len(t.reason) > 20 for t in task.targets)
    scene = task.scene
    tunnel = np.concatenate([np.asarray(o.to_trimesh().triangles) for o in scene.obstacles
                             if "carotid" not in o.name and "chiasm" not in o.name])
    others = [o for o in scene.obstacles if "carotid" in o.name or "chiasm" in o.name]
    clearance = RobotCollisionChecker(CollisionWorld.from_scene(scene), np.eye(4), 2, 0.0)
    angles = np.radians(np.arange(8) * 45.0 + 10.0)  # off the mesh's symmetry planes
    for target in task.targets:
        c = target.region.center
        for d in np.stack([np.cos(angles), np.sin(angles), np.zeros(8)], axis=1):
            assert _crossings(c, d, tunnel) % 2 == 1, target.name
        for o in others:  # outside the bounding box of each carotid and of the optic apparatus
            lo, hi = o.bounds
            assert np.any((c < lo) | (c > hi)), (target.name, o.name)
        point = np.stack([c, c + [0.0, 0.0, 1e-3]])  # a point as a capsule of no radius
        gap = clearance.clearance(point, np.zeros(2)).distance_mm
        assert gap >= 1.0, (target.name, gap)
        reach = scene.robot.lengths_mm[0]
        assert np.linalg.norm(c - scene.base_pose[:3, 3]) < reach, target.name


def test_task_errors_are_input_errors(tmp_path):
    with pytest.raises(InputError, match="file not found"):
        load_task(tmp_path / "none.yaml")
    with pytest.raises(InputError, match="is a directory"):
        load_task(tmp_path)
