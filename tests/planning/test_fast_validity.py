"""The planner's shortcuts give the full answers: staged validity checks (distal half of the
backbone first) agree with FCL on the whole backbone, for states and for edges, and the exact goal
step brings a surrogate's goal onto the target with the exact model."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from ctrplan.collision.checker import RobotCollisionChecker
from ctrplan.kinematics import CosseratBackend, make_backend
from ctrplan.kinematics.base import DEFAULT_POINTS, Backend
from ctrplan.planning import ConfigurationChecker
from ctrplan.planning.model import PlanningModel, planning_backend
from ctrplan.planning.planner import EXACT_GOAL_TOL_MM, exact_goal
from ctrplan.scene.loader import load_scene
from ctrplan.scene.objects import Obstacle, TargetRegion
from tests.paths import SCENES


@pytest.fixture(scope="module")
def pinn_checker(skullbase):
    be, margin, _ = planning_backend(skullbase, make_backend("pinn", skullbase.robot))
    return ConfigurationChecker(PlanningModel.of(skullbase, be, margin_mm=margin))


def _fcl_valid(checker: ConfigurationChecker, q: np.ndarray) -> np.ndarray:
    """Whole backbones, FCL contacts on every capsule (no broadphase, no stages)."""
    fcl = RobotCollisionChecker(checker.world, checker.scene.base_pose, checker.points, checker.margin_mm)
    bb = checker.backend.forward(q, checker.points, check=False)
    return np.array([bool(ok) and not fcl.contacts(p, r)
                     for ok, p, r in zip(bb.converged, bb.positions_mm, bb.radius_mm, strict=True)])


def _states_near_start(checker: ConfigurationChecker, n: int, seed: int) -> np.ndarray:
    """States scattered around the start (planning metric, sd 6 mm): valid and colliding ones."""
    sp = checker.space
    noise = np.random.default_rng(seed).normal(scale=6.0, size=(n, sp.dimension))
    y = sp.to_coords(checker.scene.start) + noise
    return sp.to_joints(sp.clip(y))


def _one_by_one(checker: ConfigurationChecker, q: np.ndarray) -> np.ndarray:
    """`is_valid` (the planner's single-state path) of every row, on a checker with an empty cache."""
    fresh = ConfigurationChecker(checker.model)
    return np.array([fresh.is_valid(qi) for qi in q])


def test_staged_state_checks_agree_with_fcl_on_the_whole_backbone(skullbase, pinn_checker):
    assert len(pinn_checker.stages) == 2  # the PINN makes part of a backbone cheaper
    q = _states_near_start(pinn_checker, 400, seed=7)
    valid = pinn_checker.check(q)
    assert 0.1 < valid.mean() < 0.9, valid.mean()  # both kinds are tested
    np.testing.assert_array_equal(valid, _fcl_valid(pinn_checker, q))
    np.testing.assert_array_equal(_one_by_one(pinn_checker, q), valid)


def test_a_body_is_the_backbone_a_collision_check_needs(skullbase, pinn_checker):
    """`Backend.body` (what a validity check asks for) equals the corresponding parts of `forward`:
    the PINN's own kernel, and the planning margin added by region."""
    q = _states_near_start(pinn_checker, 50, seed=3)
    stage = pinn_checker.stages[0]
    for be in (pinn_checker.backend, pinn_checker.backend.inner, CosseratBackend(skullbase.robot)):
        body, bb = be.body(q, stage, check=False), be.forward(q, stage, check=False)
        np.testing.assert_allclose(body.positions_mm, bb.positions_mm, atol=1e-6)  # float32 network
        np.testing.assert_allclose(body.radius_mm, bb.radius_mm, atol=1e-12)
        np.testing.assert_array_equal(body.usable, bb.stable)
    planning, plain = pinn_checker.backend, pinn_checker.backend.inner
    assert (planning.body(q, stage).radius_mm - plain.body(q, stage).radius_mm).min() > 0  # the bound
    # the prepared single-state query (the planner's hot path) is `body`, bit for bit
    for be in (planning, plain, CosseratBackend(skullbase.robot)):
        query = be.body_query(stage)
        for qi in q[:10]:
            got, want = query(qi[None]), be.body(qi[None], stage, check=False)
            for a, b in zip(got[:3], want[:3], strict=True):
                np.testing.assert_array_equal(a, b)


def test_contacts_on_the_proximal_half_alone_are_found():
    """A ball beside the proximal half of the backbone, where the first stage does not look."""
    scene = load_scene(SCENES / "open.yaml")
    pose = np.eye(4)
    pose[:3, 3] = [6.0, 0.0, 45.0]
    scene = replace(scene, obstacles=(Obstacle("ball", "sphere", pose, radius=3.0),))
    be, margin, _ = planning_backend(scene, make_backend("pinn", scene.robot))
    checker = ConfigurationChecker(PlanningModel.of(scene, be, margin_mm=margin))
    q = scene.robot.sample_joints(300, rng=11)
    bb = be.forward(q, checker.points, check=False)
    assert bb.s_mm[0, checker.points // 2] > 45.0 + 10.0  # the ball is beside the proximal half
    valid = checker.check(q)
    assert 0.05 < 1 - valid.mean() < 0.95, valid.mean()
    np.testing.assert_array_equal(valid, _fcl_valid(checker, q))
    np.testing.assert_array_equal(_one_by_one(checker, q), valid)


def test_staged_edge_checks_agree_with_fcl_on_every_state(skullbase, pinn_checker):
    """An edge is valid exactly when its end and every interior state at the resolution are."""
    q = _states_near_start(pinn_checker, 400, seed=8)
    starts = q[pinn_checker.check(q)][:12]
    rng = np.random.default_rng(9)
    res = skullbase.settings.resolution_mm
    outcomes = []
    for q1 in starts:
        y2 = pinn_checker.space.to_coords(q1) + rng.normal(scale=4.0, size=pinn_checker.space.dimension)
        q2 = pinn_checker.space.to_joints(pinn_checker.space.clip(y2))
        n = max(1, int(np.ceil(float(pinn_checker.space.distance(q1, q2)) / res)))
        line = pinn_checker.space.interpolate(q1, q2, np.arange(1, n + 1) / n)
        expected = bool(_fcl_valid(pinn_checker, line).all())
        fresh = ConfigurationChecker(pinn_checker.model)
        fresh.check(q1)
        assert fresh.check_motion(q1, q2, res) == expected
        outcomes.append(expected)
    assert any(outcomes) and not all(outcomes)


class _CurvedMore(Backend):
    """A deliberately wrong surrogate: the exact model of the robot with tube 1 8 % more curved."""

    name = "curved_more"

    def __init__(self, robot):
        super().__init__(robot)
        tubes = list(robot.tubes)
        tubes[0] = replace(tubes[0], curvature_per_mm=1.08 * tubes[0].curvature_per_mm)
        self.inner = CosseratBackend(replace(robot, tubes=tuple(tubes)))

    def forward(self, q, points=DEFAULT_POINTS, *, guess=None, check=True):
        return self.inner.forward(q, points, check=check)


def test_exact_goal_puts_the_exact_tip_where_the_surrogate_put_it():
    scene = load_scene(SCENES / "open.yaml")
    exact = CosseratBackend(scene.robot)
    checker = ConfigurationChecker(PlanningModel.of(scene, _CurvedMore(scene.robot), exact=exact))
    goal = np.array([-40.0, -25.0, -5.0, 0.4, 1.2, -0.6])
    aim = checker.backend.forward(goal, 2).tip_mm[0]
    assert np.linalg.norm(exact.forward(goal, 2).tip_mm[0] - aim) > 1.0  # the surrogate is off
    path = np.stack([scene.start, goal])
    out = exact_goal(path, checker)
    assert out.shape == (3, 6)
    np.testing.assert_array_equal(out[:2], path)
    assert np.linalg.norm(exact.forward(out[-1], 2).tip_mm[0] - aim) <= EXACT_GOAL_TOL_MM + 1e-9
    assert np.linalg.norm(out[-1] - goal) < 5.0  # a small correction, not another configuration

    # with an approach direction: the surrogate's tip pose (position and tangent)
    aimed = replace(scene, target=replace(scene.target, direction=np.array([0.0, 0.0, 1.0]),
                                          angle_tolerance_rad=np.pi / 2))
    _, tangent, _ = checker.backend.tip_and_tangent(goal)
    out = exact_goal(path, ConfigurationChecker(checker.model.with_scene(aimed)))
    tip, exact_tangent, _ = exact.tip_and_tangent(out[-1])
    assert np.linalg.norm(tip - aim) < EXACT_GOAL_TOL_MM
    assert np.degrees(np.arccos(np.clip(exact_tangent[0] @ tangent[0], -1, 1))) < 0.2

    # left alone: when the exact tip is in the target already, and for an exact planning backend
    inside = replace(scene, target=TargetRegion.sphere(scene.to_scene(exact.forward(goal, 2).tip_mm[0]), 2.0))
    assert exact_goal(path, ConfigurationChecker(checker.model.with_scene(inside))) is path
    assert exact_goal(path, ConfigurationChecker(PlanningModel.of(scene, exact))) is path
