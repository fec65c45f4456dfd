"""A structure that moves: `CollisionWorld.moved` repaints the distance grid around the old and the new
place only (growing it where the new place reaches beyond it); the grid must be the one painted afresh
from the moved obstacles on the same cells, and the collision verdicts those of a world built anew."""

from __future__ import annotations

import numpy as np

from ctrplan.collision.broadphase import _LEVELS, _paint
from ctrplan.collision.checker import RobotCollisionChecker
from ctrplan.collision.world import CollisionWorld
from ctrplan.scene.loader import load_scene
from ctrplan.scene.objects import Obstacle
from tests.paths import SCENES

NAMES = ("sella_turcica", "right_internal_carotid", "optic_chiasm")


def _structures() -> list[Obstacle]:
    sc = load_scene(SCENES / "skullbase.yaml")
    ball = Obstacle("ball", "sphere", pose=np.array([[1, 0, 0, 6.0], [0, 1, 0, 20.0], [0, 0, 1, 84.0],
                                                    [0, 0, 0, 1]]), radius=2.0, margin_mm=0.3)
    return [o for o in sc.obstacles if o.name in NAMES] + [ball]


def test_a_moved_structure_gives_the_grid_and_verdicts_of_a_new_world():
    """Moves in turn -- a carotid by a step off the grid's lattice, twice (the second reuses what the
    others give its cells), the chiasm beyond the grid's edge (it grows), the ball: each time the
    repainted grid equals a grid painted afresh from the moved obstacles on its cells, and every
    backbone near them gets the verdict of a world built anew."""
    obstacles = _structures()
    world = CollisionWorld(obstacles)
    moves = [("right_internal_carotid", [-1.37, 0.52, 2.11]), ("right_internal_carotid", [0.9, 0.2, -1.3]),
             ("optic_chiasm", [0.4, 2.2, 3.3]), ("ball", [0.8, -3.3, 0.26])]
    grew = False
    for name, t in moves:
        i = next(k for k, o in enumerate(obstacles) if o.name == name)
        obstacles[i] = obstacles[i].translated(t)
        before = world.grid.values.shape
        world = world.moved(obstacles[i])
        grew |= world.grid.values.shape != before
        g = world.grid
        fresh = np.full(g.values.shape, _LEVELS, dtype=np.uint8)
        _paint(obstacles, g.lo, g.cell_mm, g.band_mm, fresh)
        np.testing.assert_array_equal(g.values, fresh)
        assert sorted(world.names) == sorted(CollisionWorld(obstacles, broadphase=False).names)
    assert grew
    rng = np.random.default_rng(3)
    starts = rng.uniform([-12, 12, 70], [10, 34, 92], size=(400, 1, 3))
    pts = starts + np.cumsum(rng.normal(scale=1.5, size=(400, 6, 3)), axis=1)
    radius = np.full((400, 6), 0.6)
    verdict = RobotCollisionChecker(world, np.eye(4), 6, 0.1).free_batch(pts, radius)
    anew = RobotCollisionChecker(CollisionWorld(obstacles), np.eye(4), 6, 0.1).free_batch(pts, radius)
    np.testing.assert_array_equal(verdict, anew)
    assert 0 < verdict.sum() < len(verdict)
