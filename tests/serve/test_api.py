"""The JSON API of `ctrplan serve` on a small roadmap of open.yaml: documents, bad requests (a 4xx
and one line, the server alive after each), and tissue that moves onto the path (checked apart from
ctrplan's collision code)."""

from __future__ import annotations

import numpy as np
import pytest

from ctrplan.kinematics import CosseratBackend
from ctrplan.model.robot import Robot
from ctrplan.planning import BoxSpace
from tests.independent.geometry import sphere_gap
from tests.serve.conftest import call

TARGET = [37.2, -27.2, 181.6]
BALL = np.array([43.0, -47.0, 150.0])
BALL_RADIUS = 7.0


def exact_backbones(path: list) -> tuple[np.ndarray, np.ndarray]:
    """The exact backbones (scene frame = robot frame in open.yaml) of a joint path densified to
    0.5 mm: points (K, 30, 3) and radii (K, 30)."""
    q = BoxSpace.for_robot(Robot.nominal()).densify(np.asarray(path), 0.5)
    bb = CosseratBackend(Robot.nominal()).forward(q, points=30)
    assert bb.converged.all()
    return bb.positions_mm, bb.radius_mm


def test_scene_and_plan_documents(app):
    status, scene = call(app.url + "api/scene")
    assert status == 200
    assert [s["name"] for s in scene["structures"]] == ["ball", "block"]
    assert np.asarray(scene["base_pose"]).shape == (4, 4)
    assert scene["roadmap"]["nodes"] >= 300 and scene["planner"] == "roadmap"
    status, doc = call(app.url + "api/plan", "POST", {"target_mm": TARGET, "tolerance_mm": 3.0})
    assert status == 200
    assert {"solved", "query_time_s", "path", "validated", "message"} <= set(doc)
    assert doc["solved"] and doc["validated"]["collision_free"] and doc["query_time_s"] > 0
    assert np.allclose(doc["path"][0], [-80.0, -65.0, -10.0, 0.0, 0.0, 0.0])
    assert doc["structures"][0]["clearance_mm"] <= doc["structures"][1]["clearance_mm"]  # nearest first
    p, r = exact_backbones(doc["path"])
    assert np.linalg.norm(p[-1, -1] - TARGET) <= 3.0


@pytest.mark.parametrize("method, path, body, status, words", [
    ("POST", "api/plan", b"{not json", 400, "body is not JSON"),
    ("POST", "api/plan", {"target_mm": [1, 2]}, 400, "target_mm: must be three numbers"),
    ("POST", "api/plan", {"tolerance_mm": 1}, 400, "target_mm: missing"),
    ("POST", "api/plan", b'{"target_mm": [1, 2, NaN]}', 400, "must be a finite number"),
    ("POST", "api/plan", {"target_mm": [1, 2, 3], "tolerance_mm": -1}, 400, "tolerance_mm: must be > 0"),
    ("GET", "api/plan", None, 405, "takes POST"),
    ("POST", "api/structures/bone/move", {"translation_mm": [0, 0, 1]}, 404, "no structure named 'bone'"),
    ("POST", "api/structures/ball/move", {"translation_mm": [0, 0, 99]}, 400, "at most 30 mm"),
    ("GET", "api/nothing", None, 404, "no such endpoint"),
])
def test_a_bad_request_is_one_line_and_the_server_lives_on(app, method, path, body, status, words):
    got, doc = call(app.url + path, method, body)
    assert got == status and list(doc) == ["error"]
    assert words in doc["error"] and "\n" not in doc["error"]
    assert call(app.url + "api/scene")[0] == 200


def test_a_structure_moved_onto_the_path_is_avoided_by_the_next_plan(app):
    """The ball moves so that it overlaps today's path; the roadmap is repaired (a part of it checked),
    the next path to the same target is solved and clears the ball at its new place -- distances
    computed here from the exact backbones, not with ctrplan's collision code."""
    _, first = call(app.url + "api/plan", "POST", {"target_mm": TARGET, "tolerance_mm": 3.0})
    assert first["solved"]
    p, r = exact_backbones(first["path"])
    gaps = np.linalg.norm(p - BALL, axis=-1) - BALL_RADIUS - r
    k, i = np.unravel_index(np.argmin(gaps), gaps.shape)
    shift = p[k, i] - BALL
    shift *= 1.0 - 0.5 * BALL_RADIUS / np.linalg.norm(shift)  # the ball's centre half a radius from the path
    assert np.linalg.norm(shift) <= 30.0
    status, moved = call(app.url + "api/structures/ball/move", "POST", {"translation_mm": shift.tolist()})
    assert status == 200 and np.allclose(moved["shift_mm"], shift, atol=1e-3)
    rep = moved["repair"]
    assert 0 < rep["suspect"]["nodes"] < rep["total"]["nodes"]
    assert sphere_gap(p, r, BALL + shift, BALL_RADIUS) < 0  # today's path goes through the moved ball
    _, second = call(app.url + "api/plan", "POST", {"target_mm": TARGET, "tolerance_mm": 3.0})
    assert second["solved"], second["message"]
    p2, r2 = exact_backbones(second["path"])
    assert sphere_gap(p2, r2, BALL + shift, BALL_RADIUS) >= 0.0
    _, scene = call(app.url + "api/scene")
    assert np.allclose(scene["structures"][0]["shift_mm"], shift, atol=1e-3)
    assert scene["roadmap"]["blocked_nodes"] + scene["roadmap"]["blocked_edges"] > 0  # found on the way
