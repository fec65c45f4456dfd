"""Roadmaps: a small build on open.yaml, queries checked apart from ctrplan, continuation, refusals."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ctrplan.base.errors import InputError
from ctrplan.base.parallel import InlinePool
from ctrplan.cli.app import main
from ctrplan.kinematics import CosseratBackend
from ctrplan.planning import BoxSpace
from ctrplan.planning.roadmap.build import build
from ctrplan.planning.roadmap.query import RoadmapPlanner
from ctrplan.planning.roadmap.store import fingerprints, load_roadmap
from ctrplan.scene.loader import load_scene
from ctrplan.scene.objects import TargetRegion
from tests.independent.cosserat import Tubes, solve
from tests.independent.geometry import axis_angle, box_gap, sphere_gap
from tests.paths import SCENES
from tests.roadmaps import small_roadmap

OPEN = SCENES / "open.yaml"
FIRST_NODES = 600


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """A roadmap of open.yaml grown to `FIRST_NODES` nodes in this process (a budget in work)."""
    folder = tmp_path_factory.mktemp("roadmap")
    ctx, source, rm = small_roadmap(folder, 0, FIRST_NODES)
    return ctx, source, folder, rm


def assert_safe(path: np.ndarray, target: np.ndarray, tolerance_mm: float) -> None:
    """A joint path of open.yaml checked apart from the roadmap code: it starts at the scene's start,
    the independent integrator puts its last tip within the tolerance of the target, and the exact
    backbones of the path, densified to 0.5 mm, clear the ball and the block (distances computed
    here, without FCL's or the planner's collision code)."""
    scene = load_scene(OPEN)
    assert np.allclose(path[0], scene.start)
    tip = solve(path[-1][None], Tubes.paper())["tips_mm"][0, 0]
    assert np.linalg.norm(tip - target) <= tolerance_mm
    bb = CosseratBackend(scene.robot).forward(BoxSpace.for_robot(scene.robot).densify(path, 0.5), points=30)
    assert bb.converged.all()
    p, r = bb.positions_mm, bb.radius_mm
    assert sphere_gap(p, r, [43.0, -47.0, 150.0], 7.0) >= 0.0
    assert box_gap(p, r, [-25.0, -30.0, 150.0], [20.0, 20.0, 20.0], axis_angle([0, 0, 1], 30.0)) >= 0.0


def test_query_path_is_safe_by_an_independent_check(built):
    ctx, _, _, rm = built
    planner = RoadmapPlanner(ctx, rm)
    target = np.array([37.2, -27.2, 181.6])
    res = planner.answer(TargetRegion.sphere(target, 3.0))
    assert res.solved, res.message
    assert res.validated.ok and res.validated.collision_free
    assert_safe(res.path, target, 3.0)


def test_shortest_path_tree_distances_are_path_lengths(built):
    """dist[node] is the metric length of the tree path to it, and no stored edge offers a shorter
    way to either of its ends (the tree is a shortest-path tree)."""
    ctx, _, _, rm = built
    space = BoxSpace.for_scene(ctx.scene)
    nodes = np.flatnonzero(rm.connected)[1::37]
    for node in nodes:
        path = rm.path_to(int(node))
        assert rm.dist[node] == pytest.approx(space.distance(path[1:], path[:-1]).sum(), rel=1e-5, abs=1e-4)
    a, b = rm.edges[:, 0], rm.edges[:, 1]
    length = space.distance(rm.q[a], rm.q[b])
    np.testing.assert_allclose(rm.lengths, length, rtol=1e-5, atol=1e-4)
    assert np.all(rm.dist[a] <= rm.dist[b] + length + 1e-3)
    assert np.all(rm.dist[b] <= rm.dist[a] + length + 1e-3)


def test_an_interrupted_build_continues(built, tmp_path):
    """A second build in the same folder keeps every node and edge and adds to them."""
    ctx, source, folder, rm = built
    copy = tmp_path / "more"
    copy.mkdir()
    for f in folder.iterdir():
        (copy / f.name).write_bytes(f.read_bytes())
    more = build(ctx, source, copy, InlinePool(context=lambda: ctx), time_limit_s=600.0, seed=0, workers=1,
                 executor="test", max_nodes=FIRST_NODES + 200)
    assert len(more.meta["runs"]) == 2
    assert more.meta["runs"][1]["nodes_before"] == rm.n_nodes
    assert more.n_nodes >= FIRST_NODES + 200
    np.testing.assert_array_equal(more.q[:rm.n_nodes], rm.q)
    np.testing.assert_array_equal(more.edges[:len(rm.edges)], rm.edges)


def test_a_roadmap_of_another_scene_is_refused(built, capsys):
    ctx, _, folder, _ = built
    other = load_scene(SCENES / "pipe.yaml")
    with pytest.raises(InputError, match="another scene"):
        load_roadmap(folder, fingerprints(other, ctx.loaded))
    assert main(["plan", str(SCENES / "pipe.yaml"), "--roadmap", str(folder)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "roadmap built for another scene" in err[0]


@pytest.mark.parametrize("text, what", [("x,y,z\n1,2,3\n", "missing column 'tolerance_mm'"),
                                        ("x,y,z,tolerance_mm\n1,2,3,1\n1,2,3,0\n", "row 3: tolerance_mm"),
                                        ("x,y,z,tolerance_mm\n1,2,abc,1\n", "row 2: z")])
def test_a_bad_targets_file_is_one_line_exit_2(built, tmp_path, capsys, text, what):
    _, _, folder, _ = built
    csv = tmp_path / "targets.csv"
    csv.write_text(text)
    out = tmp_path / "out"
    assert main(["plan", str(OPEN), "--roadmap", str(folder), "--targets", str(csv), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and what in err[0] and str(csv) in err[0]
    assert not out.exists()


def test_cli_answers_every_target_row(built, tmp_path, capsys):
    """Two rows: the scene's target (solved) and a point out of reach (not solved: exit 1); one JSON
    document with a result per row; --out writes obstacles.ply and a path file per row."""
    _, _, folder, _ = built
    csv = tmp_path / "targets.csv"
    csv.write_text("x,y,z,tolerance_mm\n37.2,-27.2,181.6,3\n0,0,900,1\n")
    out = tmp_path / "out"
    code = main(["plan", str(OPEN), "--roadmap", str(folder), "--targets", str(csv), "--json",
                 "--out", str(out)])
    doc = json.loads(capsys.readouterr().out)
    assert code == 1
    first, second = doc["results"]
    assert first["solved"] and not second["solved"]
    assert first["target_mm"] == [37.2, -27.2, 181.6] and second["path"] == []
    assert first["validated"]["collision_free"] and first["query_time_s"] > 0
    assert 0 < first["validated"]["max_position_error_mm"] < 5  # the PINN against the exact model
    assert np.asarray(doc["base_pose"]).shape == (4, 4)
    assert_safe(np.array(first["path"]), np.array([37.2, -27.2, 181.6]), 3.0)
    assert sorted(p.name for p in out.iterdir()) == ["obstacles.ply", "path_001.json", "path_002.json"]
    assert json.loads((out / "path_001.json").read_text())["solved"] is True


@pytest.mark.parametrize("args, what", [(["--time-limit", "0"], "--time-limit: must be a positive duration"),
                                        (["--workers", "99"], "--workers: 99 workers but only"),
                                        (["--workers", "0"], "--workers: need at least 1")])
def test_roadmap_build_bad_options_are_one_line_exit_2(tmp_path, capsys, args, what):
    out = tmp_path / "rm"
    assert main(["roadmap", "build", str(OPEN), "--out", str(out), *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and what in err[0]
    assert not out.exists()


def test_roadmap_build_refuses_to_continue_a_foreign_roadmap(built, capsys):
    """A folder holding open.yaml's roadmap is not continued for pipe.yaml: one line, exit 2, the
    folder untouched."""
    _, _, folder, _ = built
    before = {f.name: f.read_bytes() for f in folder.iterdir()}
    args = ["roadmap", "build", str(SCENES / "pipe.yaml"), "--out", str(folder), "--time-limit", "5s"]
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "roadmap built for another scene" in err[0]
    assert {f.name: f.read_bytes() for f in folder.iterdir()} == before
