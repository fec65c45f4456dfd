"""The corridor RRT-Connect (`ctrplan.planning.corridor`): its sampler against closed forms, its paths
against the motion validator OMPL's planners use and against the exact model, and its goal states."""

from __future__ import annotations

import numpy as np
import pytest

from ctrplan.model.robot import Robot
from ctrplan.planning import ConfigurationChecker, PlanningModel, plan, resolve_backend
from ctrplan.planning.corridor import CorridorSampler
from ctrplan.planning.search import search
from ctrplan.planning.space import BoxSpace
from ctrplan.scene.loader import load_scene
from tests.paths import SCENES


@pytest.fixture(scope="module")
def strict():
    return load_scene(SCENES / "skullbase_strict.yaml")


def test_corridor_samples_follow_their_closed_forms():
    """All samples lie in the box; with share 1 (a box much larger than the noise) the squared
    distance to the start-goal line averages (D - 1) sigma^2 and the position along it is uniform;
    with share 0 the samples are uniform in the box (mean at its centre, variance width^2 / 12)."""
    space = BoxSpace.for_robot(Robot.nominal(), mm_per_rad=400.0)
    rng = np.random.default_rng(3)
    d, sigma = space.dimension, 2.0
    centre = 0.5 * (space.lower + space.upper)
    start, goal = centre - 0.2 * (space.upper - space.lower), centre + 0.2 * (space.upper - space.lower)
    y = CorridorSampler(space, rng, share=1.0, width_mm=sigma).sample(40_000, start, goal[None])
    assert np.all((y >= space.lower) & (y <= space.upper))
    axis = (goal - start) / np.linalg.norm(goal - start)
    along = (y - start) @ axis
    perp2 = np.sum((y - start) ** 2, axis=1) - along ** 2
    assert perp2.mean() == pytest.approx((d - 1) * sigma ** 2, rel=0.05)
    t = along / np.linalg.norm(goal - start)
    assert np.histogram(t, bins=5, range=(0.0, 1.0))[0] / len(t) == pytest.approx(np.full(5, 0.2), abs=0.01)
    u = CorridorSampler(space, rng, share=0.0).sample(40_000, start, goal[None])
    width = space.upper - space.lower
    assert u.mean(axis=0) == pytest.approx(centre, abs=0.02 * width.max())
    assert u.var(axis=0) == pytest.approx(width ** 2 / 12, rel=0.05)
    none = CorridorSampler(space, rng, share=1.0).sample(1000, start, np.zeros((0, d)))
    assert abs(none.mean(axis=0) - centre).max() < 0.1 * width.max()  # no goals yet: uniform


def test_corridor_plans_the_strict_skull_base_safely_and_repeatably(strict):
    """The default planner solves the scene whose straight joint line collides; the exact model
    confirms the path (plan's validation), every edge of it passes the single-state motion validator
    of OMPL's planners, and the same seed gives the same path."""
    assert strict.settings.planner == "corridor"
    backend = resolve_backend("pinn", strict.robot)
    first = plan(strict, backend, seed=5)
    assert first.solved and first.validated.collision_free and first.validated.tip_in_target
    assert first.planner == "corridor" and first.validated.repaired is False
    checker = ConfigurationChecker(PlanningModel.build(strict, backend, None, None))
    res = strict.settings.resolution_mm
    planned = first.path[:-1] if first.work.exact_goal.appended else first.path
    assert all(checker.check_motion(a, b, res) for a, b in zip(planned[:-1], planned[1:], strict=True))
    again = plan(strict, backend, seed=5)
    np.testing.assert_array_equal(again.path, first.path)


def test_corridor_reaches_a_single_goal_configuration(strict):
    """With a goal configuration (as a repair re-plans a stretch) the path ends exactly there."""
    backend = resolve_backend("pinn", strict.robot)
    checker = ConfigurationChecker(PlanningModel.build(strict, backend, None, None))
    goal = plan(strict, backend, seed=2).path[-2]
    out = search(checker, planner="corridor", goal_q=goal, seed=1, max_states=60_000, simplify=False)
    assert out.exact and out.path_q is not None
    np.testing.assert_allclose(out.path_q[0], strict.start, atol=1e-9)
    np.testing.assert_allclose(out.path_q[-1], goal, atol=1e-9)
