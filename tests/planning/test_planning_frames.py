"""Planning and exact validation in the scene frame, with a base pose that is not the identity.

The open workspace is moved rigidly (robot base, obstacles, target) by a rotation about a skew axis
and a shift: the same problem in other coordinates. Expectations come from outside the code under
test: tips from the separately written integrator (`tests/independent/cosserat.py`), the transform
applied here, distances to spheres and boxes computed here, and numbers of the scene files
(tolerance 3 mm, margin 0.2 mm).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ctrplan.planning import plan, validate_path
from ctrplan.planning.validate import CLEARANCE_CAP_MM
from ctrplan.scene.loader import load_scene
from tests.independent.cosserat import Tubes, solve
from tests.independent.geometry import axis_angle, box_gap, sphere_gap

START = [-80.0, -65.0, -10.0, 0.0, 0.0, 0.0]
TOLERANCE_MM = 3.0
MARGIN_MM = 0.2

#: The base pose: robot frame -> scene frame.
R_BASE = axis_angle([1.0, 2.0, -1.0], 70.0)
P_BASE = np.array([12.0, -40.0, 25.0])
BALL = (np.array([43.0, -47.0, 150.0]), 7.0)                         # open.yaml, robot frame
BLOCK = (np.array([-25.0, -30.0, 150.0]), np.array([20.0, 20.0, 20.0]), axis_angle([0, 0, 1], 30.0))
TARGET = np.array([37.2, -27.2, 181.6])


def to_scene(p: np.ndarray) -> np.ndarray:
    return np.asarray(p) @ R_BASE.T + P_BASE


def rows(m: np.ndarray) -> str:
    return "[" + ", ".join("[" + ", ".join(f"{v:.12g}" for v in row) + "]" for row in m) + "]"


def vec(v) -> str:
    return "[" + ", ".join(f"{x:.12g}" for x in v) + "]"


def write_scene(tmp_path: Path, obstacles: str, target: np.ndarray, name: str = "posed") -> Path:
    """A scene file with the base pose above, obstacles (YAML list text, scene frame) and a point
    target (robot-frame point ``target`` moved into the scene frame) of `TOLERANCE_MM`."""
    path = tmp_path / f"{name}.yaml"
    path.write_text(f"name: {name}\nrobot: nominal\nbase_pose:\n  position: {vec(P_BASE)}\n"
                    f"  rotation: {{matrix: {rows(R_BASE)}}}\nobstacles: {obstacles}\n"
                    f"target: {{point: {vec(to_scene(target))}, tolerance_mm: {TOLERANCE_MM}}}\n"
                    f"start: {vec(START)}\n"
                    f"planner: {{time_limit_s: 10.0, points: 30, margin_mm: {MARGIN_MM}}}\n")
    return path


def posed_open(tmp_path: Path) -> Path:
    """open.yaml moved by the base pose."""
    (c, r), (bc, size, br) = BALL, BLOCK
    obstacles = (f"\n- {{name: ball, sphere: {{center: {vec(to_scene(c))}, radius: {r}}}}}\n"
                 f"- {{name: block, box: {{center: {vec(to_scene(bc))}, size: {vec(size)}, "
                 f"rotation: {{matrix: {rows(R_BASE @ br)}}}}}}}")
    return write_scene(tmp_path, obstacles, TARGET)


def tip_mm(q) -> np.ndarray:
    """Tip of tube 1 (robot frame) by the independent integrator."""
    out = solve(np.atleast_2d(q), Tubes.paper())
    assert out["converged"].all()
    return out["tips_mm"][:, 0]


def surface_distance(points: np.ndarray, radius: np.ndarray) -> dict[str, float]:
    """Smallest distance (mm) between the robot's surface (backbone points, scene frame, with their
    tube radius) and each obstacle of the posed open scene."""
    (c, r), (bc, size, br) = BALL, BLOCK
    return {"ball": sphere_gap(points, radius, to_scene(c), r),
            "block": box_gap(points, radius, to_scene(bc), size, R_BASE @ br)}


def test_validation_checks_the_robot_where_the_base_pose_puts_it(tmp_path):
    scene = load_scene(posed_open(tmp_path))
    goal = scene.robot.domain.from_box(np.array([0, 10, 5, 0.5, 3.0, 0.3]))  # through the ball
    vp = validate_path(scene, np.stack([scene.start, goal]))
    rep = vp.report
    assert not rep.collision_free and rep.first_collision.obstacles == ("ball",)
    np.testing.assert_allclose(rep.tip_mm, to_scene(tip_mm(goal)[0]), atol=1e-3)
    i = rep.colliding_states[0]
    hit = surface_distance(to_scene(vp.exact.positions_mm[i]), vp.exact.radius_mm[i])
    assert hit["ball"] < MARGIN_MM  # the robot really is that close to the moved ball


@pytest.mark.parametrize(("offset", "inside"), [(0.5, True), (1.5, False)])
def test_tip_in_target_is_judged_in_the_scene_frame_with_the_files_tolerance(tmp_path, offset, inside):
    """The target sits ``offset`` x 3 mm from the independent tip of the path's end (robot frame,
    then moved by the base pose): inside at half the tolerance, outside at one and a half."""
    end = np.array([-30.0, -20.0, -5.0, 0.4, -0.3, 1.2])
    direction = np.array([2.0, -1.0, 2.0]) / 3.0
    target = tip_mm(end)[0] + offset * TOLERANCE_MM * direction
    scene = load_scene(write_scene(tmp_path, "[]", target, name="targets"))
    rep = validate_path(scene, np.stack([scene.start, end])).report
    assert rep.converged and rep.collision_free
    assert rep.tip_in_target is inside
    assert np.linalg.norm(np.asarray(rep.tip_mm) - to_scene(target)) == pytest.approx(
        offset * TOLERANCE_MM, abs=1e-3)


def test_validation_keeps_the_margin_and_measures_the_clearance(tmp_path):
    """A ball of 2 mm beside the straight first 5 mm of the backbone (all tubes straight there; the
    robot bends towards -y, the ball is on +y), 0.1 mm from tube 3's surface (outer radius 0.75 mm):
    it collides with the 0.2 mm margin, the clearance is 0.1 mm, and without the margin it is free."""
    q = np.array([-20.0, -10.0, -5.0, 0.0, 0.0, 0.0])
    gap, radius = 0.1, 2.0
    center = np.array([0.0, 0.75 + radius + gap, 2.5])
    ball = f"\n- {{name: ball, sphere: {{center: {vec(to_scene(center))}, radius: {radius}}}}}"
    scene = load_scene(write_scene(tmp_path, ball, tip_mm(q)[0], name="beside"))
    vp = validate_path(scene, q[None], measure=True)
    rep = vp.report
    assert not rep.collision_free and rep.first_collision.obstacles == ("ball",)
    assert rep.min_clearance_mm == pytest.approx(gap, abs=0.01)
    along = vp.clearance_mm[0]  # per capsule, as plan.html colours the backbone
    assert along[0] == pytest.approx(gap, abs=0.01) and along.min() == pytest.approx(gap, abs=0.01)
    assert along[-1] == CLEARANCE_CAP_MM  # the distal capsules are far from the ball: capped
    (ball_clearance,) = rep.structures  # the one structure, measured at the state and capsule nearest it
    assert ball_clearance.distance_mm == pytest.approx(gap, abs=0.01) and ball_clearance.below_margin
    free = validate_path(scene, q[None], margin_mm=0.0).report
    assert free.collision_free and free.ok


def test_plan_in_a_moved_scene_ends_in_the_target_and_clears_the_obstacles(tmp_path):
    res = plan(load_scene(posed_open(tmp_path)), "cosserat", seed=0, time_limit_s=10.0)
    assert res.solved, res.message
    end_tip = to_scene(tip_mm(res.path[-1])[0])
    assert np.linalg.norm(end_tip - to_scene(TARGET)) <= TOLERANCE_MM
    exact = res.dense.exact
    near = surface_distance(to_scene(exact.positions_mm), exact.radius_mm)
    assert min(near.values()) >= MARGIN_MM - 1e-6, near  # every checked state, margin included
    assert res.validated.min_clearance_mm == pytest.approx(min(near.values()), abs=0.05)


def test_validation_densifies_until_no_point_moves_more_than_the_thinnest_capsule(tmp_path):
    """All tubes turned together by 1 rad: points near the tip sweep ~0.1 m. Between checked states
    no backbone point may move more than tube 1's outer radius (0.25 mm) plus the margin."""
    scene = load_scene(posed_open(tmp_path))
    a = np.array([-30.0, -20.0, -5.0, -0.5, -0.5, -0.5])
    vp = validate_path(scene, np.stack([a, a + np.r_[0, 0, 0, 1.0, 1.0, 1.0]]))
    steps = np.linalg.norm(np.diff(vp.exact.positions_mm, axis=0), axis=-1).max(axis=1)
    assert steps.max() <= 0.25 + MARGIN_MM + 1e-9
    sweep = np.linalg.norm(tip_mm(a)[0] - tip_mm(a + np.r_[0, 0, 0, 1.0, 1.0, 1.0])[0])
    assert vp.report.states >= sweep / (0.25 + MARGIN_MM)
