"""A structure that moves: `CollisionWorld.moved` repaints the distance grid around the old and the new
place only; the result must equal a world built from scratch for the moved obstacles."""

from __future__ import annotations

import numpy as np

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
    """Two moves in turn (a carotid by a non-grid step, then the ball): the repainted grid is the one
    a new world builds, cell for cell, and both worlds give every capsule of random backbones near
    the structures the same verdict."""
    obstacles = _structures()
    world = CollisionWorld(obstacles)
    moves = [("right_internal_carotid", np.array([-1.37, 0.52, 2.11])), ("ball", np.array([0.8, -3.3, 0.26]))]
    for name, t in moves:
        i = next(k for k, o in enumerate(obstacles) if o.name == name)
        obstacles[i] = obstacles[i].translated(t)
        world = world.moved(obstacles[i])
        fresh = CollisionWorld(obstacles, broadphase=True)
        assert world.grid.values.shape == fresh.grid.values.shape
        np.testing.assert_allclose(world.grid.lo, fresh.grid.lo)
        np.testing.assert_array_equal(world.grid.values, fresh.grid.values)
        assert sorted(world.names) == sorted(fresh.names)
    rng = np.random.default_rng(3)
    starts = rng.uniform([-12, 12, 72], [10, 30, 92], size=(300, 1, 3))
    pts = starts + np.cumsum(rng.normal(scale=1.5, size=(300, 6, 3)), axis=1)
    radii = np.full((300, 5), 0.6)
    a, b = world.near(pts, radii)
    c, d = fresh.near(pts, radii)
    np.testing.assert_array_equal(a, c)
    np.testing.assert_allclose(b, d)
