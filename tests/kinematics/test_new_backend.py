"""Adding a backend is one class and one registry row (docs/design.md §2): a closed-form one-tube arc,
registered here and nowhere else, plans through the command line, validates its own plan (an exact
backend is its own exact companion) and agrees with the Cosserat solver.

A single tube in free space carries no torsion (u_z = 0, so R(0) = Rz(alpha)) and no bending moment
beyond its pre-curvature: in front of the plate it is a straight segment and then an exact circular
arc of curvature kappa in the plane its rotation alpha selects.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from ctrplan.cli.app import main
from ctrplan.kinematics import CosseratBackend
from ctrplan.kinematics.backbone import Backbone
from ctrplan.kinematics.base import DEFAULT_POINTS, Backend, Points, arc_fractions
from ctrplan.kinematics.registry import BACKEND_KINDS, BackendKind, exact_companion
from ctrplan.model.robot import Robot

STRAIGHT, CURVED, KAPPA = 50.0, 40.0, 25.0  # mm, mm, 1/m


class ArcBackend(Backend):
    """One tube, closed form: straight, then a circular arc (exact for one tube in free space)."""

    name = "toy"
    exact = True

    def __init__(self, robot: Robot):
        super().__init__(robot)
        (tube,) = robot.tubes
        self.straight, self.length = tube.straight_length_mm, tube.length_mm
        self.kappa, self.radius = tube.curvature_per_mm, tube.outer_diameter_mm / 2

    def _states(self, q: np.ndarray, s: np.ndarray) -> np.ndarray:
        """States (B, P, 11) at arc lengths s (B, P): no moment, no torsion, position and orientation."""
        beta, alpha = q[:, :1], q[:, 1:]
        start = np.maximum(beta + self.straight, 0.0)  # where the arc starts, in front of the plate
        arc = np.maximum(s - start, 0.0)
        theta = self.kappa * arc
        side = -self.kappa * arc**2 / 2 * np.sinc(theta / (2 * np.pi)) ** 2  # -(1 - cos theta) / kappa
        depth = np.minimum(s, start) + arc * np.sinc(theta / np.pi)  # straight part + sin(theta) / kappa
        state = np.zeros((*s.shape, 11))
        state[..., 4], state[..., 5], state[..., 6] = -np.sin(alpha) * side, np.cos(alpha) * side, depth
        ca, sa, ct, st = np.cos(alpha / 2), np.sin(alpha / 2), np.cos(theta / 2), np.sin(theta / 2)
        state[..., 7:] = np.stack([ca * ct, ca * st, sa * st, sa * ct], axis=-1)  # Rz(alpha) Rx(theta)
        return state

    def forward(self, q: np.ndarray, points: Points = DEFAULT_POINTS, *,
                guess: np.ndarray | None = None, check: bool = True) -> Backbone:
        q = np.atleast_2d(self.robot.check_joints(q) if check else np.asarray(q, dtype=float))
        ends = q[:, :1] + self.length
        s = arc_fractions(points)[None, :] * ends
        state = self._states(q, s)
        b = len(q)
        return Backbone(q=q, s_mm=s, state=state, tube_ends_mm=ends, tips_mm=self._states(q, ends)[:, :, 4:7],
                        radius_mm=np.full(s.shape, self.radius), converged=np.ones(b, dtype=bool),
                        initial_state=self._states(q, np.zeros((b, 1)))[:, 0], iterations=np.zeros(b, int),
                        residual=np.zeros(b), backend=self.name)


@pytest.fixture
def one_tube(tmp_path):
    (tmp_path / "robot.yaml").write_text(
        "name: one_tube\ntubes:\n  - {inner_diameter_mm: 0.4, outer_diameter_mm: 0.6, "
        f"straight_length_mm: {STRAIGHT}, curved_length_mm: {CURVED}, curvature_1_per_m: {KAPPA}}}\n"
        "domain: {beta1_mm: [-10.0, 0.0], alpha_rad: [-3.141592653589793, 3.141592653589793]}\n")
    return Robot.load(tmp_path / "robot.yaml")


@pytest.fixture
def toy_registered(monkeypatch):
    """The one registry row a new backend needs."""
    monkeypatch.setitem(BACKEND_KINDS, "toy", BackendKind("toy", lambda robot, model: ArcBackend(robot),
                                                          uses_model=False, reference_states_per_s=5000.0))


def test_the_arc_is_the_cosserat_solution_of_one_tube(one_tube):
    q = one_tube.sample_joints(16, np.random.default_rng(3))
    toy, exact = ArcBackend(one_tube).forward(q, 25), CosseratBackend(one_tube).forward(q, 25)
    np.testing.assert_allclose(toy.positions_mm, exact.positions_mm, atol=1e-3)
    np.testing.assert_allclose(np.abs(np.sum(toy.quaternions * exact.quaternions, -1)), 1.0, atol=1e-6)
    np.testing.assert_allclose(toy.tip_mm, exact.tip_mm, atol=1e-3)


def test_a_registered_backend_plans_through_the_cli_and_validates_itself(tmp_path, one_tube, toy_registered,
                                                                         capsys):
    toy = ArcBackend(one_tube)
    assert exact_companion(toy, one_tube) is toy  # exact: its own companion, no Cosserat solve needed
    tip = CosseratBackend(one_tube).forward(np.array([-5.0, 0.3]), 2).tip_mm[0]  # a target it can reach
    (tmp_path / "scene.yaml").write_text(
        "name: toy_open\nrobot: robot.yaml\nbase_pose: {position: [0.0, 0.0, 0.0]}\n"
        "obstacles:\n  - {name: post, sphere: {center: [40.0, 40.0, 30.0], radius: 5.0}}\n"
        f"target: {{point: {tip.tolist()}, tolerance_mm: 2.0}}\nstart: [-10.0, 0.0]\n"
        "planner: {time_limit_s: 5.0, points: 20}\n")
    out = tmp_path / "out"
    rc = main(["plan", str(tmp_path / "scene.yaml"), "--backend", "toy", "--seed", "0", "--json", "--out",
               str(out)])
    doc = json.loads(capsys.readouterr().out)
    assert rc == 0 and doc["solved"], doc["message"]
    assert doc["backend"] == doc["validated"]["backend"] == "toy"
    assert json.loads((out / "path.json").read_text())["backbones_backend"] == "toy"
    end = CosseratBackend(one_tube).forward(np.array(doc["path"][-1]), 2).tip_mm[0]  # physics, not the toy
    assert np.linalg.norm(end - np.array(doc["tip_mm"])) < 1e-3
    assert np.linalg.norm(end - tip) <= 2.0 + 1e-6
    assert (out / "plan.png").is_file() and (out / "trajectory.csv").is_file()
