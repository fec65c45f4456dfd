"""Failures that say why (issue 41, item 5): the structure that blocks the goal candidates, with
counts, the margin that would free some -- checked against distances computed here -- and collision
told apart from elastic instability."""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from ctrplan.kinematics import CosseratBackend, make_backend
from ctrplan.planning.failure import _examine, explain_failure
from ctrplan.planning.model import PlanningModel
from ctrplan.planning.search import search
from ctrplan.planning.validity import ConfigurationChecker
from ctrplan.scene.loader import load_scene
from ctrplan.scene.objects import Obstacle
from tests.paths import SCENES
from tests.stability.test_stability_use import HALF_TURN, snapping_pair_file

CAP_CENTRE = np.array([37.2, -27.2, 213.6])
CAP_RADIUS = 30.0
#: open.yaml with a large ball ("cap", 4 mm margin of its own) 2 mm beyond the target point: every
#: tip in the 1 mm target comes within 4 mm of it.
CAP = (SCENES / "open.yaml").read_text().replace(
    "- name: block\n  box:\n    center: [-25.0, -30.0, 150.0]\n    size: [20.0, 20.0, 20.0]\n"
    "    rotation:\n      rpy_deg: [0.0, 0.0, 30.0]\n",
    f"- name: cap\n  sphere:\n    center: {CAP_CENTRE.tolist()}\n    radius: {CAP_RADIUS}\n  margin_mm: 4.0\n"
).replace("tolerance_mm: 3.0", "tolerance_mm: 1.0")


def cap_gaps(points: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """Distance (K,) from each robot's surface -- capsules between consecutive points (K, N, 3),
    radius the larger of their ends' -- to the cap: closest point of each segment to the centre."""
    a, b = points[:, :-1], points[:, 1:]
    d = b - a
    t = np.clip(np.einsum("kij,kij->ki", CAP_CENTRE - a, d) / np.einsum("kij,kij->ki", d, d), 0.0, 1.0)
    nearest = a + t[..., None] * d
    r = np.maximum(radius[:, 1:], radius[:, :-1])
    return (np.linalg.norm(nearest - CAP_CENTRE, axis=-1) - CAP_RADIUS - r).min(axis=1)


def test_blocked_goals_name_the_structure_and_the_margin_that_frees_some(tmp_path, private_cache):
    path = tmp_path / "cap.yaml"
    path.write_text(CAP)
    scene = load_scene(path)
    checker = ConfigurationChecker(PlanningModel.build(scene, make_backend("pinn", scene.robot)))
    out = search(checker, max_states=2000, seed=0, time_limit_s=10.0)
    assert out.path_q is None and not out.sampler.goals and out.sampler.rejected
    why = explain_failure(checker, out.sampler, deadline=time.perf_counter())  # no time: no backend test
    rows = np.array(out.sampler.rejected)
    assert why.goals.examined == why.goals.collision == len(rows) == why.goals.total
    assert why.goals.unstable == why.goals.not_converged == 0
    assert [(b.name, b.goal_candidates) for b in why.blockers] == [("cap", len(rows))]
    bb = checker.backend.forward(rows, points=checker.points, check=False)
    gaps = cap_gaps(bb.positions_mm, bb.radius_mm)
    assert np.all(gaps < checker.margin_mm + 4.0)  # every one is within the cap's margin
    margin = next(m for m in np.arange(3.75, -0.01, -0.25) if (gaps > checker.margin_mm + m).any())
    (s,) = [s for s in why.suggestions if s.kind == "margin"]
    assert s.structure == "cap" and s.margin_mm == margin
    assert s.freed == int((gaps > checker.margin_mm + margin).sum())
    told = f"with margin {margin:g} mm instead of 4 mm on cap, {s.freed} of the {len(rows)}"
    assert s.text.startswith(told)
    assert f"blocked by cap ({len(rows)} goal candidates)" in why.summary() and s.text[1:] in why.summary()
    assert why.untested.startswith("other backends not tried")


def test_collision_is_told_apart_from_elastic_instability(tmp_path, private_cache):
    """The snapping two-tube pair (unstable at half a turn) and a ball at the tip of one stable
    configuration: one state each unstable, in collision with the ball, free."""
    scene_file = tmp_path / "scene.yaml"
    scene_file.write_text(f"name: pair\nrobot: {snapping_pair_file(tmp_path)}\n"
                          "base_pose: {position: [0, 0, 0]}\n"
                          "obstacles: []\ntarget: {point: [0.0, 30.0, 70.0], tolerance_mm: 3.0}\n"
                          "start: [0, 0, 0, 1.0]\n")
    scene = load_scene(scene_file)
    exact = CosseratBackend(scene.robot).checking_stability()
    touching, free = np.array([0.0, 0.0, 0.0, 0.0]), np.array([0.0, 0.0, 2.5, 1.0])
    tip = exact.forward(touching, points=2).tip_mm[0]
    ball = Obstacle("ball", "sphere", pose=np.vstack([np.c_[np.eye(3), tip], [0, 0, 0, 1]]), radius=2.0)
    scene = replace(scene, obstacles=(ball,))
    checker = ConfigurationChecker(PlanningModel.of(scene, exact))
    examined = _examine(checker, np.stack([HALF_TURN, touching, free]))
    assert examined.kinds == ("unstable", "collision", "free")
    assert list(examined.touches[1]) == ["ball"] and examined.touches[1]["ball"] == 0.0
