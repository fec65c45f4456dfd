"""Is a scene usable for planning? Checks that find, before any search, what would otherwise cost a
planner its whole time budget or give a meaningless "solved".

1. **Scale**, per obstacle: its extent against the robot's length and the other obstacles (a mesh
   in metres is 1000x too small and lies near the origin, in micrometres 1000x too large). Found,
   it ends the check (the rest would judge the wrong anatomy): as fast as `plan` says it.
2. **Orientation**: mirrored or turned anatomy (`_check_orientation`); found, it ends the check too.
3. **Target inside an obstacle**: the target region lies wholly inside a closed obstacle (named).
4. **Target out of reach**: no sampled configuration of the robot puts its tip in (or near) the
   target from this base pose (the closest distance is reported).
5. **Start**: outside the joint domain, in collision under the exact model (naming what it hits),
   not converged or elastically unstable. The nearest valid start from which the exact model plans
   to the target is proposed (`reaching_start`: candidates of `start_candidates`, the start's own
   translations and the fully retracted ones, every tube turned by 1/8 turns, nearest in the planning
   metric first; a start that is merely collision-free may leave the robot outside the anatomy:
   `ctrplan.planning.start_fix`), or the command says that none of the nearest is one; `plan`
   proposes the nearest valid one without searching.
6. **Planner**: the scene names a planner of `ctrplan.planning.planners.PLANNERS`.

`check_scene` returns the problems found; `plan` and `ctrplan scene check` report the same lines.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace

import numpy as np

from ctrplan.base.errors import InputError
from ctrplan.kinematics import CosseratBackend
from ctrplan.kinematics.backbone import Backbone
from ctrplan.planning.model import PlanningModel
from ctrplan.planning.planners import scene_planner
from ctrplan.planning.space import BoxSpace
from ctrplan.planning.validity import ConfigurationChecker
from ctrplan.scene.objects import Scene
from ctrplan.scene.orientation import anatomy_code, flip_verdict, side_pairs

#: Obstacles spanning less than this fraction of the robot's length, or more than this multiple of
#: it, are reported as a likely unit error.
SCALE_TOO_SMALL = 0.02
SCALE_TOO_LARGE = 100.0
#: Without obstacles of a plausible size, a small one is in metres if it lies this many robot
#: lengths from the origin or closer once taken 1000 times larger.
WORKSPACE_ROBOT_LENGTHS = 10.0
#: Configurations sampled (seeded) for the reachability check, and the closest of them from which
#: inverse kinematics tries the target before it is called unreachable.
REACH_SAMPLES = 4000
REACH_IK_SEEDS = 16
#: Tube rotations tried for a start: multiples of 1/START_TURNS turn.
START_TURNS = 8
#: Candidate starts checked per batched call.
START_CHUNK = 64


@dataclass(frozen=True)
class SceneProblem:
    """One thing that makes a scene unusable: ``kind`` is scale | orientation | target | reach | start
    | planner."""

    kind: str
    message: str


@dataclass
class SceneCheck:
    """What `check_scene` found: the problems (empty: usable), facts for a summary, and a valid
    start (joints, mm and rad) when the scene's start is not one."""

    problems: list[SceneProblem] = field(default_factory=list)
    facts: dict[str, str] = field(default_factory=dict)
    fixed_start: np.ndarray | None = None

    @property
    def usable(self) -> bool:
        return not self.problems


def check_scene(scene: Scene, *, samples: int = REACH_SAMPLES, seed: int = 0, reach: bool = True,
                model: PlanningModel | None = None, start_backbone: Backbone | None = None,
                start_fix: StartFixer | None = None) -> SceneCheck:
    """Run every check on ``scene`` (its start may lie outside the domain: see
    `ctrplan.scene.loader.load_scene(..., check_start=False)`). ``reach=False`` skips the sampled
    reachability check (seconds; `plan` runs the others, which take milliseconds, before every
    search). ``model``: the plan's `PlanningModel` (its exact backend, with the stability decision,
    judges the start; its collision world is reused); default: one of the exact model.
    ``start_backbone``: that backend's backbone of the start at the model's points, if solved
    already (`plan` solves it when it compiles the kernels). ``start_fix``: how to find a start
    that replaces a bad one (`ctrplan.planning.start_fix.reaching_start`: the nearest valid start
    from which a search reaches the target; default: the nearest valid one, not searched from).
    Obstacles of the wrong scale or
    orientation end the check there: every later answer would be about the wrong anatomy."""
    report = SceneCheck()
    robot_mm = float(scene.robot.lengths_mm[0] + scene.robot.domain.box_upper[0])
    _check_scale(scene, robot_mm, report)
    if not report.problems:
        _check_orientation(scene, report)
    if report.problems:
        report.facts["other checks"] = f"skipped until the {report.problems[0].kind} is fixed"
        return report
    _check_target_inside(scene, report)
    if reach:
        _check_reach(scene, samples, seed, report)
    _check_start(scene, report, model or PlanningModel.of(scene), start_backbone, start_fix, seed)
    try:
        scene_planner(scene)
    except InputError as exc:
        report.problems.append(SceneProblem("planner", str(exc)))
    return report


def _check_scale(scene: Scene, robot_mm: float, report: SceneCheck) -> None:
    """Each obstacle on its own: one spanning more than `SCALE_TOO_LARGE` robot lengths is in
    micrometres; one spanning less than `SCALE_TOO_SMALL` of the robot's length is in metres when,
    taken 1000 times larger, it would be no larger than twice the largest obstacle of a plausible
    size, or would lie among those (or, without any, within `WORKSPACE_ROBOT_LENGTHS` of the
    origin), or when all obstacles together are that small -- a small structure drawn in mm among
    others is neither."""
    if not scene.obstacles:
        report.facts["obstacles"] = "none"
        return
    bounds = np.stack([o.bounds for o in scene.obstacles])
    extents = np.linalg.norm(bounds[:, 1] - bounds[:, 0], axis=1)
    extent = float(np.linalg.norm(bounds[:, 1].max(axis=0) - bounds[:, 0].min(axis=0)))
    report.facts["obstacles"] = f"{len(scene.obstacles)}, spanning {extent:.1f} mm"
    small, large = extents < SCALE_TOO_SMALL * robot_mm, extents > SCALE_TOO_LARGE * robot_mm
    plausible = ~small & ~large
    if plausible.any():  # where the anatomy is, give or take a robot length
        span = float(extents[plausible].max())
        near = np.stack([bounds[plausible, 0].min(axis=0) - robot_mm,
                         bounds[plausible, 1].max(axis=0) + robot_mm])
        others = f"the other obstacles span {extents[plausible].min():.0f}-{span:.0f} mm"
    else:
        span, near = 0.0, np.stack([np.full(3, -1.0), np.full(3, 1.0)]) * WORKSPACE_ROBOT_LENGTHS * robot_mm
        others = f"the robot is {robot_mm:.0f} mm long"
    tiny_scene = extent < SCALE_TOO_SMALL * robot_mm  # every obstacle together is small
    for i, obstacle in enumerate(scene.obstacles):
        where = f"{scene.where(f'obstacles.{i}')} ({obstacle.name})"
        fix = "its 'scale:'" if obstacle.kind == "mesh" else "its sizes"
        scaled = 1000.0 * bounds[i]
        if large[i]:
            report.problems.append(SceneProblem(
                "scale", f"{where}: spans {extents[i]:.3g} mm but the robot is {robot_mm:.0f} mm long: a "
                         f"mesh in micrometres? (multiply {fix} by 0.001; none means 1)"))
        elif small[i] and (1000.0 * extents[i] <= 2.0 * span or tiny_scene
                           or (np.all(scaled[0] <= near[1]) and np.all(scaled[1] >= near[0]))):
            report.problems.append(SceneProblem(
                "scale", f"{where}: spans {extents[i]:.3g} mm; {others}: a mesh in metres? (multiply {fix} "
                         f"by 1000; none means 1)"))


def _check_orientation(scene: Scene, report: SceneCheck) -> None:
    """Mirrored or turned anatomy (`ctrplan.scene.orientation`): mesh files that declare different
    frames in a scene that declares none, or pairs of structures named for opposite sides lying the
    wrong way round along the scene's `anatomy` axes."""
    declared = sorted({o.space for o in scene.obstacles if o.space})
    if scene.anatomy is None:
        if len(declared) > 1:
            report.problems.append(SceneProblem(
                "orientation", f"{scene.where('obstacles')}: the mesh files declare different frames "
                               f"({', '.join(f'{o.name}: {o.space}' for o in scene.obstacles if o.space)}) "
                               f"and the scene declares none: some are mirrored or turned against the "
                               f"others; add `anatomy:` and every file is converted to it"))
        report.facts["orientation"] = "not checked (the scene has no `anatomy:` key)"
        return
    centroids = {o.name: o.bounds.mean(axis=0) for o in scene.obstacles}
    pairs = side_pairs(centroids, scene.anatomy)
    verdict = flip_verdict(pairs, scene.anatomy)
    if verdict is not None:
        report.problems.append(SceneProblem("orientation", f"{scene.where('obstacles')}: {verdict}"))
        return
    converted = f"; mesh files in {', '.join(declared)} converted to {anatomy_code(scene.anatomy)}" \
        if set(declared) - {anatomy_code(scene.anatomy)} else ""
    report.facts["orientation"] = (f"{len(pairs)} pair(s) of sided structures on their sides "
                                   f"({', '.join(f'{p.positive}/{p.negative}' for p in pairs)})" if pairs else
                                   "no pair of sided structures (left_/right_ ...) to check") + converted


def _check_target_inside(scene: Scene, report: SceneCheck) -> None:
    """A target region whose centre is inside a closed obstacle, deeper than the region's largest
    semi-axis, cannot be reached by a tip outside every obstacle."""
    import trimesh

    target = scene.target
    depth_needed = float(np.max(target.semi_axes))
    for obstacle in scene.obstacles:
        mesh = obstacle.to_trimesh().copy()
        mesh.merge_vertices()  # STL files repeat each vertex per triangle: closed only once merged
        if not mesh.is_watertight:
            continue  # an open surface has no inside
        pq = trimesh.proximity.ProximityQuery(mesh)
        depth = float(pq.signed_distance(target.center[None])[0])  # > 0 inside
        if depth > depth_needed:
            report.problems.append(SceneProblem(
                "target", f"{scene.where('target')}: the target region lies inside the obstacle "
                          f"{obstacle.name!r} ({depth:.1f} mm deep)"))


def _check_reach(scene: Scene, samples: int, seed: int, report: SceneCheck) -> None:
    """Sample the domain; if no tip lands in the target, run inverse kinematics (exact model, no
    obstacles) from the closest samples toward the target's centre before calling it unreachable."""
    from ctrplan.planning.ik import backend_tip_jacobian, solve_ik
    from ctrplan.planning.space import BoxSpace

    robot = scene.robot
    exact = CosseratBackend(robot)
    q = robot.sample_joints(samples, np.random.default_rng(seed))
    bb = exact.forward(q, points=2, check=False)
    q, tips = q[bb.converged], scene.to_scene(bb.tip_mm[bb.converged])
    gap = scene.target.distance(tips)
    inside = int(np.count_nonzero(gap <= 0.0))
    report.facts["reach"] = f"{inside} of {samples} sampled configurations put the tip in the target"
    if inside or not len(q):
        return
    space = BoxSpace.for_scene(scene)
    seeds = q[np.argsort(gap)[:REACH_IK_SEEDS]]
    goal = scene.to_robot(scene.target.center[None])[0]
    ik = solve_ik(backend_tip_jacobian(exact, space), space, seeds, goal, max_iterations=60)
    closest = scene.target.distance(scene.to_scene(ik.tip[np.isfinite(ik.error_mm)]))
    best = float(min(closest.min(initial=np.inf), gap.min()))
    if best <= 0.0:
        report.facts["reach"] += "; inverse kinematics reaches it"
        return
    report.problems.append(SceneProblem(
        "reach", f"{scene.where('target')}: no configuration of the robot puts its tip in the target from "
                 f"this base pose ({samples} sampled, inverse kinematics from the {len(seeds)} closest: "
                 f"closest {best:.1f} mm)"))


def _check_start(scene: Scene, report: SceneCheck, model: PlanningModel, bb: Backbone | None,
                 start_fix: StartFixer | None, seed: int) -> None:
    """The start's problem, if any, with the fix: with ``start_fix``, the start it finds (the
    nearest valid one from which the exact model plans to the target), or why there is none;
    without (`plan`'s quick checks), the nearest valid start, not searched from."""
    robot = scene.robot
    where = scene.where("start")
    lo, hi = scene.joint_box
    space = BoxSpace.for_scene(scene)
    try:
        robot.check_joints(scene.start, where="start")
        problem = None if space.contains(scene.start) else f"{where}: outside the scene's joint_limits"
    except InputError as exc:
        problem = f"{where}: {str(exc).removeprefix('start: ').removeprefix('row 0: ')}"
    box = robot.domain.to_box(space.to_joints(space.clip(space.to_coords(scene.start))))
    inside = replace(scene, start=robot.domain.from_box(np.clip(box, lo, hi)))
    checker = ConfigurationChecker(model.exact_search().with_scene(inside))
    if problem is None:
        problem = start_problem(scene, checker, bb)
    if problem is None:
        report.facts["start"] = "valid"
        return
    if start_fix is None:
        fixed = valid_start(inside, checker)
        report.problems.append(SceneProblem("start", f"{problem}; " + (
            "no valid start found near it" if fixed is None else
            f"nearest valid start: {np.round(fixed, 4).tolist()} (not searched from: `ctrplan scene check "
            f"--fix OUT.yaml` finds one from which the target is reached)")))
        return
    found = start_fix(inside, checker, seed)
    if found.start is None:
        why = "no valid start found near it" if not found.tried else (
            f"no fix: from none of the {found.tried} nearest valid starts does the exact model reach the "
            f"target ({found.states_each:,} states searched from each); move the base pose or the start "
            f"nearer the entry")
        report.problems.append(SceneProblem("start", f"{problem}; {why}"))
        return
    report.fixed_start = found.start
    report.problems.append(SceneProblem(
        "start", f"{problem}; nearest valid start: {np.round(found.start, 4).tolist()} (the exact model "
                 f"plans from it to the target: {found.tried} candidate(s) searched from, {found.states:,} "
                 f"states)"))


def start_problem(scene: Scene, checker: ConfigurationChecker, bb: Backbone | None = None) -> str | None:
    """Why the scene's start cannot begin a plan under ``checker``'s exact model: not converged,
    unstable, or in collision (naming the obstacles, with the scene's margin); None if it can.
    ``bb``: the start's backbone under that model (solved here if not given)."""
    if bb is None:
        bb = checker.backend.forward(scene.start, points=checker.points, check=False)
    where = scene.where("start")
    if not bb.converged[0]:
        return f"{where}: the exact model does not converge at the start configuration"
    if not bb.stable[0]:
        return f"{where}: the start configuration is elastically unstable (the robot snaps there)"
    contacts = checker.collision.contacts(bb.positions_mm[0], bb.radius_mm[0])
    if contacts:
        own = {o.name: o.margin_mm for o in scene.obstacles}  # per-structure margins, where set
        names = ", ".join(f"{n} (its own margin {own[n]:g} mm)" if own.get(n) else n
                          for n in sorted({n for _, n in contacts}))
        return (f"{where}: the start configuration is in collision with {names} "
                f"(scene margin {scene.settings.margin_mm:g} mm)")
    return None


@dataclass(frozen=True)
class StartFix:
    """What `reaching_start` found: a start (joints, mm and rad) or None, how many valid candidates
    it searched from, the states the successful search used and the budget of each."""

    start: np.ndarray | None
    tried: int
    states: int
    states_each: int


#: Finds a start to replace a bad one: (scene with the start clipped into the box, its exact
#: checker, seed) -> `StartFix`.
StartFixer = Callable[[Scene, ConfigurationChecker, int], StartFix]


def start_candidates(scene: Scene, space: BoxSpace) -> np.ndarray:
    """Candidate starts near the scene's (joints (C, 2N)), nearest in the planning metric first
    (wrapping rotations the short way): its translations and the fully retracted ones (``betaN``
    lowest, differences largest), each with every rotatable tube turned by multiples of
    1/`START_TURNS` turn (wrapped into its interval)."""
    robot = scene.robot
    n = robot.n_tubes
    lo, hi = scene.joint_box
    box0 = robot.domain.to_box(scene.start)
    retracted = np.concatenate([[lo[0]], hi[1:n]])
    angles = []
    for c in range(n, 2 * n):
        if hi[c] > lo[c]:
            turns = box0[c] + np.arange(START_TURNS) * (hi[c] - lo[c]) / START_TURNS
            angles.append(lo[c] + np.mod(turns - lo[c], hi[c] - lo[c]))
        else:
            angles.append(np.array([box0[c]]))
    rows = [np.concatenate([t, a]) for t in (box0[:n], retracted) for a in itertools.product(*angles)]
    cands = robot.domain.from_box(np.array(rows))
    dist = space.distance(cands, scene.start[None])
    return cands[np.argsort(dist, kind="stable")]


def valid_starts(scene: Scene, checker: ConfigurationChecker) -> Iterator[np.ndarray]:
    """The valid `start_candidates` under ``checker``, nearest first (checked `START_CHUNK` at a
    time)."""
    cands = start_candidates(scene, checker.space)
    for a in range(0, len(cands), START_CHUNK):
        chunk = cands[a:a + START_CHUNK]
        yield from chunk[checker.check(chunk).astype(bool)]


def valid_start(scene: Scene, checker: ConfigurationChecker) -> np.ndarray | None:
    """A start near the scene's that is valid under ``checker`` (a design's start; the quick fix
    `plan` proposes): the scene's start if valid, else the nearest valid of `start_candidates`. None
    when no candidate is valid."""
    return next(valid_starts(scene, checker), None)
