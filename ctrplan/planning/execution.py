"""``trajectory.csv``: what a controller executes (issue 41, item 11).

The validated path is timed within the robot's joint limits without stopping at waypoints where the
exact model allows (`ctrplan.planning.trajectory.executed_trajectory`: blends checked with the exact
model at the planner's resolution, a waypoint whose blend fails becomes a stop), then sampled at a
fixed rate. Each row: ``time_s``, the joints (mm, rad), their velocities (``beta1_mm_per_s`` ...,
``alpha1_rad_per_s`` ...), the robot file's actuators (``actuators:``: value and rate in counts,
`ctrplan.model.actuators`), the exact tip (scene frame, mm) and the exact model's clearance to the
nearest obstacle (mm, capped).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ctrplan.collision.checker import RobotCollisionChecker
from ctrplan.collision.world import CollisionWorld
from ctrplan.kinematics.backbone import Backbone
from ctrplan.planning.model import PlanningModel
from ctrplan.planning.trajectory import Trajectory, executed_trajectory, sample_times
from ctrplan.planning.validate import CLEARANCE_CAP_MM
from ctrplan.planning.validity import ConfigurationChecker
from ctrplan.scene.objects import Scene

#: trajectory.csv's rows per second when no rate is given.
DEFAULT_RATE_HZ = 50.0


def scene_trajectory(scene: Scene, path_q: np.ndarray, world: CollisionWorld | None = None) -> Trajectory:
    """The executed trajectory of a validated path (joints (K, 2N)) in ``scene``: blends checked
    with the exact model (the scene's margins, stability) at the scene's resolution."""
    checker = ConfigurationChecker(PlanningModel.of(scene, world=world))
    space = checker.space

    def spacing(q: np.ndarray) -> np.ndarray:
        return space.distance(q[:-1], q[1:])

    return executed_trajectory(path_q, scene.robot.limits, lambda q: checker.check(q).astype(bool), spacing,
                               scene.settings.resolution_mm)


@dataclass(frozen=True)
class TrajectoryTable:
    """``trajectory.csv`` computed: its column names, its rows (T, C) at ``rate_hz`` rows per second
    (see the module docstring), and the trajectory they sample."""

    header: list[str]
    rows: np.ndarray
    rate_hz: float
    trajectory: Trajectory


def trajectory_table(scene: Scene, path_q: np.ndarray, rate_hz: float = DEFAULT_RATE_HZ,
                     world: CollisionWorld | None = None) -> TrajectoryTable:
    """The trajectory of a validated path (joints (K, 2N)) sampled at ``rate_hz``; ``world``: the
    scene's collision world if built already."""
    robot = scene.robot
    world = world or CollisionWorld.from_scene(scene)
    traj = scene_trajectory(scene, path_q, world)
    t = sample_times(traj.duration_s, rate_hz)
    q, qd = traj.at(t)
    model = PlanningModel.of(scene, world=world)
    bb = model.exact.forward(q, points=scene.settings.points, check=False)
    clearance = row_clearances(scene, bb, world)
    n = robot.n_tubes
    rates = [f"{name}_mm_per_s" if i < n else f"{name}_rad_per_s" for i, name in enumerate(robot.joint_names)]
    actuators = [a.name for a in robot.actuators] + [f"{a.name}_per_s" for a in robot.actuators]
    header = ["time_s", *robot.joint_names, *rates, *actuators, "tip_x", "tip_y", "tip_z", "clearance_mm"]
    columns = [t[:, None], q, qd] + [a.position(q)[:, None] for a in robot.actuators] \
        + [a.rate(qd)[:, None] for a in robot.actuators] + [scene.to_scene(bb.tip_mm), clearance[:, None]]
    return TrajectoryTable(header, np.column_stack(columns), float(rate_hz), traj)


def row_clearances(scene: Scene, bb: Backbone, world: CollisionWorld) -> np.ndarray:
    """The exact model's clearance (mm, no margin, 0 in contact, capped at `CLEARANCE_CAP_MM`) of
    each backbone (K,) (robot frame); NaN where one did not converge. One nearest-obstacle-first
    distance query per row (a third of the cost of every capsule's own distance)."""
    checker = RobotCollisionChecker(world, scene.base_pose, bb.positions_mm.shape[1])
    return np.array([min(checker.clearance(p, r).distance_mm, CLEARANCE_CAP_MM) if ok else np.nan
                     for p, r, ok in zip(bb.positions_mm, bb.radius_mm, bb.converged, strict=True)])
