"""Tissue that moves: the sweep index and the roadmap repair on a small roadmap of open.yaml, checked
against flags computed from scratch (every node and edge of the roadmap checked in the moved scene)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from ctrplan.base.errors import InputError
from ctrplan.collision.world import CollisionWorld
from ctrplan.planning.roadmap._adapter import checker_with_world, edge_states
from ctrplan.planning.roadmap.query import RoadmapPlanner
from ctrplan.planning.roadmap.repair import BLOCKED, OK, SUSPECT, LiveRoadmap
from ctrplan.planning.roadmap.sweep import CellGrid, SweepIndex
from ctrplan.scene.objects import TargetRegion
from tests.roadmaps import small_roadmap


@pytest.fixture(scope="module")
def indexed(tmp_path_factory):
    """A 400-node roadmap of open.yaml and its sweep index (saved and read back)."""
    folder = tmp_path_factory.mktemp("roadmap")
    ctx, _, rm = small_roadmap(folder, 1, 400)
    return ctx, rm, SweepIndex.load(folder, rm)  # the build indexed it


def _flags_from_scratch(live: LiveRoadmap) -> tuple[np.ndarray, np.ndarray]:
    """Every node and every edge's interior of the built roadmap checked in the scene as it is now
    (a collision world built anew)."""
    ctx, rm = live.ctx, live.built
    checker = checker_with_world(ctx, CollisionWorld(ctx.scene.obstacles))
    nodes = checker.validate(rm.q)[0]
    states, edge = edge_states(ctx, rm.q[rm.edges[:, 0]], rm.q[rm.edges[:, 1]])
    edges = np.ones(len(rm.edges), dtype=bool)
    edges[np.unique(edge[~checker.validate(states)[0]])] = False
    return nodes, edges


def _ball_onto_the_roadmap(ctx, rm) -> np.ndarray:
    """A shift (mm) that puts the ball's centre 4 mm beside the tip of a connected node near it."""
    ball = next(o for o in ctx.scene.obstacles if o.name == "ball")
    centre = ball.pose[:3, 3]
    tips = rm.tips[rm.connected]
    near = tips[np.argsort(np.linalg.norm(tips - centre, axis=1))[:20]]
    aim = near[np.argmax(np.linalg.norm(near - centre, axis=1) > 8.0)]
    return aim + 4.0 * (centre - aim) / np.linalg.norm(centre - aim) - centre


def test_the_index_lists_every_cell_a_sample_lies_in(indexed):
    """The index read back has the roadmap's counts; a node's own tip cell lists it."""
    ctx, rm, index = indexed
    assert (index.nodes, index.edges) == (rm.n_nodes, len(rm.edges))
    grid = CellGrid.for_scene(ctx.scene)
    for node in (0, rm.n_nodes // 2, rm.n_nodes - 1):
        assert node in index.nodes_in(grid.ids(rm.tips[node])[None])
    assert 0 < index.reach_mm < 3.0


def test_the_build_records_how_close_it_came_to_each_focus_region(tmp_path):
    """Two focus regions (the scene's target and a far sphere): the record's reach of each is the
    distance of the nearest connected tip (computed here) and the count of tips inside."""
    far = TargetRegion.sphere([60.0, 40.0, 150.0], 2.0)
    ctx, _, rm = small_roadmap(tmp_path, 3, 150, focus=[("target", None), ("far", far)])
    assert list(rm.meta["settings"]["focus"]) == ["target", "far"]
    tips = rm.tips[rm.connected]
    for name, region in (("target", ctx.scene.target), ("far", far)):
        d = np.maximum(np.linalg.norm(tips - region.center, axis=1) - region.semi_axes[0], 0.0)
        assert rm.meta["reach"][name]["closest_mm"] == pytest.approx(d.min(), abs=1e-3)
        assert rm.meta["reach"][name]["inside"] == int((d <= 0).sum())


def test_repaired_states_equal_states_from_scratch_through_moves_and_back(indexed):
    """The ball moves onto the roadmap, then a little further, the block moves too, then both go
    home. After every move: each element not SUSPECT has the state computed from scratch, a move
    marks only a part of the roadmap SUSPECT, and once every SUSPECT one is checked all states are
    those from scratch. At home all are OK again, and the tree is the built one."""
    ctx, rm, index = indexed
    live = LiveRoadmap(ctx, rm, index)
    shift = _ball_onto_the_roadmap(ctx, rm)
    moves = [("ball", shift), ("ball", shift + [1.5, -2.0, 1.0]), ("block", np.array([3.0, 4.0, -2.0])),
             ("ball", np.zeros(3)), ("block", np.zeros(3))]
    blocked_any = False
    for k, (name, t) in enumerate(moves):
        rep = live.move(name, t)
        nodes, edges = _flags_from_scratch(live)
        known = live.node_state != SUSPECT
        np.testing.assert_array_equal(live.node_state[known] == OK, nodes[known])
        known = live.edge_state != SUSPECT
        np.testing.assert_array_equal(live.edge_state[known] == OK, edges[known])
        assert rep.suspect["nodes"] < rm.n_nodes
        if k % 2 == 0:  # resolve now and then: states from scratch
            live.resolve_all()
            np.testing.assert_array_equal(live.node_state == OK, nodes)
            np.testing.assert_array_equal(live.edge_state == OK, edges)
        blocked_any |= bool((live.node_state == BLOCKED).any() or (live.edge_state == BLOCKED).any())
    assert blocked_any
    live.resolve_all()
    assert (live.node_state == OK).all() and (live.edge_state == OK).all()
    np.testing.assert_allclose(live.roadmap.dist, rm.dist, rtol=1e-5, atol=1e-4)


def test_a_query_on_a_live_roadmap_checks_its_path_first(indexed):
    """With the ball moved onto the roadmap, an answer's path has no SUSPECT or BLOCKED element left
    on it and is valid in the moved scene (checked from scratch)."""
    ctx, rm, index = indexed
    live = LiveRoadmap(ctx, rm, index)
    shift = _ball_onto_the_roadmap(ctx, rm)
    live.move("ball", shift)
    ball = next(o for o in ctx.scene.obstacles if o.name == "ball").pose[:3, 3] + shift
    # a target at the tip of a node still reachable in the moved scene (from scratch) whose present
    # tree path has SUSPECT elements, the farthest such from the ball
    nodes_ok, edges_ok = _flags_from_scratch(live)
    a, b = rm.edges[:, 0], rm.edges[:, 1]
    use = edges_ok & nodes_ok[a] & nodes_ok[b]
    graph = coo_matrix((np.ones(use.sum()), (a[use], b[use])), shape=(rm.n_nodes, rm.n_nodes))
    reachable = np.isfinite(dijkstra(graph.tocsr(), directed=False, indices=0))
    nodes = [n for n in np.flatnonzero(reachable & rm.connected)
             if (live.node_state[live.tree_nodes(n)] == SUSPECT).any()]
    node = max(nodes, key=lambda n: np.linalg.norm(rm.tips[n] - ball))
    res = RoadmapPlanner(live.ctx, live.roadmap, live).answer(TargetRegion.sphere(rm.tips[node], 2.0))
    assert res.solved, res.message
    assert res.steps["lazy_s"] > 0
    assert res.validated.collision_free
    last = int(np.argmin(np.linalg.norm(rm.q - res.path[-1], axis=1)))  # a direct answer ends on a node
    assert np.allclose(rm.q[last], res.path[-1])
    path = live.tree_nodes(last)
    assert (live.node_state[path] == OK).all()
    assert (live.edge_state[live.edge_ids(path[:-1], path[1:])] == OK).all()


def test_an_unknown_structure_is_refused(indexed):
    ctx, rm, index = indexed
    with pytest.raises(InputError, match="no structure named 'bone'"):
        LiveRoadmap(ctx, rm, index).move("bone", np.zeros(3))


def test_a_stale_index_is_not_used(indexed, tmp_path):
    """An index made for another roadmap (other counts) reads as none."""
    ctx, rm, index = indexed
    index.save(tmp_path)
    fewer = replace(rm, edges=rm.edges[:-1], lengths=rm.lengths[:-1])
    assert SweepIndex.load(tmp_path, fewer) is None
    assert SweepIndex.load(tmp_path, rm) is not None
