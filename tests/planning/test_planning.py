"""Planning: state space, IK, goal sampling, motion validation, exact re-validation, the CLI."""

from __future__ import annotations

import json
import re
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import trimesh

from ctrplan.cli.app import main
from ctrplan.kinematics import CosseratBackend
from ctrplan.kinematics.base import DEFAULT_POINTS, Backend
from ctrplan.model.robot import Robot
from ctrplan.planning import (
    BoxSpace,
    ConfigurationChecker,
    GoalSampler,
    PlanningModel,
    build_problem,
    make_planner,
    plan,
    resolve_backend,
    seed_ompl,
    solve_ik,
    validate_path,
)
from ctrplan.planning.corridor import CorridorRRTConnect
from ctrplan.planning.ik import _damped_step, _lm_iteration, compile_ik, fd_tip_jacobian
from ctrplan.planning.planners import PLANNERS
from ctrplan.planning.validity import bisection_order
from ctrplan.scene.loader import load_scene
from tests.independent.cosserat import Tubes, solve
from tests.independent.geometry import axis_angle, box_gap, sphere_gap
from tests.paths import REPO, SCENES


def test_box_space_round_trip_and_metric():
    robot = Robot.nominal()
    sp = BoxSpace.for_robot(robot, mm_per_rad=40.0)
    q = robot.sample_joints(50, 0)
    assert np.allclose(sp.to_joints(sp.to_coords(q)), q)
    assert sp.contains(q).all()
    d = np.zeros(6)
    d[3] = 0.5  # half a radian of tube 1 = 20 mm
    assert np.isclose(sp.distance(q[0], q[0] + d), 20.0)
    d = np.zeros(6)
    d[:3] = 3.0  # all tubes 3 mm forward: only beta3 changes in box coordinates
    assert np.isclose(sp.distance(q[0], q[0] + d), 3.0)
    dense = sp.densify(q[:3], 1.0)
    assert np.all(sp.distance(dense[1:], dense[:-1]) <= 1.0 + 1e-9)
    assert np.allclose(dense[0], q[0]) and np.allclose(dense[-1], q[2])
    assert sorted(bisection_order(8)) == list(range(1, 8)) and bisection_order(8)[0] == 4


def test_ik_reaches_reachable_targets(exact):
    robot = exact.robot
    sp = BoxSpace.for_robot(robot)
    goal_q = robot.sample_joints(8, 3)
    targets = exact.forward(goal_q, points=2, check=False).tip_mm
    seeds = robot.sample_joints(8, 4)
    jac = fd_tip_jacobian(lambda q, points=2: exact.forward(q, points=points, check=False), sp)
    res = solve_ik(jac, sp, seeds, targets, tol_mm=0.05, max_iterations=40)
    assert res.success.mean() >= 0.75
    tips = exact.forward(res.q, points=2, check=False).tip_mm
    ok = res.success
    assert np.all(np.linalg.norm(tips[ok] - targets[ok], axis=1) <= 0.05 + 1e-6)
    assert sp.contains(res.q).all()


def test_ik_asked_enough_stops_there_or_changes_nothing(exact):
    """``enough`` is asked once, after ``check_after`` iterations, with the result so far: True ends
    the solve exactly as ``max_iterations=check_after`` would; False leaves it bit for bit as without
    the question."""
    robot = exact.robot
    sp = BoxSpace.for_robot(robot)
    targets = exact.forward(robot.sample_joints(6, 5), points=2, check=False).tip_mm
    seeds = robot.sample_joints(6, 6)
    jac = fd_tip_jacobian(lambda q, points=2: exact.forward(q, points=points, check=False), sp)
    asked = []

    def ask(answer):
        def enough(partial):
            asked.append(partial.iterations)
            return answer
        return enough

    def solve(**kw):
        return solve_ik(jac, sp, seeds, targets, tol_mm=0.05, **kw)

    full = solve(max_iterations=12)
    never = solve(max_iterations=12, enough=ask(False), check_after=3)
    for field in ("q", "tip", "error_mm", "success"):
        np.testing.assert_array_equal(getattr(full, field), getattr(never, field))
    assert full.iterations == never.iterations > 3
    short = solve(max_iterations=3)
    stopped = solve(max_iterations=12, enough=ask(True), check_after=3)
    np.testing.assert_array_equal(stopped.q, short.q)
    np.testing.assert_array_equal(stopped.error_mm, short.error_mm)
    assert stopped.iterations == short.iterations == 3
    assert asked == [3, 3]  # once per solve, with check_after iterations done


def test_compile_ik_compiles_what_solve_ik_runs(exact):
    """`compile_ik` runs before a planning clock starts: the kernel it compiles must be the one
    `solve_ik` then calls (one seed or several, one shared target or one each), else numba compiles
    a new version inside the clock."""
    robot = exact.robot
    sp = BoxSpace.for_robot(robot)
    compile_ik(sp)
    before = list(_lm_iteration.signatures)
    jac = fd_tip_jacobian(lambda q, points=2: exact.forward(q, points=points, check=False), sp)
    targets = exact.forward(robot.sample_joints(3, 5), points=2, check=False).tip_mm
    for seeds, goal in ((1, targets[0]), (3, targets), (3, targets[0])):
        solve_ik(jac, sp, robot.sample_joints(seeds, 6), goal, max_iterations=2)
    assert list(_lm_iteration.signatures) == before


def test_damped_step_is_the_least_squares_step_with_bounds_as_an_active_set():
    """Closed forms: away from the bounds, a lightly damped step solves J dy = e with the least
    weighted norm (dy = W J^T x, W the column weights); a coordinate at a bound that the step would
    push outwards is held and the others still solve J dy = e; a long step is cut to ``max_step``."""
    rng = np.random.default_rng(3)
    J, e = rng.normal(size=(3, 6)), rng.normal(size=3)
    w = np.array([1.0, 1.0, 1.0, 0.25, 0.25, 0.25])
    lo, hi = np.full(6, -100.0), np.full(6, 100.0)
    y = np.zeros(6)
    dy = _damped_step(y, J, e, 1e-6, w, lo, hi, 1e3)
    np.testing.assert_allclose(J @ dy, e, atol=1e-8)
    Jw = J * w  # dy = w * dz with dz = Jw^T (Jw Jw^T)^-1 e: the least-norm solution in z
    np.testing.assert_allclose(dy, w * (Jw.T @ np.linalg.solve(Jw @ Jw.T, e)), atol=1e-8)
    j = int(np.argmax(np.abs(dy)))
    at = y.copy()
    if dy[j] < 0:
        at[j] = lo[j]
    else:
        at[j] = hi[j]
    held = _damped_step(at, J, e, 1e-6, w, lo, hi, 1e3)
    assert held[j] == 0.0
    np.testing.assert_allclose(J @ held, e, atol=1e-8)
    short = _damped_step(y, J, 1e3 * e, 1e-6, w, lo, hi, 2.0)
    assert np.linalg.norm(short) == pytest.approx(2.0)
    np.testing.assert_allclose(short / np.linalg.norm(short), dy / np.linalg.norm(dy), atol=1e-8)


def test_goal_sampler_gives_valid_goals_in_the_region(open_scene, exact):
    checker = ConfigurationChecker(PlanningModel.of(open_scene, exact))
    sampler = GoalSampler(checker, open_scene.target, np.random.default_rng(0), start=open_scene.start)
    goals = sampler.sample_batch()
    assert len(goals) >= 3
    bb = exact.forward(np.stack(goals), points=open_scene.settings.points, check=False)
    assert open_scene.target.contains(open_scene.to_scene(bb.tip_mm)).all()
    assert checker.check(np.stack(goals)).all()


def test_motion_validator_checks_an_edge_in_one_batch(open_scene, exact):
    checker = ConfigurationChecker(PlanningModel.of(open_scene, exact))
    a = open_scene.start
    b = a.copy()
    b[:3] += np.array([10.0, 10.0, 5.0])  # box coordinates move by (5, -5, 0): 7.07 mm
    before = checker.counters.kinematics_batches
    assert checker.check_motion(a, b, resolution=1.0)
    assert checker.counters.kinematics_batches - before == 2  # end state, then the whole interior
    assert checker.counters.kinematics_calls == 8  # ceil(7.07 / 1) states
    assert not checker.check_motion(a, b, resolution=0.5) or checker.counters.kinematics_calls == 8 + 14


def test_straight_line_through_the_ball_collides_under_exact_validation(open_scene, exact):
    goal = Robot.nominal().domain.from_box(np.array([0, 10, 5, 0.5, 3.0, 0.3]))
    vp = validate_path(open_scene, np.stack([open_scene.start, goal]), exact)
    rep = vp.report
    assert not rep.collision_free and rep.colliding_states
    assert rep.first_collision.obstacles == ("ball",) and rep.first_collision.why == "the robot touches ball"
    assert rep.min_clearance_mm == 0.0
    assert rep.max_position_error_mm < 1e-6  # planning backend = exact model (to solver tolerance)


class WrongBackend(CosseratBackend):
    """A deliberately wrong model: every pre-curvature 40 % too small."""

    name = "wrong"

    def __init__(self):
        robot = Robot.nominal()
        tubes = tuple(replace(t, curvature_per_mm=0.6 * t.curvature_per_mm) for t in robot.tubes)
        super().__init__(robot.with_changes(tubes=tubes))


def test_validation_catches_a_wrong_backend(open_scene):
    res = plan(open_scene, WrongBackend(), seed=0, time_limit_s=5.0, repair=False)
    assert res.validated is not None, res.message  # the wrong model did find a path
    assert res.validated.backend == "cosserat"
    assert res.validated.max_position_error_mm > 5.0
    assert not res.solved  # its tip misses the target under the exact model
    assert not res.validated.tip_in_target
    assert "not solved" in res.message and "repair disabled" in res.message
    assert res.to_json()["solved"] is False


def test_plan_with_repair_is_never_unsafe(open_scene):
    """The wrong model's path misses the target under the exact model; the exact repair re-plans its
    end. The result is checked here apart from ctrplan: the independent integrator's tip is within
    open.yaml's 3 mm of its target, and every checked state clears the ball and the block by the
    0.2 mm margin (distances computed here)."""
    res = plan(open_scene, WrongBackend(), seed=1, time_limit_s=5.0)
    assert res.work.repair.first_validation.tip_in_target is False  # the wrong model's own path
    assert res.solved and res.validated.repaired, res.message
    tip = solve(res.path[-1][None], Tubes.paper())["tips_mm"][0, 0]
    assert np.linalg.norm(tip - [37.2, -27.2, 181.6]) <= 3.0
    p, r = res.dense.exact.positions_mm, res.dense.exact.radius_mm
    assert sphere_gap(p, r, [43.0, -47.0, 150.0], 7.0) >= 0.2 - 1e-6
    assert box_gap(p, r, [-25.0, -30.0, 150.0], [20.0, 20.0, 20.0], axis_angle([0, 0, 1], 30.0)) >= 0.2 - 1e-6


def assert_safe_open_path(scene, exact, path: np.ndarray) -> None:
    """A joint path of open.yaml checked apart from the planner: it starts at the scene's start, the
    independent integrator puts its last tip within the target's 3 mm, and the exact backbones of the
    path, densified to 0.5 mm, clear the ball and the block (distances computed here)."""
    assert np.allclose(path[0], scene.start)
    tip = solve(path[-1][None], Tubes.paper())["tips_mm"][0, 0]
    assert np.linalg.norm(tip - [37.2, -27.2, 181.6]) <= 3.0
    bb = exact.forward(BoxSpace.for_robot(scene.robot).densify(path, 0.5), points=30)
    assert bb.converged.all()
    p, r = bb.positions_mm, bb.radius_mm
    assert sphere_gap(p, r, [43.0, -47.0, 150.0], 7.0) >= 0.0
    assert box_gap(p, r, [-25.0, -30.0, 150.0], [20.0, 20.0, 20.0], axis_angle([0, 0, 1], 30.0)) >= 0.0


def test_python_api_with_any_ompl_planner(open_scene, exact):
    """An OMPL planner made by the user (here og.LBKPIECE1, which ctrplan does not name) on ctrplan's
    problem: its path is checked apart from ctrplan; every planner ctrplan names is the OMPL class
    its spec says."""
    from ompl import base as ob
    from ompl import geometric as og

    seed_ompl(0)
    problem = build_problem(open_scene, exact, rng=np.random.default_rng(0))
    planner = og.LBKPIECE1(problem.si)
    planner.setRange(20.0)
    planner.setProblemDefinition(problem.pdef)
    planner.setup()
    # until the first exact solution, or a budget of work (not seconds: the same on a loaded machine)
    counters = problem.checker.counters
    planner.solve(ob.plannerOrTerminationCondition(
        ob.PlannerTerminationCondition(lambda: counters.kinematics_calls >= 40_000),
        ob.exactSolnPlannerTerminationCondition(problem.pdef)))
    assert problem.pdef.hasExactSolution()
    assert_safe_open_path(open_scene, exact, problem.solution())
    for name, spec in PLANNERS.items():
        made = make_planner(name, problem.si, problem)
        cls = CorridorRRTConnect if spec.own else getattr(og, spec.ompl_name)
        assert isinstance(made, cls) and made.getSpaceInformation() == problem.si


# ---- CLI ------------------------------------------------------------------------------------------
def run_cli(args, capsys):
    rc = main(args)
    out = capsys.readouterr()
    return rc, out.out, out.err


ACTUATORS = """actuators:
  beta1: {counts_per_mm: 1000, offset: 80000, sign: -1, name: stage1}
  alpha3: {counts_per_rad: 651.9, offset: 12}
"""


def test_cli_plan_end_to_end(tmp_path, capsys):
    out_dir = tmp_path / "out"
    robot = tmp_path / "driven.yaml"  # the nominal robot with actuators: same mechanics
    robot.write_text((REPO / "ctrplan" / "data" / "nominal.yaml").read_text() + ACTUATORS)
    rc, out, err = run_cli(["plan", str(SCENES / "open.yaml"), "--backend", "cosserat", "--seed", "0",
                            "--time-limit", "8", "--out", str(out_dir), "--json", "--robot", str(robot),
                            "--rate", "20"], capsys)
    assert rc == 0, err
    doc = json.loads(out)
    for key in ("solved", "planner", "backend", "planning_time_s", "kinematics_calls", "path", "tip_mm",
                "target_mm", "goal_tolerance_mm", "base_pose", "validated"):
        assert key in doc
    assert doc["solved"] and doc["planner"] == "corridor" and doc["backend"] == "cosserat"
    v = doc["validated"]
    assert v["backend"] == "cosserat" and v["collision_free"] is True
    assert v["min_clearance_mm"] > 0 and v["max_position_error_mm"] == 0.0
    assert np.allclose(doc["path"][0], [-80, -65, -10, 0, 0, 0])
    assert np.linalg.norm(np.subtract(doc["tip_mm"], doc["target_mm"])) <= doc["goal_tolerance_mm"]
    assert np.allclose(doc["base_pose"], np.eye(4))
    assert doc["kinematics_calls"] > 0
    for name in ("path.json", "obstacles.ply", "plan.png", "plan.html"):
        assert (out_dir / name).stat().st_size > 1000
    full = json.loads((out_dir / "path.json").read_text())
    assert len(full["backbones_mm"]) == len(full["dense_path"]) > len(full["path"])
    assert np.array(full["backbones_mm"]).shape[1:] == (30, 3)
    mesh = trimesh.load(out_dir / "obstacles.ply", force="mesh")
    assert len(mesh.faces) == len(load_scene(SCENES / "open.yaml").merged_obstacles().faces)
    html = (out_dir / "plan.html").read_text()
    assert "<canvas" in html and not re.search(r"(src|href)\s*=\s*[\"']?(https?:)?//", html)
    data = re.search(r'<script id="data" type="application/json">(.*?)</script>', html, re.S).group(1)
    assert len(json.loads(data)["backbones"]) == len(full["dense_path"])
    assert not [p for p in out_dir.iterdir() if p.name.startswith(".")]  # no temporary leftovers
    assert_trajectory_within_limits(out_dir / "trajectory.csv", full, load_scene(SCENES / "open.yaml"))
    assert_structure_clearances(v["structures"], full)


def assert_structure_clearances(listed: list[dict], full: dict) -> None:
    """``validated.structures`` of open.yaml: the ball and the block, none below its 0.2 mm, the ball's
    clearance the closed-form capsule-chain distance (segment to sphere centre, minus the radii)
    over path.json's exact backbones, on the state where it is smallest; the overall minimum is
    ``min_clearance_mm``."""
    by_name = {c["name"]: c for c in listed}
    assert set(by_name) == {"ball", "block"}
    assert not any(c["below_margin"] for c in listed)
    assert all(c["required_mm"] == 0.2 and c["margin_mm"] == 0.0 for c in listed)
    p = np.array(full["backbones_mm"])                 # (K, N, 3), scene frame = robot frame here
    r = np.array(full["backbone_radius_mm"])
    a, d = p[:, :-1], p[:, 1:] - p[:, :-1]
    c = np.array([43.0, -47.0, 150.0])
    t = np.clip(np.einsum("kmi,kmi->km", c - a, d) / np.einsum("kmi,kmi->km", d, d), 0.0, 1.0)
    gap = np.linalg.norm(a + t[..., None] * d - c, axis=-1) - 7.0 - np.maximum(r[:, :-1], r[:, 1:])
    ball = by_name["ball"]
    assert ball["clearance_mm"] == pytest.approx(gap.min(), abs=1e-3)
    assert gap[ball["state"]].min() == pytest.approx(gap.min(), abs=1e-3)
    assert np.linalg.norm(np.subtract(ball["structure_point_mm"], c)) == pytest.approx(7.0, abs=1e-3)
    assert min(x["clearance_mm"] for x in listed) == pytest.approx(full["validated"]["min_clearance_mm"],
                                                                  abs=1e-4)


def assert_trajectory_within_limits(path, full: dict, scene) -> None:
    """trajectory.csv at 20 Hz: rows 0.05 s apart from rest at the start to rest at the goal; the
    velocity columns the finite differences of the joints, within the robot's speed limits, their
    changes within its acceleration limits (all computed here); the actuator columns the robot
    file's map; tips of the exact model (recomputed here); no row in contact."""
    lines = path.read_text().splitlines()
    assert lines[0] == ("time_s,beta1,beta2,beta3,alpha1,alpha2,alpha3,beta1_mm_per_s,beta2_mm_per_s,"
                        "beta3_mm_per_s,alpha1_rad_per_s,alpha2_rad_per_s,alpha3_rad_per_s,stage1,"
                        "alpha3_counts,stage1_per_s,alpha3_counts_per_s,tip_x,tip_y,tip_z,clearance_mm")
    rows = np.array([[float(v) for v in line.split(",")] for line in lines[1:]])
    t, q, qd, act, tip, clearance = (rows[:, 0], rows[:, 1:7], rows[:, 7:13], rows[:, 13:17], rows[:, 17:20],
                                     rows[:, 20])
    np.testing.assert_allclose(np.diff(t)[:-1], 0.05, atol=1e-6)  # the last row is the end itself
    np.testing.assert_allclose(q[[0, -1]], np.array(full["path"])[[0, -1]], atol=1e-5)
    np.testing.assert_allclose(qd[[0, -1]], 0.0, atol=1e-9)
    speed, accel = scene.robot.limits.per_joint(3)
    assert np.all(np.abs(qd) <= speed * (1 + 1e-6))
    assert np.all(np.abs(np.diff(qd, axis=0)) / np.diff(t)[:, None] <= accel * (1 + 1e-3))
    mid = 0.5 * (qd[1:] + qd[:-1])  # trapezoid rule: exact for linear velocity, off by a dt^2 / 4 at a kink
    err = np.abs(np.diff(q, axis=0) - mid * np.diff(t)[:, None])
    assert np.all(err <= accel * 0.05**2 / 4 + 1e-6)
    np.testing.assert_allclose(act[:, 0], -1000 * q[:, 0] + 80000, atol=1e-3)
    np.testing.assert_allclose(act[:, 1], 651.9 * q[:, 5] + 12, atol=1e-3)
    np.testing.assert_allclose(act[:, 2], -1000 * qd[:, 0], atol=1e-3)
    exact = CosseratBackend(scene.robot).forward(q[::10], points=2).tip_mm
    np.testing.assert_allclose(tip[::10], exact, atol=1e-3)
    assert clearance.min() > 0.0


MINI = """\
robot: nominal
base_pose: {position: [0, 0, 0]}
obstacles:
  - {name: ball, sphere: {center: [0, -49.6, 112.3], radius: 3}}
  - {name: wall, mesh: wall.stl}
target: {point: [37.2, -27.2, 181.6], tolerance_mm: 3}
start: [-80, -65, -10, 0, 0, 0]
"""


@pytest.fixture()
def mini_dir(tmp_path):
    m = trimesh.creation.box(extents=[10, 10, 1])
    m.apply_translation([100, 100, 0])
    m.export(tmp_path / "wall.stl")
    return tmp_path


def test_cli_start_in_collision_is_bad_input(mini_dir, capsys):
    (mini_dir / "s.yaml").write_text(MINI)
    rc, out, err = run_cli(["plan", str(mini_dir / "s.yaml"), "--json"], capsys)
    assert rc == 2 and out == ""
    assert err.count("\n") == 1 and re.search(r"s\.yaml:7: start: .*collision with ball", err)


def test_cli_missing_mesh_and_malformed_scene(mini_dir, capsys):
    (mini_dir / "s.yaml").write_text(MINI.replace("wall.stl", "gone.stl"))
    rc, out, err = run_cli(["plan", str(mini_dir / "s.yaml")], capsys)
    assert rc == 2 and out == ""
    assert re.search(r"s\.yaml:5: obstacles\[1\]\.mesh: mesh file not found", err)
    (mini_dir / "t.yaml").write_text(MINI.replace("radius: 3}}", "radius: [3]}}"))
    rc, out, err = run_cli(["plan", str(mini_dir / "t.yaml")], capsys)
    assert rc == 2 and re.search(r"t\.yaml:4: obstacles\[0\]\.sphere\.radius: expected a finite number", err)
    (mini_dir / "s.yaml").write_text(MINI)
    rc, out, err = run_cli(["plan", str(mini_dir / "s.yaml"), "--planner", "prm"], capsys)
    assert rc == 2 and out == "" and err.count("\n") == 1
    assert "planner: unknown planner 'prm' (choose from corridor, rrtconnect, rrt, rrtstar" in err


def test_cli_unreachable_target(mini_dir, capsys):
    # out of the robot's length: bad input (exit 2) naming the target key and line
    far = MINI.replace("center: [0, -49.6, 112.3]", "center: [50, 50, 50]")
    (mini_dir / "far.yaml").write_text(far.replace("point: [37.2, -27.2, 181.6]", "point: [0, 0, 300]"))
    rc, out, err = run_cli(["plan", str(mini_dir / "far.yaml")], capsys)
    assert rc == 2 and re.search(r"far\.yaml:6: target: out of reach", err)
    # within the length but not reachable (behind the front plate): not solved (exit 1)
    (mini_dir / "near.yaml").write_text(far.replace("point: [37.2, -27.2, 181.6]", "point: [0, 0, -60]"))
    rc, out, err = run_cli(["plan", str(mini_dir / "near.yaml"), "--backend", "cosserat", "--json",
                            "--time-limit", "6"], capsys)
    assert rc == 1, out
    doc = json.loads(out)
    assert doc["solved"] is False and doc["path"] == [] and "unreachable" in doc["message"]


# ---- the clock --------------------------------------------------------------------------------------
class SlowFirstCall(Backend):
    """The PINN, but its first single and first batched call take 2 s more each -- like cold numba
    compiles of its single-query and batched kernels."""

    name = "pinn-cold"

    def __init__(self, inner: Backend):
        super().__init__(inner.robot)
        self.inner = inner
        self.compiled: set[bool] = set()

    def forward(self, q, points=DEFAULT_POINTS, *, guess=None, check=True):
        batched = np.atleast_2d(q).shape[0] > 1
        if batched not in self.compiled:
            self.compiled.add(batched)
            time.sleep(2.0)
        return self.inner.forward(q, points, check=check)


def test_compilation_is_outside_the_time_limit(open_scene):
    cold = SlowFirstCall(resolve_backend("pinn", open_scene.robot))
    res = plan(open_scene, cold, seed=0, time_limit_s=1.5)
    assert res.solved, res.message
    assert res.work.compile_s >= 4.0
    assert res.planning_time_s < 4.0 and not res.cut_short  # the 4 s of compiling are not in it


def test_a_tiny_budget_ends_the_search_by_work_not_by_the_clock(open_scene, exact):
    """A work budget of 5 exact states (what 1 ms buys), no time limit: the first goal-sampling batch
    (hundreds of states) uses them up. The work budget decides (the 30 ms guard has passed too, but
    work is checked first), so the verdict does not depend on the machine."""
    res = plan(open_scene, exact, seed=0, time_limit_s=0.001, max_states=5)
    assert not res.solved and res.status == "TIMEOUT"
    assert res.max_states == 5 and "budget used up while sampling goal configurations" in res.message
    assert res.states >= 5 and not res.cut_short


def test_library_resolve_backend_does_not_fall_back(tmp_path):
    from importlib import resources

    from ctrplan.base.errors import InputError
    from ctrplan.model.robot import Robot
    from ctrplan.planning import resolve_backend

    text = resources.files("ctrplan.data").joinpath("nominal.yaml").read_text()
    (tmp_path / "r.yaml").write_text(text.replace("curvature_1_per_m: 28.0", "curvature_1_per_m: 30.0")
                                     .replace("name: nominal", "name: r"))
    other = Robot.load(str(tmp_path / "r.yaml"))  # the shipped PINNs were trained for other robots
    with pytest.raises(InputError) as info:
        resolve_backend(None, other)
    message = str(info.value)  # names this robot, where it looked and how to train one; no other model
    assert message.startswith("no PINN model trained for robot 'r' (fingerprint ")
    assert str(Path("models").resolve()) in message and "shipped models (pinn_nominal" in message
    assert "ctrplan train --robot ROBOT.yaml --name r_pinn" in message and "'nominal'" not in message
    assert resolve_backend("cosserat", other).name == "cosserat"
