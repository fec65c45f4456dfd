"""The exact pool's joints (issue 40): half of them near the joint limits, by the arcsine law, spread
over the pool and inside the domain."""

from __future__ import annotations

import math

import numpy as np

from ctrplan.training.samples import pool_joints


def test_edge_share_follows_the_arcsine_law_near_the_limits(robot):
    q = pool_joints(robot, 40_000, np.random.default_rng(0), edge_share=0.5)
    assert not robot.domain.violations(q)
    box = robot.domain.to_box(q)
    lo, hi = robot.domain.box_lower, robot.domain.box_upper
    u = (box[:, :3] - lo[:3]) / (hi[:3] - lo[:3])
    near = (u < 0.05) | (u > 0.95)
    arcsine = 2 * (2 / math.pi) * math.asin(math.sqrt(0.05))   # 0.287 for the arcsine law, 0.1 uniform
    expected = 0.5 * 0.1 + 0.5 * arcsine
    np.testing.assert_allclose(near.mean(axis=0), expected, atol=0.01)
    np.testing.assert_allclose(near[:20_000].mean(axis=0), expected, atol=0.015)  # spread over the pool
    alphas = box[:, 3:]
    assert abs(float(np.mean(np.abs(alphas) > 0.9 * math.pi)) - 0.1) < 0.01      # rotations stay uniform
    uniform = robot.domain.to_box(pool_joints(robot, 40_000, np.random.default_rng(0)))
    u0 = (uniform[:, :3] - lo[:3]) / (hi[:3] - lo[:3])
    np.testing.assert_allclose(((u0 < 0.05) | (u0 > 0.95)).mean(axis=0), 0.1, atol=0.01)
