"""`ctrplan scene place`: a base pose and a start through an entry point, written into the user's scene
with its comments kept; a blocked entry is one line and nothing written. The anatomy is a plate with a
round hole (the entry) in front of the target, made here; the verdicts are checked against the plate's
geometry (the backbone's distance from the hole's axis where it crosses the plate), not against the
collision checker."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

import ctrplan.planning.placement as placement
from ctrplan.cli.app import main
from ctrplan.kinematics import CosseratBackend
from ctrplan.scene.edit import with_keys
from ctrplan.scene.geometry import transform_points
from ctrplan.scene.loader import load_scene

PLATE_Z, PLATE_HALF_THICKNESS = 100.0, 2.0
TARGET = [12.0, 5.0, 165.0]
SCENE = f"""# my patient: a plate with a hole
name: plate
robot: nominal   # the paper's robot
base_pose:
  position: [0.0, 0.0, 0.0]
obstacles:
- name: plate
  mesh: plate.stl
target:
  point: {TARGET}
  tolerance_mm: 3.0
# retracted, but the plate is in the way
start: [-80.0, -65.0, -10.0, 0.0, 0.0, 0.0]
planner:
  points: 30
  margin_mm: 0.2
"""


@pytest.fixture(autouse=True)
def fewer_samples(monkeypatch):
    monkeypatch.setattr(placement, "REACH_SAMPLES", 1000)


def plate_scene(folder, hole_mm: float):
    plate = trimesh.creation.annulus(r_min=hole_mm, r_max=70.0, height=2 * PLATE_HALF_THICKNESS)
    plate.apply_translation([0.0, 0.0, PLATE_Z])
    plate.export(folder / "plate.stl")
    path = folder / "scene.yaml"
    path.write_text(SCENE)
    return path


def through_plate(scene, q) -> float:
    """The largest distance (mm) from the hole's axis of the backbone's surface within the plate."""
    bb = CosseratBackend(scene.robot).forward(q, points=400)
    p = transform_points(scene.base_pose, bb.positions_mm[0])
    inside = np.abs(p[:, 2] - PLATE_Z) <= PLATE_HALF_THICKNESS + bb.radius_mm[0]
    assert inside.any()  # the backbone does cross the plate
    return float(np.max(np.linalg.norm(p[inside, :2], axis=1) + bb.radius_mm[0][inside]))


def test_the_robot_is_placed_through_the_hole_and_the_comments_stay(tmp_path, capsys):
    """Written to --out in a new folder: the comments kept, the mesh path made relative to it, the
    user's scene untouched."""
    path = plate_scene(tmp_path, hole_mm=6.0)
    before = path.read_text()
    capsys.readouterr()
    placed = tmp_path / "placed" / "scene.yaml"
    code = main(["scene", "place", str(path), "--entry", f"0,0,{PLATE_Z}", "--out", str(placed), "--json"])
    out = capsys.readouterr()
    assert code == 0, out.err
    doc = json.loads(out.out)
    assert path.read_text() == before
    path, text = placed, placed.read_text()
    assert "mesh: ../plate.stl" in text
    assert "# my patient: a plate with a hole" in text and "# the paper's robot" in text
    assert "# retracted, but the plate is in the way" in text
    scene = load_scene(path)
    np.testing.assert_allclose(scene.start, doc["start"], atol=1e-6)
    assert through_plate(scene, scene.start) < 6.0  # the start enters through the hole, clear of its rim
    assert transform_points(scene.base_pose, np.zeros((1, 3)))[0, 2] < PLATE_Z  # the base is outside
    goal = np.array(doc["chosen"]["goal"])
    tip = transform_points(scene.base_pose, CosseratBackend(scene.robot).forward(goal, points=2).tip_mm)[0]
    assert np.linalg.norm(tip - TARGET) < 1e-6 + 3.0 and through_plate(scene, goal) < 6.0
    assert doc["chosen"]["solved"] and doc["chosen"]["path_clearance_mm"] > 0


def test_a_closed_entry_is_one_line_and_nothing_is_written(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(placement, "REFINE_ROUNDS", 1)  # no refinement frees a tube through a 0.5 mm hole
    path = plate_scene(tmp_path, hole_mm=0.5)  # narrower than the tubes
    before = path.read_text()
    capsys.readouterr()
    code = main(["scene", "place", str(path), "--entry", f"0,0,{PLATE_Z}"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert "no placement through the entry" in err[0] and "plate (" in err[0], err
    assert path.read_text() == before


@pytest.mark.parametrize("entry, expected", [("0,0", "three numbers"), ("nan,0,0", "three numbers"),
                                             (",".join(map(str, TARGET)), "apart from the target")])
def test_a_bad_entry_is_refused(tmp_path, capsys, entry, expected):
    path = plate_scene(tmp_path, hole_mm=6.0)
    capsys.readouterr()
    code = main(["scene", "place", str(path), f"--entry={entry}"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "--entry" in err[0] and expected in err[0], err


def test_keys_are_replaced_in_place_and_flow_style_is_dumped():
    text = ("# head\nname: a  # why\nobstacles:\n- {name: x, mesh: x.stl}  # mine\n- name: y\n  mesh: y.stl\n"
            "start: [1, 2]\n\n# tail comment\nplanner:\n  points: 3\n")
    edited, kept = with_keys(text, {"start": [3, 4], "base_pose": {"position": [0, 0, 1]},
                                    "obstacles": [{"name": "x", "mesh": "../x.stl"}]})
    assert kept and edited.startswith("# head\nname: a  # why\nobstacles:\n- name: x\n  mesh: ../x.stl\n"
                                      "start: [3, 4]\n\n# tail comment\nplanner:\n")
    assert edited.endswith("base_pose:\n  position: [0, 0, 1]\n")
    dumped, kept = with_keys("{name: a, start: [1, 2]}\n", {"start": [3, 4]})
    assert not kept and "start: [3, 4]" in dumped and "name: a" in dumped
