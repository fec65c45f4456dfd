"""`ctrplan scene check`: each problem a user meets with their own scene is found before planning,
in one line naming what and where, and a usable scene passes. The verdicts are checked against
geometry computed here (distances from the exact backbone to a sphere), not against the checker."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from ctrplan.cli.app import main
from ctrplan.kinematics import CosseratBackend
from ctrplan.scene.geometry import transform_points
from ctrplan.scene.loader import load_scene
from tests.paths import SCENES

OPEN = (SCENES / "open.yaml").read_text()
START = "start: [-80.0, -65.0, -10.0, 0.0, 0.0, 0.0]"


def scene_file(folder: Path, text: str, name: str = "scene.yaml") -> Path:
    path = folder / name
    path.write_text(text)
    return path


def check(path: Path, capsys, *extra: str) -> tuple[int, list[str], str]:
    capsys.readouterr()
    code = main(["scene", "check", str(path), *extra])
    captured = capsys.readouterr()
    return code, captured.err.strip().splitlines(), captured.out


def test_a_usable_scene_passes_with_a_summary(tmp_path, capsys):
    code, err, out = check(scene_file(tmp_path, OPEN), capsys)
    assert code == 0 and not err
    assert "usable" in out and "start: valid" in out


def test_meshes_in_metres_are_reported(tmp_path, capsys):
    trimesh.creation.box(extents=[0.02, 0.02, 0.02]).export(tmp_path / "box_m.stl")
    tiny = "obstacles:\n- {name: tiny, mesh: box_m.stl, position: [40.0, 40.0, 100.0]}\n"
    text = OPEN[:OPEN.index("obstacles:")] + tiny + OPEN[OPEN.index("target:"):]
    code, err, _ = check(scene_file(tmp_path, text), capsys)
    assert code == 2 and len(err) == 1 and "metres" in err[0], err


def test_a_target_inside_an_obstacle_is_named(tmp_path, capsys):
    text = OPEN.replace("obstacles:\n", "obstacles:\n- {name: tumour_capsule, sphere: "
                                        "{center: [37.2, -27.2, 181.6], radius: 9.0}}\n")
    code, err, _ = check(scene_file(tmp_path, text), capsys)
    assert code == 2 and any("inside the obstacle 'tumour_capsule'" in e for e in err), err


def test_a_target_inside_a_mesh_file_is_named(tmp_path, capsys):
    """An STL file repeats each vertex per triangle: the obstacle is closed only once they are
    merged, and a target 6 mm deep inside it must be found as for a primitive."""
    trimesh.creation.icosphere(subdivisions=3, radius=6.0).export(tmp_path / "capsule.stl")
    text = OPEN.replace("obstacles:\n", "obstacles:\n- {name: tumour_capsule, mesh: capsule.stl, "
                                        "position: [37.2, -27.2, 181.6]}\n")
    code, err, _ = check(scene_file(tmp_path, text), capsys)
    assert code == 2 and any("inside the obstacle 'tumour_capsule'" in e for e in err), err


def test_fix_writes_a_usable_scene_with_the_robot_relative_to_it(tmp_path, capsys):
    robot = tmp_path / "robots" / "mine.yaml"
    robot.parent.mkdir()
    robot.write_text((SCENES.parent / "ctrplan" / "data" / "nominal.yaml").read_text())
    out = tmp_path / "fixed" / "scene.yaml"
    code, err, stdout = check(scene_file(tmp_path, OPEN), capsys, "--robot", str(robot), "--fix", str(out))
    assert code == 0 and not err and "usable" in stdout, err
    assert "robot: ../robots/mine.yaml" in out.read_text()
    assert load_scene(out).robot.fingerprint == load_scene(scene_file(tmp_path, OPEN)).robot.fingerprint


def test_a_target_behind_the_plate_is_out_of_reach(tmp_path, capsys):
    text = OPEN.replace("point: [37.2, -27.2, 181.6]", "point: [0.0, 0.0, -60.0]")
    code, err, _ = check(scene_file(tmp_path, text), capsys)
    assert code == 2 and len(err) == 1 and "no configuration of the robot puts its tip" in err[0], err


def clearance_to_sphere(scene, q: np.ndarray, centre: np.ndarray, radius: float) -> float:
    """Smallest gap (mm) between the exact backbone's surface and a sphere, from points alone."""
    bb = CosseratBackend(scene.robot).forward(q, points=200)
    points = transform_points(scene.base_pose, bb.positions_mm[0])
    return float(np.min(np.linalg.norm(points - centre, axis=1) - radius - bb.radius_mm[0]))


def test_a_colliding_start_is_named_and_fixed(tmp_path, capsys):
    scene = load_scene(scene_file(tmp_path, OPEN))
    centre = CosseratBackend(scene.robot).forward(scene.start, points=11).positions_mm[0, 4]  # on the robot
    text = OPEN.replace("obstacles:\n", f"obstacles:\n- {{name: blocker, sphere: {{center: "
                                        f"{np.round(centre, 3).tolist()}, radius: 3.0}}}}\n")
    path = scene_file(tmp_path, text)
    scene = load_scene(path)
    assert clearance_to_sphere(scene, scene.start, centre, 3.0) < 0  # the premise: it does collide
    code, err, _ = check(path, capsys, "--fix", str(tmp_path / "fixed" / "scene.yaml"))
    assert code == 0, err
    assert len(err) == 1 and "in collision with blocker" in err[0] and "nearest valid start" in err[0]
    fixed = load_scene(tmp_path / "fixed" / "scene.yaml")
    assert clearance_to_sphere(fixed, fixed.start, centre, 3.0) > scene.settings.margin_mm
    assert check(tmp_path / "fixed" / "scene.yaml", capsys)[0] == 0


def test_a_start_outside_the_domain_gets_the_nearest_valid_one(tmp_path, capsys):
    path = scene_file(tmp_path, OPEN.replace(START, "start: [-80.0, -65.0, -12.0, 0.0, 0.0, 0.0]"))
    code, err, _ = check(path, capsys)
    assert code == 2 and len(err) == 1 and "beta3" in err[0] and "nearest valid start" in err[0], err
    found = np.array([float(v) for v in err[0].split("nearest valid start: [")[1].split("]")[0].split(",")])
    scene = load_scene(path, check_start=False)
    scene.robot.check_joints(found)  # inside the domain
    assert found[2] == pytest.approx(-10.0)  # the nearest: beta3 clipped onto its bound


def test_plan_refuses_a_target_inside_an_obstacle_at_once(tmp_path, capsys):
    text = OPEN.replace("obstacles:\n", "obstacles:\n- {name: tumour_capsule, sphere: "
                                        "{center: [37.2, -27.2, 181.6], radius: 9.0}}\n")
    capsys.readouterr()
    code = main(["plan", str(scene_file(tmp_path, text)), "--backend", "cosserat", "--time-limit", "60"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "inside the obstacle 'tumour_capsule'" in err[0], err


def test_fix_never_writes_a_start_from_which_the_target_cannot_be_reached(tmp_path, capsys, monkeypatch):
    """The target sits in a closed cage (a hollow shell: the sampled reach, which ignores obstacles,
    finds it; no robot gets in), and the start collides: collision-free starts exist, but from none
    does the exact model reach the target, so --fix says there is no fix and writes nothing."""
    import ctrplan.planning.start_fix as start_fix

    monkeypatch.setattr(start_fix, "FIX_SEARCH_STATES", 1500)  # the verdict holds for any budget
    monkeypatch.setattr(start_fix, "FIX_CANDIDATES", 2)
    scene = load_scene(scene_file(tmp_path, OPEN))
    outer = trimesh.creation.icosphere(subdivisions=2, radius=14.0)
    inner = trimesh.creation.icosphere(subdivisions=2, radius=10.0)
    inner.invert()
    cage = trimesh.util.concatenate([outer, inner])
    cage.apply_translation(scene.target.center)
    cage.export(tmp_path / "cage.stl")
    centre = CosseratBackend(scene.robot).forward(scene.start, points=11).positions_mm[0, 4]
    blocker = f"{{name: blocker, sphere: {{center: {np.round(centre, 3).tolist()}, radius: 3.0}}}}"
    text = OPEN.replace("obstacles:\n", f"obstacles:\n- {{name: cage, mesh: cage.stl}}\n- {blocker}\n")
    code, err, _ = check(scene_file(tmp_path, text), capsys, "--fix", str(tmp_path / "fixed.yaml"))
    assert code == 2 and len(err) == 1, err
    assert "in collision with blocker" in err[0]
    assert "no fix: from none of the 2 nearest valid starts" in err[0]
    assert not (tmp_path / "fixed.yaml").exists()
