"""A design's record where one-target studies cannot show a mistake: the clearance of a design with
two targets of different clearance, and a start where the scene's own start collides.

The robot is one tube (50 mm straight, 40 mm curved at 12 1/m, OD 0.6 mm): in front of the plate a
straight segment along z and a circular arc, so its surface and its distance to a ball are written
here in closed form (`backbone_mm`), not taken from ctrplan's model or FCL.

The habit these tests keep (issue 25 §5): every safety or science function gets a test that a sign,
index, bound or unit error would fail -- here a minimum taken as a maximum and a start taken without
its collision check (`scripts/mutations.py` applies both).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from ctrplan.design.evaluate import evaluate
from ctrplan.design.task import load_task

STRAIGHT, CURVED, KAPPA = 50.0, 40.0, 12e-3  # mm, mm, 1/mm
RADIUS = 0.3  # mm, the tube's outer radius
BALL_R = 2.0  # mm
TIP_R = (1 - math.cos(KAPPA * CURVED)) / KAPPA  # mm: the tip's distance from the axis
START = (-10.0, 0.0)

#: Stability certificates and distance grids in a cache of each test's own.
pytestmark = pytest.mark.usefixtures("private_cache")


def backbone_mm(beta: float, alpha: float, n: int = 400) -> np.ndarray:
    """Points (n, 3) of the tube in front of the plate: straight to z = beta + 50, then the arc
    bending towards -y turned by alpha about z."""
    s = np.linspace(0.0, beta + STRAIGHT + CURVED, n)
    arc = np.clip(s - (beta + STRAIGHT), 0.0, None)
    inplane = (1 - np.cos(KAPPA * arc)) / KAPPA
    z = np.minimum(s, beta + STRAIGHT) + np.sin(KAPPA * arc) / KAPPA
    return np.stack([inplane * math.sin(alpha), -inplane * math.cos(alpha), z], axis=1)


def tip_mm(beta: float, alpha: float) -> np.ndarray:
    return backbone_mm(beta, alpha, 2)[-1]


def clearance_mm(q, ball: np.ndarray) -> float:
    """Distance (mm) from the tube's surface to the ball (negative: they overlap)."""
    return float(np.linalg.norm(backbone_mm(*q) - ball, axis=1).min() - BALL_R - RADIUS)


def write_task(folder: Path, ball: np.ndarray, targets: list[tuple[str, np.ndarray, float]]) -> Path:
    """The one-tube robot as its own base design, a scene with one ball, start `START`, and the given
    targets (name, point, tolerance mm); nothing varies that matters here."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "robot.yaml").write_text(
        "name: one_tube\ntubes:\n  - {inner_diameter_mm: 0.4, outer_diameter_mm: 0.6, "
        f"straight_length_mm: {STRAIGHT}, curved_length_mm: {CURVED}, curvature_1_per_m: 12.0}}\n"
        "domain: {beta1_mm: [-10.0, 0.0], alpha_rad: [-3.141592653589793, 3.141592653589793]}\n")
    (folder / "scene.yaml").write_text(
        "robot: robot.yaml\nbase_pose: {position: [0.0, 0.0, 0.0]}\n"
        f"obstacles:\n  - {{name: ball, sphere: {{center: {ball.tolist()}, radius: {BALL_R}}}}}\n"
        f"target: {{point: [0.0, 0.0, 80.0], tolerance_mm: 2.0}}\nstart: {list(START)}\n"
        "planner: {time_limit_s: 5.0, points: 20, margin_mm: 0.2, goal_samples: 2}\n")
    lines = "".join(f"  - {{name: {n}, point: {p.tolist()}, tolerance_mm: {t}}}\n" for n, p, t in targets)
    (folder / "task.yaml").write_text(
        f"scene: scene.yaml\ntargets:\n{lines}vary:\n  1: {{curvature_1_per_m: [10.0, 14.0]}}\n"
        "constraints: {max_strain: 0.08, snap_free: false}\n"
        "objectives: [targets_reached, min_clearance_mm]\nbudget: {trials: 2, plan_time_s: 3.0}\n")
    return folder / "task.yaml"


def test_a_design_does_not_start_where_the_scenes_start_collides(tmp_path):
    """A 2 mm ball sits on the start's tip: the scene's start collides. The design starts at another
    candidate -- the tube turned by 1/8 turn puts its tip 2 r sin(22.5 deg) = 7.2 mm away -- whose
    surface clears the ball by more than the 0.2 mm margin (closed-form geometry)."""
    ball = tip_mm(*START)
    assert clearance_mm(START, ball) < 0
    task = write_task(tmp_path, ball, [("behind", np.array([0.0, 0.0, -30.0]), 1.0)])
    record = evaluate(load_task(task), {})
    assert record.feasible, record.infeasible
    start = record.start
    assert start != list(START)
    assert clearance_mm(start, ball) > 0.2
    assert start[0] == pytest.approx(START[0]) and abs(start[1]) == pytest.approx(math.pi / 4)


def test_a_designs_clearance_is_its_worst_targets(tmp_path):
    """Two targets on the tip's surface of revolution: ``near`` 0.3 rad from the start's tip, far
    from the ball, and ``tight`` a quarter turn away with the ball 4 mm beyond it (the tip ends at
    most 6 mm from its centre there). The design's clearance is the smaller of the two: at most the
    ball's distance from the tight path's last configuration (computed here), well below the near
    path's clearance."""
    tight = tip_mm(-5.0, math.pi / 2)
    ball = tight + np.array([4.0, 0.0, 0.0])  # radially outside the tip circle
    near = tip_mm(-7.0, 0.3)
    task = write_task(tmp_path, ball, [("near", near, 2.0), ("tight", tight, 2.0)])
    record = evaluate(load_task(task), {})
    assert record.reached == ["near", "tight"], [t.message for t in record.targets]
    end_tight = record.target("tight").path[-1]
    assert np.linalg.norm(tip_mm(*end_tight) - tight) <= 2.0 + 1e-3
    worst = clearance_mm(end_tight, ball)
    assert 0.2 - 1e-3 <= worst <= 3.7 + 1e-3
    near_path = np.asarray(record.target("near").path)
    dense = [a + f * (b - a) for a, b in zip(near_path[:-1], near_path[1:], strict=True)
             for f in np.linspace(0.0, 1.0, 50)]
    assert min(clearance_mm(q, ball) for q in dense) > worst + 5.0  # min and max differ: a mix-up shows
    assert record.min_clearance_mm <= worst + 0.05
    assert record.min_clearance_mm == pytest.approx(min(t.min_clearance_mm for t in record.targets))
