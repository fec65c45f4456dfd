"""Safety net tests that can fail: a path is reported solved only if the exact model confirms it."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from ctrplan.collision.checker import RobotCollisionChecker
from ctrplan.collision.world import CollisionWorld
from ctrplan.kinematics import CosseratBackend
from ctrplan.kinematics.backbone import Backbone
from ctrplan.kinematics.base import DEFAULT_POINTS, Backend
from ctrplan.planning import BoxSpace, plan, validate_path
from ctrplan.scene.geometry import make_pose
from ctrplan.scene.loader import load_scene
from ctrplan.scene.objects import Obstacle, Scene
from tests.independent.geometry import box_gap
from tests.paths import SCENES


class FoldedBodyBackend(Backend):
    """Exact tips, wrong body: every backbone point of the exact model moved onto the tip.

    A planner using it sees only a ball at the tip, so it finds paths whose tip is right while the
    exact robot's body may pass through anything."""

    name = "folded"
    exact = False

    def __init__(self, inner: Backend):
        super().__init__(inner.robot)
        self.inner = inner

    def forward(self, q: np.ndarray, points: int | np.ndarray = DEFAULT_POINTS, *, check: bool = True,
                guess: np.ndarray | None = None) -> Backbone:
        if guess is None:
            bb = self.inner.forward(q, points, check=check)
        else:
            bb = self.inner.forward(q, points, check=check, guess=guess)
        state = bb.state.copy()
        state[..., 8:11] = bb.tip_mm[:, None, :]
        return replace(bb, state=state, backend=self.name)


def _box(name: str, center, size) -> Obstacle:
    return Obstacle(name=name, kind="box", pose=make_pose(np.eye(3), np.asarray(center, dtype=float)),
                    size=tuple(float(v) for v in size))


@pytest.fixture(scope="module")
def collar_scene() -> Scene:
    """open.yaml plus a plate across the robot's base at z = 25 mm with a 3 x 3 mm hole where the
    start's body passes (x = 0, y = -1.9): every configuration with the tubes turned collides there,
    the tip never goes near it."""
    sc = load_scene(SCENES / "open.yaml")
    z, t, hw = 25.0, 2.0, 40.0  # plate depth, thickness, half width (mm)
    hx, y0, y1 = 1.5, -3.5, -0.5  # hole: |x| < 1.5, y0 < y < y1
    frame = (_box("collar_left", [-(hx + hw) / 2, 0, z], [hw - hx, 2 * hw, t]),
             _box("collar_right", [(hx + hw) / 2, 0, z], [hw - hx, 2 * hw, t]),
             _box("collar_low", [0, (y0 - hw) / 2, z], [2 * hx, hw + y0, t]),
             _box("collar_high", [0, (y1 + hw) / 2, z], [2 * hx, hw - y1, t]))
    return replace(sc, obstacles=sc.obstacles + frame, name="collar")


def test_a_right_tip_on_a_colliding_body_is_never_solved(collar_scene):
    folded = FoldedBodyBackend(CosseratBackend(collar_scene.robot))
    res = plan(collar_scene, folded, seed=0, time_limit_s=8.0, repair=False)
    v = res.validated
    assert v is not None, res.message  # the folded model found a path ...
    assert v.tip_in_target and v.converged  # ... whose exact tip is in the target ...
    assert not v.collision_free  # ... and whose exact body goes through the collar
    assert v.first_collision.obstacles[0].startswith("collar")
    assert not res.solved and res.to_json()["solved"] is False
    assert "collides" in res.message


def test_repair_of_a_colliding_body_is_checked_again(collar_scene):
    """Whether or not the exact repair gets through the collar's hole in time, the verdict must be
    the geometry's: the exact body clears the collar plates by the margin on every checked state
    exactly when the plan says solved (distances computed here, not by FCL)."""
    folded = FoldedBodyBackend(CosseratBackend(collar_scene.robot))
    res = plan(collar_scene, folded, seed=0, time_limit_s=8.0)
    first = res.work.repair.first_validation  # a repair was tried
    assert first.collision_free is False and first.tip_in_target is True
    p, r = res.dense.exact.positions_mm, res.dense.exact.radius_mm
    gap = min(box_gap(p, r, o.pose[:3, 3], o.size, o.pose[:3, :3]) for o in collar_scene.obstacles
              if o.name.startswith("collar"))
    assert (gap >= collar_scene.settings.margin_mm - 1e-6) is res.solved
    assert res.solved is bool(res.validated.repaired) is validate_path(collar_scene, res.path).report.ok


def test_an_obstacle_thinner_than_the_resolution_is_caught():
    sc = load_scene(SCENES / "open.yaml")
    exact = CosseratBackend(sc.robot)
    a = sc.start.copy()
    b = a.copy()
    b[3:] += 0.5  # all tubes turned together: the robot turns rigidly about z by 0.5 rad
    space = BoxSpace.for_scene(sc)
    resolution = float(space.distance(a, b)) / 4 + 1e-6  # coarse states at turns of 0, 1/8 ... 1/2 rad
    mid = exact.forward(space.interpolate(a, b, np.array([0.375])), points=sc.settings.points,
                        check=False)
    tip = mid.tip_mm[0]
    tangent = np.array([-tip[1], tip[0], 0.0]) / np.hypot(tip[0], tip[1])
    R = np.column_stack([tangent, np.cross([0.0, 0.0, 1.0], tangent), [0.0, 0.0, 1.0]])
    plate = Obstacle(name="plate", kind="box", pose=make_pose(R, tip), size=(0.05, 4.0, 4.0))
    thin = replace(sc, obstacles=(plate,))

    coarse = space.densify(np.stack([a, b]), resolution)
    assert len(coarse) == 5
    cbb = exact.forward(coarse, points=sc.settings.points, check=False)
    rc = RobotCollisionChecker(CollisionWorld.from_scene(thin), thin.base_pose, sc.settings.points,
                               sc.settings.margin_mm)
    assert all(rc.is_free(p, r) for p, r in zip(cbb.positions_mm, cbb.radius_mm, strict=True))
    assert np.linalg.norm(cbb.tip_mm[2] - cbb.tip_mm[1]) > 4 * 0.45  # the states step over the plate

    rep = validate_path(thin, np.stack([a, b]), exact, exact=exact, resolution=resolution).report
    assert not rep.collision_free and rep.first_collision.obstacles == ("plate",)
    assert rep.states > len(coarse) and rep.max_step_mm <= rep.step_bound_mm + 1e-9
    assert np.isclose(rep.step_bound_mm, sc.robot.outer_radii_mm[0] + sc.settings.margin_mm)
