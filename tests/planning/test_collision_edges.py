"""Edge checks in batches: a long edge that collides early stops computing kinematics; a free one
checks every interior state; the batches cover the interior exactly once."""

from __future__ import annotations

import numpy as np
import pytest

from ctrplan.model.robot import Robot
from ctrplan.planning.model import PlanningModel
from ctrplan.planning.validity import EDGE_BATCHES, ConfigurationChecker, bisection_order, edge_batches


@pytest.mark.parametrize("k", [0, 1, 14, 15, 16, 31, 200])
def test_edge_batches_cover_the_interior_once(k):
    ranges = edge_batches(k)
    covered = [i for a, b in ranges for i in range(a, b)]
    assert covered == list(range(k))
    sizes = [b - a for a, b in ranges]
    full = [*EDGE_BATCHES, *[EDGE_BATCHES[-1]] * len(sizes)]
    assert sizes[:-1] == full[:max(len(sizes) - 1, 0)]  # batches grow: few calls for any edge
    assert k == 0 or 0 < sizes[-1] <= full[len(sizes) - 1]
    assert (len(ranges) == 1) == (0 < k <= EDGE_BATCHES[0])


def test_long_edge_through_an_obstacle_stops_after_the_first_batch(open_scene, cosserat):
    domain = Robot.nominal().domain
    checker = ConfigurationChecker(PlanningModel.of(open_scene, cosserat))
    # both ends valid, the straight line between them swings the robot through the ball
    goal = domain.from_box(np.array([0, 10, 5, 0.5, 3.0, 0.3]))
    assert checker.check(np.stack([open_scene.start, goal])).all()
    n = int(np.ceil(float(checker.space.distance(open_scene.start, goal)) / 0.25))
    assert n - 1 > 3 * EDGE_BATCHES[0]  # a long edge: several batches
    before = checker.counters.kinematics_calls
    assert not checker.check_motion(open_scene.start, goal, resolution=0.25)
    assert checker.counters.kinematics_calls - before == EDGE_BATCHES[0]
    # the same edge state by state: some state of the first batch (bisection order) collides
    first = np.asarray(bisection_order(n)[:EDGE_BATCHES[0]]) / n
    qs = checker.space.interpolate(open_scene.start, goal, first)
    assert not checker.check(qs).all()


def test_long_free_edge_checks_every_interior_state(open_scene, cosserat):
    checker = ConfigurationChecker(PlanningModel.of(open_scene, cosserat))
    a = open_scene.start
    b = a.copy()
    b[:3] += np.array([10.0, 10.0, 5.0])  # a short insertion move in free space: 7.07 mm
    assert checker.check(np.stack([a, b])).all()
    before = checker.counters.kinematics_calls, checker.counters.kinematics_batches
    assert checker.check_motion(a, b, resolution=0.1)
    n = int(np.ceil(float(checker.space.distance(a, b)) / 0.1))
    assert checker.counters.kinematics_calls - before[0] == n - 1
    assert checker.counters.kinematics_batches - before[1] == len(edge_batches(n - 1)) > 1
