"""Capsule-chain collision checks against analytic answers (FCL primitives and meshes)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from ctrplan.collision.capsules import CapsuleChain, segment_frames, segment_radii
from ctrplan.collision.checker import RobotCollisionChecker
from ctrplan.collision.world import CollisionWorld
from ctrplan.scene.geometry import frame_from_z, make_pose
from ctrplan.scene.objects import Obstacle


def straight(n: int = 11, length: float = 100.0) -> np.ndarray:
    p = np.zeros((n, 3))
    p[:, 2] = np.linspace(0.0, length, n)
    return p


def checker(obstacles, margin=0.0, n=11, base=None):
    return RobotCollisionChecker(CollisionWorld(obstacles), np.eye(4) if base is None else base, n, margin)


def sphere(c, r, name="ball"):
    return Obstacle(name, "sphere", pose=make_pose(np.eye(3), np.asarray(c, float)), radius=r)


def test_segment_frames_map_z_onto_segments():
    rng = np.random.default_rng(0)
    p = np.cumsum(rng.normal(size=(30, 3)), axis=0)
    p[5] = p[4] + np.array([0, 0, -2.0])  # antiparallel to z
    c, R, length = segment_frames(p)
    d = p[1:] - p[:-1]
    assert np.allclose(length, np.linalg.norm(d, axis=1))
    assert np.allclose(np.einsum("mij,j->mi", R, [0, 0, 1.0]), d / length[:, None])
    assert np.allclose(np.einsum("mji,mjk->mik", R, R), np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(R), 1.0)
    assert np.allclose(c, 0.5 * (p[1:] + p[:-1]))


def test_segment_radius_is_outermost_tube_plus_margin():
    r = np.array([0.75, 0.75, 0.45, 0.45, 0.25])
    assert np.allclose(segment_radii(r, 0.2), [0.95, 0.95, 0.65, 0.65])


@pytest.mark.parametrize("gap", [0.05, -0.05])
def test_capsule_vs_sphere_side(gap):
    # robot radius 1 along z, sphere radius 2 centred 3 + gap off the axis at mid height
    ch = checker([sphere([3.0 + gap, 0, 50], 2.0)])
    free = ch.is_free(straight(), np.full(11, 1.0))
    assert free == (gap > 0)
    if gap > 0:
        assert math.isclose(ch.clearance(straight(), np.full(11, 1.0)).distance_mm, gap, abs_tol=1e-6)


def test_capsule_end_cap_vs_sphere_beyond_tip():
    # sphere on the axis beyond the tip: distance = 10 - (radius of the cap) - sphere radius
    ch = checker([sphere([0, 0, 110.0], 4.0)])
    c = ch.clearance(straight(), np.full(11, 1.5))
    assert math.isclose(c.distance_mm, 10.0 - 1.5 - 4.0, abs_tol=1e-6)
    assert ch.is_free(straight(), np.full(11, 1.5))
    assert not ch.is_free(straight(), np.full(11, 6.1))  # 1.5 -> 6.1: the cap reaches the sphere


def test_margin_is_added_to_the_radius():
    ch0 = checker([sphere([3.3, 0, 50], 2.0)], margin=0.0)
    ch1 = checker([sphere([3.3, 0, 50], 2.0)], margin=0.4)
    assert ch0.is_free(straight(), np.full(11, 1.0))
    assert not ch1.is_free(straight(), np.full(11, 1.0))


def test_rotated_box():
    # a cube of side 10 turned 45 deg about z; its edge points at the robot
    box = Obstacle("box", "box", pose=make_pose(frame_from_z([0, 0, 1], [1, 1, 0]), np.array([12.0, 0, 50])),
                   size=(10.0, 10.0, 10.0))
    edge = 12.0 - 5.0 * math.sqrt(2.0)  # nearest edge at x = 4.93
    ch = checker([box])
    c = ch.clearance(straight(), np.full(11, 1.0))
    assert math.isclose(c.distance_mm, edge - 1.0, abs_tol=1e-5)
    assert ch.is_free(straight(), np.full(11, edge - 0.01))
    assert not ch.is_free(straight(), np.full(11, edge + 0.01))


def test_cylinder_and_capsule_obstacles():
    # horizontal cylinder (axis x) crossing above the tip; capsule obstacle parallel to the robot
    cyl = Obstacle("cyl", "cylinder", pose=make_pose(frame_from_z([1, 0, 0]), np.array([0, 0, 106.0])),
                   radius=3.0, length=40.0)
    cap = Obstacle("cap", "capsule", pose=make_pose(np.eye(3), np.array([0, 8.0, 40.0])), radius=2.0,
                   length=20.0)
    ch = checker([cyl, cap])
    c = ch.clearance(straight(), np.full(11, 1.0))
    assert math.isclose(c.distance_mm, 2.0, abs_tol=1e-5)  # cylinder: 106 - 3 - (100 + 1)
    assert c.obstacle == "cyl"
    assert ch.is_free(straight(), np.full(11, 2.9))
    assert not ch.is_free(straight(), np.full(11, 3.1))  # cylinder: 106 - 3 - 103.1 < 0
    assert {n for _, n in ch.contacts(straight(), np.full(11, 5.5))} == {"cyl"}  # cap: 8 - 2 - 5.5 > 0
    assert {n for _, n in ch.contacts(straight(), np.full(11, 6.5))} == {"cyl", "cap"}


def test_mesh_obstacle_and_base_pose():
    # an open tube (no caps) of radius 5 around the z axis from z = 20 to 80: inside is free
    tube = trimesh.creation.cylinder(radius=5.0, height=60.0, sections=64)
    tube.apply_translation([0, 0, 50.0])
    keep = np.abs(tube.face_normals[:, 2]) < 0.5  # drop the end caps
    wall = Obstacle("wall", "mesh", vertices=np.asarray(tube.vertices), faces=np.asarray(tube.faces)[keep])
    ch = checker([wall])
    assert ch.is_free(straight(), np.full(11, 4.5))
    assert not ch.is_free(straight(), np.full(11, 5.1))
    r_in = 5.0 * math.cos(math.pi / 64)  # the polygon's inscribed radius
    assert math.isclose(ch.clearance(straight(), np.full(11, 1.0)).distance_mm, r_in - 1.0, abs_tol=1e-3)
    # the same robot moved sideways by the base pose hits the wall
    shifted = checker([wall], base=make_pose(np.eye(3), np.array([3.0, 0, 0])))
    assert not shifted.is_free(straight(), np.full(11, 2.5))
    assert shifted.is_free(straight(), np.full(11, 1.5))


def test_chain_is_updated_in_place():
    ch = checker([sphere([0, 20.0, 50], 5.0)])
    chain_objects = list(ch.chain._objects)
    bent = straight()
    bent[:, 1] = np.linspace(0, 30.0, 11)  # passes through the sphere
    results = [ch.is_free(p, np.full(11, 0.5)) for p in (straight(), bent, straight(), bent)]
    assert results == [True, False, True, False]
    assert ch.chain._objects == chain_objects  # no new FCL objects


def test_batch_equals_single_and_nan_rows_are_not_free():
    rng = np.random.default_rng(1)
    obs = [sphere(rng.uniform([-20, -20, 20], [20, 20, 100]), 6.0, f"s{i}") for i in range(6)]
    ch = checker(obs, margin=0.1)
    P = np.stack([straight() + rng.normal(scale=8.0, size=(1, 3)) * np.linspace(0, 1, 11)[:, None]
                  for _ in range(40)])
    R = np.full((40, 11), 0.75)
    P[7, 3] = np.nan
    batch = ch.free_batch(P, R)
    single = np.array([ch.is_free(P[i], R[i]) for i in range(40)])
    assert np.array_equal(batch, single)
    assert not batch[7]
    assert 0 < batch.sum() < 40


def test_distance_pruning_matches_brute_force():
    import fcl

    rng = np.random.default_rng(2)
    obs = [sphere(rng.uniform([-40, -40, 0], [40, 40, 120]), rng.uniform(2, 6), f"s{i}") for i in range(12)]
    world = CollisionWorld(obs)
    chain = CapsuleChain(10)
    p = straight()
    chain.set(p, np.full(10, 1.0))
    best = chain.distance(world).distance_mm
    brute = np.inf
    req = fcl.DistanceRequest()
    for i in range(10):
        for w in world._objects:
            brute = min(brute, fcl.distance(chain._object(i), w, req, fcl.DistanceResult()))
    assert math.isclose(best, max(brute, 0.0), rel_tol=1e-9, abs_tol=1e-9)
