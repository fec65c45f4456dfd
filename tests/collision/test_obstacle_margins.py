"""Per-structure margins (`Obstacle.margin_mm`) against closed forms: a capsule collides with an
obstacle exactly when its surface comes within the robot's margin plus the obstacle's; the distance
grid stays a lower bound of the margin-reduced distance; and the per-structure clearances along a
path (minimum, state, arc length, points) match the geometry of a straight and a circular backbone."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from ctrplan.collision.broadphase import DistanceGrid
from ctrplan.collision.checker import RobotCollisionChecker
from ctrplan.collision.world import CollisionWorld
from ctrplan.scene.geometry import make_pose
from ctrplan.scene.objects import Obstacle


@pytest.fixture(autouse=True)
def _private_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("CTRPLAN_CACHE_DIR", str(tmp_path / "cache"))


def sphere(c, r: float, margin: float = 0.0, name: str = "ball") -> Obstacle:
    return Obstacle(name, "sphere", pose=make_pose(np.eye(3), np.asarray(c, float)), radius=r,
                    margin_mm=margin)


def box(c, size, margin: float = 0.0, name: str = "block") -> Obstacle:
    return Obstacle(name, "box", pose=make_pose(np.eye(3), np.asarray(c, float)), size=tuple(size),
                    margin_mm=margin)


def mesh_box(c, size, margin: float = 0.0, name: str = "wall") -> Obstacle:
    m = trimesh.creation.box(extents=size)
    m.apply_translation(c)
    return Obstacle(name, "mesh", vertices=np.asarray(m.vertices, float),
                    faces=np.asarray(m.faces, np.int64), margin_mm=margin)


def straight(n: int = 21, length: float = 100.0) -> np.ndarray:
    p = np.zeros((n, 3))
    p[:, 2] = np.linspace(0.0, length, n)
    return p


TUBE_MM = 1.0      # robot radius
ROBOT_MARGIN = 0.2  # the scene's margin_mm (robot side)


def obstacle_at(kind: str, gap: float, margin: float) -> Obstacle:
    """An obstacle whose surface is ``gap`` mm from the straight robot's surface (axis = z, radius
    `TUBE_MM`), beside its middle."""
    if kind == "sphere":
        return sphere([TUBE_MM + gap + 3.0, 0, 50], 3.0, margin)
    if kind == "box":
        return box([TUBE_MM + gap + 2.0, 0, 50], [4.0, 6.0, 6.0], margin)
    return mesh_box([TUBE_MM + gap + 2.0, 0, 50], [4.0, 6.0, 6.0], margin)


@pytest.mark.parametrize("broad", [True, False])
@pytest.mark.parametrize("kind", ["sphere", "box", "mesh"])
@pytest.mark.parametrize("margin", [0.0, 1.5, 6.0])
def test_collides_exactly_within_robot_plus_structure_margin(kind, margin, broad):
    """Free iff gap > robot margin + structure margin, on both sides of that threshold (also for a
    margin larger than the broadphase band)."""
    need = ROBOT_MARGIN + margin
    for gap, free in ((need + 0.02, True), (need - 0.02, False)):
        world = CollisionWorld([obstacle_at(kind, gap, margin)], broadphase=broad)
        ch = RobotCollisionChecker(world, np.eye(4), 21, ROBOT_MARGIN)
        p, r = straight(), np.full(21, TUBE_MM)
        assert ch.is_free(p, r) == free, (kind, margin, gap)
        assert bool(ch.free_batch(p[None], r[None])[0]) == free
        assert (ch.contacts(p, r) == []) == free
        # distances stay raw: surface to surface, no margin
        assert math.isclose(ch.clearance(p, r).distance_mm, gap, abs_tol=1e-6)


def test_margin_belongs_to_its_structure_only():
    """Two obstacles at the same 1 mm gap on either side: only the one with a 2 mm margin counts."""
    plain = sphere([-(TUBE_MM + 1.0 + 3.0), 0, 50], 3.0, 0.0, "mucosa")
    guarded = sphere([TUBE_MM + 1.0 + 3.0, 0, 50], 3.0, 2.0, "carotid")
    p, r = straight(), np.full(21, TUBE_MM)
    assert RobotCollisionChecker(CollisionWorld([plain]), np.eye(4), 21, ROBOT_MARGIN).is_free(p, r)
    ch = RobotCollisionChecker(CollisionWorld([plain, guarded]), np.eye(4), 21, ROBOT_MARGIN)
    assert not ch.is_free(p, r)
    assert {name for _, name in ch.contacts(p, r)} == {"carotid"}


def segment_point_distance(a: np.ndarray, b: np.ndarray, x: np.ndarray) -> np.ndarray:
    d = b - a
    t = np.clip((x - a) @ d / (d @ d), 0.0, 1.0)
    return np.linalg.norm(a + t[:, None] * d - x, axis=1)


def test_grid_bounds_the_margin_reduced_distance_from_below():
    """For two spheres with margins 0.5 and 3 mm: the grid's bound of a point x is at most
    min_j(|x - c_j| - R_j - m_j) (closed form), and within a cell diagonal of it where that is in
    (0, band)."""
    obstacles = [sphere([0, 0, 0], 2.0, 0.5, "a"), sphere([9, 0, 0], 1.0, 3.0, "b")]
    grid = DistanceGrid.build(obstacles)
    rng = np.random.default_rng(4)
    x = rng.uniform([-10, -8, -8], [18, 8, 8], size=(3000, 3))
    exact = np.min([np.linalg.norm(x - o.pose[:3, 3], axis=1) - o.radius - o.margin_mm
                    for o in obstacles], axis=0)
    bound = grid.segment_lower_bounds(np.stack([x, x], axis=1))[:, 0]
    assert (bound <= np.maximum(exact, 0.0) + 1e-9).all()
    assert (bound[exact <= 0] <= 0).all()
    inside = (exact > 0) & (exact < grid.band_mm)
    slack = math.sqrt(3) * grid.cell_mm + grid.step_mm + 1e-9
    assert (bound[inside] >= exact[inside] - slack).all()
    assert inside.sum() > 500


def arc(n: int, radius: float, angle: float) -> np.ndarray:
    """n points of a circular arc of ``radius`` in the x-z plane from the origin, tangent z at s = 0,
    bending towards +x (centre (radius, 0, 0)), over ``angle`` rad."""
    th = np.linspace(0.0, angle, n)
    return np.column_stack([radius * (1 - np.cos(th)), np.zeros(n), radius * np.sin(th)])


def test_structure_clearances_on_a_circular_backbone():
    """A sphere outside a circular backbone on the radial line through its 12th point: the distance
    is |c - O| - R_arc - R - tube (any point of the chords lies inside the circle, no nearer), at that
    point's arc length and on the state the sphere is placed for; a far box is reported too, and
    flagged only when closer than the robot's plus its own margin."""
    n, rc, angle = 31, 60.0, 1.2
    th = np.linspace(0.0, angle, n)
    k0 = 12
    gap = 1.3
    c = np.array([rc, 0.0, 0.0]) + (rc + TUBE_MM + gap + 2.0) * np.array([-np.cos(th[k0]), 0, np.sin(th[k0])])
    ball = sphere(c, 2.0, 1.0, "carotid")        # 1.3 mm away, needs 0.2 + 1.0: not flagged
    wall = box([-30.0, 0.0, 30.0], [4.0, 40.0, 40.0], 0.0, "wall")  # its face x = -28 is far
    base = arc(n, rc, angle)
    shift = np.array([0.0, 0.0, 5.0])
    states = np.stack([base - shift, base, base - 2 * shift])   # state 1 is the nearest
    radius = np.full((3, n), TUBE_MM)
    s = np.tile(rc * th, (3, 1))
    ch = RobotCollisionChecker(CollisionWorld([ball, wall]), np.eye(4), n, ROBOT_MARGIN)
    got = {g.name: g for g in ch.structure_clearances(states, radius, s)}
    g = got["carotid"]
    assert math.isclose(g.distance_mm, gap, abs_tol=1e-6)
    assert g.state == 1
    assert math.isclose(g.arc_length_mm, rc * th[k0], abs_tol=1e-6)
    outward = (base[k0] - np.array([rc, 0, 0])) / rc   # from the arc's centre through the point
    assert np.allclose(g.robot_point, base[k0] + TUBE_MM * outward, atol=1e-6)
    assert np.allclose(g.obstacle_point, base[k0] + (TUBE_MM + gap) * outward, atol=1e-6)
    assert g.required_mm == pytest.approx(1.2) and not g.below_margin
    # the far wall: brute force over its face x = -28 (y = 0 by symmetry), every segment of every state
    face = np.column_stack([np.full(2001, -28.0), np.zeros(2001), np.linspace(10, 50, 2001)])
    axis_dist = min(segment_point_distance(states[i, j], states[i, j + 1], face).min()
                    for i in range(3) for j in range(n - 1))
    w = got["wall"]
    assert math.isclose(w.distance_mm, axis_dist - TUBE_MM, abs_tol=1e-3)
    assert w.distance_mm > 20 and not w.below_margin
    # a larger margin on the sphere flags it, and the checker then finds the path in collision
    ball2 = sphere(c, 2.0, 1.5, "carotid")
    ch2 = RobotCollisionChecker(CollisionWorld([ball2, wall]), np.eye(4), n, ROBOT_MARGIN)
    assert ch2.structure_clearances(states, radius, s)[0].below_margin
    assert not ch2.is_free(states[1], radius[1]) and ch2.is_free(states[0] - 3 * shift, radius[0])


def test_structure_in_contact_reports_zero_at_the_touching_capsule():
    p = straight()
    ball = sphere([TUBE_MM + 1.0, 0, 72.5], 1.5, 0.0)   # overlaps the robot around z = 72.5
    ch = RobotCollisionChecker(CollisionWorld([ball]), np.eye(4), 21, 0.0)
    (g,) = ch.structure_clearances(p[None], np.full((1, 21), TUBE_MM), p[None, :, 2])
    assert g.distance_mm == 0.0 and g.below_margin
    assert 65.0 <= g.arc_length_mm <= 80.0
