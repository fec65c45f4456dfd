"""Geometry that decides safety: an oblique target's containment, the side the tip arrives from, a
tube's base in front of the plate, the tube order of a robot file's domain.

The habit these tests keep (issue 25 §5): every safety or science function gets a test that a sign,
index, bound or unit error would fail. So each expectation here is computed outside the code under
test -- rotations written out by hand, tip frames from the separately written integrator
(`tests/independent/cosserat.py`), configurations whose verdict follows from the tube lengths -- and
each test sits on the side of a bound where the wrong sign, index or bound gives the other answer.
`scripts/mutations.py` applies those one-line bugs and checks that these tests fail.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from ctrplan.base.errors import InputError
from ctrplan.model.robot import Robot
from ctrplan.planning import validate_path
from ctrplan.scene.loader import load_scene
from tests.independent.cosserat import Tubes, solve
from tests.independent.geometry import axis_angle
from tests.paths import REPO

NOMINAL_YAML = (REPO / "ctrplan" / "data" / "nominal.yaml").read_text()
#: Robot frame -> scene frame: a rotation about a skew axis and a shift.
R_BASE = axis_angle([1.0, -2.0, 0.5], 50.0)
P_BASE = np.array([5.0, 10.0, -20.0])
YAW_DEG = 30.0
SEMI_AXES = (10.0, 2.0, 2.0)


def vec(v) -> str:
    return "[" + ", ".join(f"{x:.12g}" for x in v) + "]"


def rows(m: np.ndarray) -> str:
    return "[" + ", ".join(vec(r) for r in m) + "]"


def scene_file(tmp_path: Path, target: str, name: str = "guard") -> Path:
    """An obstacle-free scene of the nominal robot at the base pose above with the given target
    mapping (YAML flow text)."""
    path = tmp_path / f"{name}.yaml"
    path.write_text(f"robot: nominal\nbase_pose:\n  position: {vec(P_BASE)}\n"
                    f"  rotation: {{matrix: {rows(R_BASE)}}}\n"
                    f"target: {target}\nstart: [-80.0, -65.0, -10.0, 0.0, 0.0, 0.0]\n")
    return path


def test_an_oblique_ellipsoid_contains_its_long_axis_and_not_its_mirror_image(tmp_path):
    """Semi-axes 10, 2, 2 mm, the long axis turned 30 deg about z (rpy yaw): the long axis runs along
    (cos 30, sin 30, 0). A point 8 mm along it is inside (normalised radius 0.8). Its mirror image
    across the x axis, 8 (cos 30, -sin 30, 0), lies 8 cos 60 = 4 mm along the long axis and 8 sin 60
    = 6.93 mm across it: radius sqrt(0.4^2 + 3.46^2) > 1, outside -- a rotation applied transposed
    swaps the two verdicts. Points sampled in the region are inside by the same hand rotation."""
    center = np.array([20.0, -10.0, 150.0])
    target = (f"{{ellipsoid: {{center: {vec(center)}, semi_axes_mm: {vec(SEMI_AXES)}, "
              f"rotation: {{rpy_deg: [0, 0, {YAW_DEG}]}}}}}}")
    region = load_scene(scene_file(tmp_path, target)).target
    a = math.radians(YAW_DEG)
    along, across = np.array([math.cos(a), math.sin(a), 0.0]), np.array([-math.sin(a), math.cos(a), 0.0])
    mirror = np.array([math.cos(a), -math.sin(a), 0.0])
    assert region.contains(center + 8.0 * along)
    assert region.normalized_radius(center + 8.0 * along) == pytest.approx(0.8)
    assert not region.contains(center + 8.0 * mirror)
    assert region.normalized_radius(center + 8.0 * mirror) == pytest.approx(math.hypot(0.4, 2 * math.sqrt(3)))
    assert region.contains(center + 1.9 * across) and not region.contains(center + 2.1 * across)
    pts = region.sample(500, np.random.default_rng(0)) - center
    local = np.stack([pts @ along, pts @ across, pts[:, 2]], axis=1) / np.array(SEMI_AXES)
    assert np.linalg.norm(local, axis=1).max() <= 1.0 + 1e-9
    assert np.abs(pts @ along).max() > 5.0  # the samples fill the long axis, not a sphere of 2 mm


@pytest.mark.parametrize(("sign", "inside"), [(1.0, True), (-1.0, False)])
def test_a_tip_arriving_from_the_wrong_side_is_not_in_the_target(tmp_path, sign, inside):
    """Exact validation of a one-state path whose tip ends at the centre of a 3 mm target. The
    approach direction is the tip's own tangent (independent integrator, moved into the scene frame by
    the base pose) or its opposite, 30 deg wide: the tip arrives along it (0 deg) or from the wrong
    side (180 deg), which a sign-agnostic angle test would accept."""
    q = np.array([-30.0, -20.0, -5.0, 0.4, -0.3, 1.2])
    out = solve(q[None], Tubes.paper())
    assert out["converged"].all()
    tip = out["tips_mm"][0, 0] @ R_BASE.T + P_BASE
    tangent = R_BASE @ out["tip_rotation"][0][:, 2]
    target = (f"{{point: {vec(tip)}, tolerance_mm: 3.0, direction: {vec(sign * tangent)}, "
              f"angle_tolerance_deg: 30}}")
    scene = load_scene(scene_file(tmp_path, target))
    rep = validate_path(scene, q[None]).report
    assert rep.converged and rep.collision_free
    assert rep.tip_angle_deg == pytest.approx(0.0 if inside else 180.0, abs=0.05)
    assert rep.tip_in_target is inside and rep.ok is inside
    assert bool(scene.target.direction_ok(tangent)) is inside
    assert bool(scene.target.direction_ok(-tangent)) is not inside
    assert float(np.degrees(scene.target.angle_rad(-tangent))) == pytest.approx(
        180.0 if inside else 0.0, abs=1e-6)


def test_the_outermost_tubes_base_in_front_of_the_plate_is_impossible():
    """beta = (-20, -10, 2) mm keeps the tube order (-20 <= -10 <= 2) and every tip in order (ends
    190, 155, 112 mm), but tube 3's base sits 2 mm in front of the plate: physically impossible,
    refused even where leaving the domain is allowed. Tube 1's base (-20 mm) is behind it, so a check
    on the wrong tube passes it."""
    robot = Robot.nominal()
    with pytest.raises(InputError, match=r"row 0: tube 3 base in front of the plate: need beta3 <= 0"):
        robot.check_joints(np.array([-20.0, -10.0, 2.0, 0.0, 0.0, 0.0]), allow_outside_domain=True)
    robot.check_joints(np.array([-20.0, -10.0, 0.0, 0.0, 0.0, 0.0]), allow_outside_domain=True)


@pytest.mark.parametrize("bounds", ["[-5.0, 15.0]", "[-5.0, -1.0]"])
def test_a_domain_that_reverses_the_tube_order_is_refused(tmp_path, bounds):
    """A difference of translations beta2 - beta1 below 0 puts tube 2's base behind tube 1's: the
    tube order is broken, and sampling that box draws impossible configurations. The lower bound
    decides it (an upper bound of 15 mm is fine); the loader names the key and its line."""
    path = tmp_path / "robot.yaml"
    key = "beta2_minus_beta1_mm"
    path.write_text(NOMINAL_YAML.replace(f"{key}: [0.0, 15.0]", f"{key}: {bounds}"))
    with pytest.raises(InputError, match="domain.beta2_minus_beta1_mm.*tube order"):
        Robot.load(str(path))
    path.write_text(NOMINAL_YAML.replace(f"{key}: [0.0, 15.0]", f"{key}: [0.0, 40.0]"))
    q = Robot.load(str(path)).sample_joints(500, rng=0)
    assert np.all(q[:, 0] <= q[:, 1] + 1e-12) and np.all(q[:, 1] <= q[:, 2] + 1e-12)
