"""The distance-grid broadphase against exact geometry and against FCL itself: it never clears a
capsule FCL says collides (meshes, a zero-thickness plate, primitives), its bounds are tight, it is
cached on disk, and the planner's validity answers are the same with and without it."""

from __future__ import annotations

import math
from dataclasses import replace

import fcl
import numpy as np
import pytest
import trimesh

from ctrplan.collision import broadphase
from ctrplan.collision.broadphase import DistanceGrid, capsule_contact, geometry_key, grid_for
from ctrplan.collision.checker import RobotCollisionChecker
from ctrplan.collision.world import CollisionWorld
from ctrplan.planning.model import PlanningModel
from ctrplan.planning.space import BoxSpace
from ctrplan.planning.validity import ConfigurationChecker
from ctrplan.scene.geometry import make_pose
from ctrplan.scene.loader import load_scene
from ctrplan.scene.objects import Obstacle
from tests.paths import SCENES


@pytest.fixture(autouse=True)
def _private_cache(tmp_path, monkeypatch):
    """Grids go to a per-test directory, never to the user's cache."""
    monkeypatch.setenv("CTRPLAN_CACHE_DIR", str(tmp_path / "cache"))


def mesh_obstacle(mesh: trimesh.Trimesh, name: str = "mesh") -> Obstacle:
    return Obstacle(name, "mesh", vertices=np.asarray(mesh.vertices, float),
                    faces=np.asarray(mesh.faces, np.int64))


def plate() -> Obstacle:
    """A zero-thickness square plate (two triangles) in the plane z = 5, 20 x 20 mm."""
    v = np.array([[-10, -10, 5], [10, -10, 5], [10, 10, 5], [-10, 10, 5]], float)
    return Obstacle("plate", "mesh", vertices=v, faces=np.array([[0, 1, 2], [0, 2, 3]]))


def skull_parts() -> list[Obstacle]:
    """Three meshes of the skull-base anatomy: a thin wall, the sella and a carotid artery."""
    scene = load_scene(SCENES / "skullbase.yaml")
    keep = {"nasal_septum", "sella_turcica", "right_internal_carotid"}
    return [o for o in scene.obstacles if o.name in keep]


def primitives() -> list[Obstacle]:
    rot = trimesh.transformations.rotation_matrix(0.7, [1, 1, 0])[:3, :3]
    return [
        Obstacle("ball", "sphere", pose=make_pose(np.eye(3), np.array([0.0, 0, 0])), radius=2.0),
        Obstacle("wall", "box", pose=make_pose(rot, np.array([8.0, 0, 0])), size=(4.0, 6.0, 0.05)),
        Obstacle("rod", "cylinder", pose=make_pose(rot, np.array([0.0, 8, 0])), radius=1.0, length=6.0),
        Obstacle("pin", "capsule", pose=make_pose(np.eye(3), np.array([0.0, -8, 0])), radius=0.5,
                 length=4.0),
    ]


def exact_distance(obstacles: list[Obstacle], x: np.ndarray) -> np.ndarray:
    """Distance (mm) from points x (n, 3) to the obstacles (mesh surfaces, primitive solids), by FCL:
    a tiny sphere at each point against each mesh's BVH; analytic for primitives."""
    d = np.full(len(x), np.inf)
    probe = fcl.CollisionObject(fcl.Sphere(1e-9), fcl.Transform())
    request = fcl.DistanceRequest()
    for o in obstacles:
        if o.kind != "mesh":
            d = np.minimum(d, broadphase._solid_distance(o, x))
            continue
        bvh = fcl.BVHModel()
        bvh.beginModel(len(o.vertices), len(o.faces))
        bvh.addSubModel(np.asarray(o.vertices, float), np.asarray(o.faces, np.int64))
        bvh.endModel()
        mesh = fcl.CollisionObject(bvh, fcl.Transform())
        for i, xi in enumerate(x):
            probe.setTranslation(xi)
            d[i] = min(d[i], max(fcl.distance(probe, mesh, request, fcl.DistanceResult()), 0.0) + 1e-9)
    return d


def random_capsules(obstacles: list[Obstacle], n: int, rng: np.random.Generator):
    """Capsules (a, b, r) near the obstacles' surfaces (offsets -1..3 mm along the normal, many
    within a fraction of a mm of touching) and some far away."""
    mesh = trimesh.util.concatenate([o.to_trimesh() for o in obstacles])
    pts, face = trimesh.sample.sample_surface(mesh, n, seed=int(rng.integers(1 << 31)))
    centre = pts + mesh.face_normals[face] * rng.uniform(-1.0, 3.0, size=(n, 1))
    far = rng.uniform(size=n) < 0.15
    centre[far] += rng.normal(scale=15.0, size=(far.sum(), 3))
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    half = rng.uniform(0.0, 4.0, size=(n, 1))
    return centre - half * u, centre + half * u, rng.uniform(0.2, 1.5, size=n)


def fcl_collides(world: CollisionWorld, a: np.ndarray, b: np.ndarray, r: float) -> bool:
    chain = RobotCollisionChecker(world, np.eye(4), 2).chain
    chain.set(np.stack([a, b]), np.array([r]))
    return chain.collides(world)


@pytest.mark.parametrize("kind", ["skull", "plate", "primitives"])
def test_broadphase_never_clears_a_capsule_fcl_says_collides(kind):
    rng = np.random.default_rng(3)
    obstacles = {"skull": skull_parts, "plate": lambda: [plate()], "primitives": primitives}[kind]()
    world = CollisionWorld(obstacles)
    a, b, r = random_capsules(obstacles, 600, rng)
    near, _ = world.near(np.stack([a, b], axis=1), r[:, None])
    hits = np.array([fcl_collides(world, a[i], b[i], r[i]) for i in range(len(r))])
    assert 50 < hits.sum() < len(r) - 50  # both outcomes are well represented
    assert near[hits, 0].all(), "a colliding capsule was cleared"
    # and the broadphase is useful: most free capsules are cleared
    assert (~near[~hits, 0]).mean() > 0.5


def test_capsule_through_a_zero_thickness_plate_is_never_cleared():
    world = CollisionWorld([plate()])
    rng = np.random.default_rng(0)
    xy = rng.uniform(-8.0, 8.0, size=(200, 2))
    a = np.column_stack([xy, 5.0 - rng.uniform(0.0, 2.0, 200)])
    b = np.column_stack([xy + rng.uniform(-1.0, 1.0, size=(200, 2)), 5.0 + rng.uniform(0.0, 2.0, 200)])
    near, lower = world.near(np.stack([a, b], axis=1), np.full((200, 1), 0.05))
    assert near.all() and (lower <= 0.0).all()
    assert all(fcl_collides(world, a[i], b[i], 0.05) for i in range(200))


@pytest.mark.parametrize("kind", ["skull", "primitives"])
def test_point_bounds_are_lower_bounds_and_tight(kind):
    """For a point x: d(x) >= bound >= min(d(x), band) - sqrt(3) cell - one quantisation step."""
    obstacles = skull_parts() if kind == "skull" else primitives()
    grid = DistanceGrid.build(obstacles)
    rng = np.random.default_rng(1)
    lo = np.min([broadphase.obstacle_bounds(o)[0] for o in obstacles], axis=0) - 6
    hi = np.max([broadphase.obstacle_bounds(o)[1] for o in obstacles], axis=0) + 6
    mesh = trimesh.util.concatenate([o.to_trimesh() for o in obstacles])
    near_surface = mesh.sample(600, seed=2) + rng.normal(scale=1.5, size=(600, 3))
    x = np.concatenate([rng.uniform(lo, hi, size=(400, 3)), near_surface])
    bound = grid.segment_lower_bounds(np.stack([x, x], axis=1))[:, 0]
    d = exact_distance(obstacles, x)
    assert (bound <= d + 1e-9).all()
    slack = math.sqrt(3) * grid.cell_mm + grid.step_mm + 1e-9
    assert (bound >= np.minimum(d, grid.band_mm) - slack).all()
    assert (d < 1.0).sum() > 150  # many points near the geometry


@pytest.mark.parametrize("kind", ["skull", "primitives"])
def test_point_upper_bounds_are_upper_bounds_and_tight(kind):
    """Where the grid has a value within its band: d(x) <= bound <= d(x) + sqrt(3) cell + one step."""
    obstacles = skull_parts() if kind == "skull" else primitives()
    grid = DistanceGrid.build(obstacles)
    mesh = trimesh.util.concatenate([o.to_trimesh() for o in obstacles])
    rng = np.random.default_rng(8)
    x = mesh.sample(800, seed=3) + rng.normal(scale=1.0, size=(800, 3))
    upper = np.array([broadphase._point_upper_bound(*xi, grid.lo, grid.cell_mm, grid.step_mm, grid.values)
                      for xi in x])
    d = exact_distance(obstacles, x)
    known = np.isfinite(upper)
    assert known.mean() > 0.9
    assert (upper[known] >= d[known] - 1e-9).all()
    assert (upper[known] <= d[known] + math.sqrt(3) * grid.cell_mm + grid.step_mm + 1e-9).all()


@pytest.mark.parametrize("kind", ["skull", "plate", "primitives", "margins"])
def test_grid_contacts_are_fcl_contacts(kind):
    """`capsule_contact` (the grid's upper bound) only reports contacts FCL reports too -- obstacle
    margins included -- and finds most of them."""
    rng = np.random.default_rng(9)
    if kind == "margins":
        obstacles = [replace(o, margin_mm=m) for o, m in zip(skull_parts(), (0.3, 0.0, 1.0), strict=True)]
    else:
        obstacles = {"skull": skull_parts, "plate": lambda: [plate()], "primitives": primitives}[kind]()
    world = CollisionWorld(obstacles)
    grid = world.grid
    a, b, r = random_capsules(obstacles, 600, rng)
    hits = np.array([fcl_collides(world, a[i], b[i], r[i]) for i in range(len(r))])
    sure = np.array([capsule_contact(a[i], b[i], r[i], grid.lo, grid.cell_mm, grid.step_mm, grid.values,
                                     grid.spacing_mm) for i in range(len(r))])
    assert 50 < hits.sum() < len(r) - 50
    assert hits[sure].all(), "the grid reported a contact FCL does not"
    assert sure[hits].mean() > 0.5


def test_non_finite_backbones_are_never_cleared():
    world = CollisionWorld([plate()])
    p = np.zeros((1, 3, 3))
    p[0, :, 2] = [20.0, 21.0, np.nan]
    near, lower = world.near(p, np.full((1, 2), 0.1))
    assert not near[0, 0] and near[0, 1] and lower[0, 1] == -np.inf


def test_grid_is_cached_on_disk_by_geometry(tmp_path, monkeypatch):
    monkeypatch.setattr(broadphase, "SAVE_AFTER_S", 0.0)
    obstacles = skull_parts()
    grid = grid_for(obstacles)
    files = list((tmp_path / "cache" / "broadphase").glob("*.npz"))
    assert [f.stem for f in files] == [geometry_key(obstacles, broadphase.CELL_MM, broadphase.BAND_MM)]
    again = grid_for(obstacles)
    assert again is not grid and np.array_equal(again.values, grid.values)
    assert np.array_equal(again.lo, grid.lo) and again.cell_mm == grid.cell_mm
    moved = [mesh_obstacle(obstacles[0].to_trimesh().apply_translation([0, 0, 0.01]), "septum")]
    assert geometry_key(moved, 0.5, 4.0) != geometry_key(obstacles[:1], 0.5, 4.0)
    # a damaged file is rebuilt, not trusted
    files[0].write_bytes(b"not a grid")
    rebuilt = grid_for(obstacles)
    assert np.array_equal(rebuilt.values, grid.values)


def test_planner_validity_is_identical_with_and_without_broadphase(cosserat):
    scene = load_scene(SCENES / "skullbase.yaml")
    space = BoxSpace.for_scene(scene)
    rng = np.random.default_rng(5)
    # states around the start (in the nose: many near misses) and across the whole box
    y = space.to_coords(np.repeat(scene.start[None], 150, axis=0)) + rng.normal(scale=6.0, size=(150, 6))
    q = np.concatenate([space.to_joints(space.clip(y)), space.sample(50, rng)])
    with_bp = ConfigurationChecker(PlanningModel.of(scene, cosserat, world=CollisionWorld.from_scene(scene)))
    without = ConfigurationChecker(PlanningModel.of(scene, cosserat,
                                                    world=CollisionWorld.from_scene(scene, broadphase=False)))
    assert with_bp.world.grid is not None and without.world.grid is None
    valid = with_bp.check(q)
    assert np.array_equal(valid, without.check(q))
    assert 20 < valid.sum() < len(q) - 20
    good = q[valid]
    pairs = [(good[i], good[j]) for i, j in rng.integers(len(good), size=(30, 2)) if i != j]
    res = scene.settings.resolution_mm
    assert [with_bp.check_motion(a, b, res) for a, b in pairs] == \
        [without.check_motion(a, b, res) for a, b in pairs]


def test_fcl_contact_for_every_state_the_broadphase_cannot_clear(cosserat):
    """The broadphase only clears; every collision verdict still comes from FCL: a state FCL
    reports in contact stays in contact, whatever the grid says."""
    scene = load_scene(SCENES / "skullbase.yaml")
    world = CollisionWorld.from_scene(scene)
    rc = RobotCollisionChecker(world, scene.base_pose, scene.settings.points, scene.settings.margin_mm)
    space = BoxSpace.for_scene(scene)
    q = space.sample(40, np.random.default_rng(7))
    bb = cosserat.forward(q, points=scene.settings.points, check=False)
    free = rc.free_batch(bb.positions_mm, bb.radius_mm)
    for i in range(len(q)):
        assert free[i] == (not rc.contacts(bb.positions_mm[i], bb.radius_mm[i]))


def test_compiled_capsule_frames_match_numpy_frames():
    from ctrplan.collision.capsules import _frames_and_boxes, capsule_frames

    rng = np.random.default_rng(4)
    a = rng.normal(size=(50, 3)) * 10
    b = a + rng.normal(size=(50, 3))
    b[3] = a[3] + [0.0, 0.0, -2.0]  # antiparallel to z
    b[4] = a[4]  # zero length
    r = rng.uniform(0.1, 1.0, 50)
    lo_o, hi_o = np.array([[-5.0, -5, -5]]), np.array([[5.0, 5, 5]])
    c, R, length, lo, hi, pairs = _frames_and_boxes(a, b, r, lo_o, hi_o)
    c2, R2, length2 = capsule_frames(a, b)
    assert np.allclose(c, c2) and np.allclose(R, R2) and np.allclose(length, length2)
    assert np.allclose(lo, np.minimum(a, b) - r[:, None]) and np.allclose(hi, np.maximum(a, b) + r[:, None])
    overlap = np.all((lo <= hi_o + 1e-6) & (hi >= lo_o - 1e-6), axis=1)
    assert pairs[:, 0].tolist() == np.flatnonzero(overlap).tolist() and 0 < len(pairs) < 50


def test_degenerate_triangles_and_coarsened_grids_stay_conservative(monkeypatch):
    """A zero-area triangle (a segment) still bounds the distance; a grid too large for
    `MAX_CELLS` gets coarser cells and stays a lower bound."""
    v = np.array([[0.0, 0, 0], [10.0, 0, 0], [5.0, 0, 0], [0.0, 40, 0]])
    sliver = Obstacle("sliver", "mesh", vertices=v[:3], faces=np.array([[0, 1, 2]]))
    far = Obstacle("far", "sphere", pose=make_pose(np.eye(3), np.array([0.0, 40, 0])), radius=1.0)
    monkeypatch.setattr(broadphase, "MAX_CELLS", 20_000)  # the 0.5 mm grid would have ~95,000
    grid = DistanceGrid.build([sliver, far])
    assert grid.cell_mm > broadphase.CELL_MM and grid.values.size <= broadphase.MAX_CELLS
    rng = np.random.default_rng(6)
    x = np.concatenate([rng.uniform([-3, -3, -3], [13, 3, 3], size=(500, 3)),
                        rng.uniform([-3, 37, -3], [3, 43, 3], size=(200, 3))])
    t = np.clip(x[:, 0] / 10.0, 0.0, 1.0)
    to_segment = np.linalg.norm(x - np.column_stack([10.0 * t, 0 * t, 0 * t]), axis=1)
    d = np.minimum(to_segment, broadphase._solid_distance(far, x))
    bound = grid.segment_lower_bounds(np.stack([x, x], axis=1))[:, 0]
    assert (bound <= d + 1e-9).all()
    assert (bound >= np.minimum(d, grid.band_mm) - math.sqrt(3) * grid.cell_mm - grid.step_mm).all()
