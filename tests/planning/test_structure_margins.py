"""Per-structure margins in planning and exact validation (open.yaml, exact model): a margin on the
ball that the first plan's path does not keep makes that path invalid under exact validation (naming
the ball), and planning again with it gives a path that keeps it; distances are checked with the
independent point-to-sphere gap of `tests.independent.geometry`, not with ctrplan's collision code."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from ctrplan.collision.checker import RobotCollisionChecker
from ctrplan.collision.world import CollisionWorld
from ctrplan.kinematics import CosseratBackend
from ctrplan.model.robot import Robot
from ctrplan.planning import plan, validate_path
from ctrplan.scene.loader import load_scene
from tests.independent.geometry import sphere_gap
from tests.paths import SCENES

BALL_CENTER, BALL_RADIUS = [43.0, -47.0, 150.0], 7.0


@pytest.fixture(scope="module")
def open_scene():
    return load_scene(SCENES / "open.yaml")


@pytest.fixture(scope="module")
def exact():
    return CosseratBackend(Robot.nominal())


def with_ball_margin(scene, margin_mm: float):
    obstacles = tuple(replace(o, margin_mm=margin_mm) if o.name == "ball" else o for o in scene.obstacles)
    return replace(scene, obstacles=obstacles)


def ball_gap(bb) -> float:
    """The exact robot's smallest point-sampled surface distance to the ball (independent; the
    capsule chain's true distance is at most this)."""
    return sphere_gap(bb.positions_mm, bb.radius_mm, BALL_CENTER, BALL_RADIUS)


def test_a_structure_margin_invalidates_a_close_path_and_the_replan_keeps_it(open_scene, exact):
    # a path that passes near the ball: of a few plans, the closest (a margin just beyond a far
    # path's gap would swallow the target, and no path could keep it)
    firsts = [plan(open_scene, exact, seed=seed, time_limit_s=5.0) for seed in range(4)]
    assert all(p.solved for p in firsts), [p.message for p in firsts]
    first = min(firsts, key=lambda p: ball_gap(p.dense.exact))
    robot_margin = open_scene.settings.margin_mm
    gap0 = ball_gap(first.dense.exact)
    assert robot_margin - 1e-6 <= gap0 < 20.0
    # a margin on the ball that the first path does not keep (its required clearance exceeds gap0)
    margin = gap0 - robot_margin + 1.0
    guarded = with_ball_margin(open_scene, margin)
    check = validate_path(guarded, first.path, exact=exact)
    assert not check.report.collision_free
    assert check.report.first_collision.obstacles == ("ball",)
    # the same path under the scene without the margin stays valid (the margin did it)
    assert validate_path(open_scene, first.path, exact=exact).report.collision_free

    second = plan(guarded, exact, seed=0, time_limit_s=10.0)
    assert second.solved, second.message
    bb = second.dense.exact
    assert ball_gap(bb) >= robot_margin + margin - 1e-6
    # the per-structure listing agrees: not flagged, and no farther than the point-sampled gap
    ch = RobotCollisionChecker(CollisionWorld.from_scene(guarded), guarded.base_pose,
                               bb.positions_mm.shape[1], robot_margin)
    listed = {c.name: c for c in ch.structure_clearances(bb.positions_mm, bb.radius_mm, bb.s_mm)}
    ball = listed["ball"]
    assert not ball.below_margin and ball.required_mm == pytest.approx(robot_margin + margin)
    assert robot_margin + margin - 1e-6 <= ball.distance_mm <= ball_gap(bb) + 1e-9
    # where: the structure's point on the sphere, the robot's that far outside it, on the listed state
    assert np.linalg.norm(ball.obstacle_point - BALL_CENTER) == pytest.approx(BALL_RADIUS, abs=1e-5)
    assert np.linalg.norm(ball.robot_point - BALL_CENTER) - BALL_RADIUS == pytest.approx(ball.distance_mm,
                                                                                           abs=1e-5)
    state = guarded.to_scene(bb.positions_mm[ball.state])
    assert np.linalg.norm(state - ball.robot_point, axis=1).min() <= 5.0
    assert 0.0 <= ball.arc_length_mm <= bb.s_mm[ball.state, -1]
    # and the first path, listed under the margin, is flagged at the ball
    fb = first.dense.exact
    old = {c.name: c for c in ch.structure_clearances(fb.positions_mm, fb.radius_mm, fb.s_mm)}
    assert old["ball"].below_margin and old["ball"].distance_mm <= gap0 + 1e-9


class ShortCurvatures(CosseratBackend):
    """A deliberately wrong planning model (every pre-curvature 40 % too small): its paths fail exact
    validation and are repaired with the exact model."""

    name = "wrong"

    def __init__(self):
        robot = Robot.nominal()
        tubes = tuple(replace(t, curvature_per_mm=0.6 * t.curvature_per_mm) for t in robot.tubes)
        super().__init__(robot.with_changes(tubes=tubes))


def test_a_repaired_path_keeps_the_structure_margin(open_scene):
    margin = 1.5
    guarded = with_ball_margin(open_scene, margin)
    res = plan(guarded, ShortCurvatures(), seed=1, time_limit_s=5.0)
    assert res.solved and res.validated.repaired, res.message
    assert ball_gap(res.dense.exact) >= open_scene.settings.margin_mm + margin - 1e-6
