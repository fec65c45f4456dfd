"""Place the robot at an entry point (issue 41, item 4): a base pose and a start that enter the
anatomy through the entry (e.g. the nostril) and from which a plan reaches the target.

An engineer puts the robot outside the body, its insertion axis roughly along the line from the entry
to the target, so that the tubes, pushed in, pass through the opening and end in the target. Searching
base poses first and asking afterwards whether the target can be reached wastes most of the effort
(a straight line through a nostril is rarely a curved robot's way); `place_robot` starts from the goal:

1. **Goals** (robot frame): `REACH_SAMPLES` configurations sampled in the joint box, solved with the
   exact model (unconverged and unstable dropped). On each backbone the point whose chord to the tip is
   as long as the distance entry -> target is found (none: the robot is too short there).
2. **Placements**: each such backbone is put with its tip at the target's centre and that point at the
   entry (the chord along the line entry -> target, a random roll about it), then moved across the line
   by up to `ENTRY_SLACK_MM` (an opening is wider than a point); bases whose insertion axis turns more
   than `MAX_TILT_DEG` from the line are dropped (the robot stays outside, in front of the opening).
   Every placed goal backbone is screened at once by the collision world's distance grid (its clearance
   beyond every margin estimated from the grid, interpolated); FCL judges the best 200 and measures the
   free ones' clearance.
3. **Starts**: for the `GOALS_KEPT` best free goals (clearance capped at `CLEARANCE_CAP_MM`, then
   tilt), the goal pulled back along its own insertion (translations moved towards fully retracted,
   rotations kept, `RETRACTIONS`), with its tip still `START_DEPTH_MM` past the entry (the robot
   already through the opening): the most retracted that is free and stable, with
   `START_CLEARANCE_MM` to spare where some has (a *retracted* start: the plan must find the way in),
   and the most retracted from which every pull-back state on to the goal is free and stable (a
   *pulled-back* start: a straight way in is known; in a tight airway it may lie near the goal).
4. **Verification**: the retracted starts of the `RETRACTED_TRIES` best placements, then the
   pulled-back starts of the best (`VERIFY` plans in all), are planned (`ctrplan.planning.plan`, a
   work budget, seeded, the goal as a hint) until a retracted start or `ACCEPT` starts are solved -- a
   path the exact model confirms into the target; a solved retracted start is chosen first, else the
   solved start whose path keeps the largest clearance.

Nothing found is a one-line reason: the robot's reach against the distance, what the nearest-to-free
placements touch (structures, counts), or what the verification plans said.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from dataclasses import dataclass, replace

import numpy as np
from scipy import ndimage
from scipy.spatial.transform import Rotation

from ctrplan.base.errors import InputError
from ctrplan.collision.checker import RobotCollisionChecker
from ctrplan.collision.world import CollisionWorld
from ctrplan.kinematics.base import Backend
from ctrplan.planning.model import exact_backend
from ctrplan.planning.planner import plan
from ctrplan.planning.result import PlanResult
from ctrplan.planning.space import BoxSpace
from ctrplan.scene.objects import Scene

#: Configurations sampled for the goals, and backbone points of each.
REACH_SAMPLES = 3000
POINTS = 40
#: Refinement: rounds, placements nearest to free kept per round, perturbed children of each, and the
#: perturbation's size (mm in the planning metric).
REFINE_ROUNDS = 8
ELITE = 100
CHILDREN = 10
REFINE_STEP_MM = 2.0
#: Each round's perturbation is this fraction of the previous one's.
REFINE_SHRINK = 0.8
#: How far (mm) a placement's backbone may pass beside the entry point and its tip beside the target's
#: centre (an opening is wider than a point).
ENTRY_SLACK_MM = 2.0
#: Insertion axes turned further than this (degrees) from the line entry -> target are not used.
MAX_TILT_DEG = 35.0
#: Clearances beyond this (mm) rank equal.
CLEARANCE_CAP_MM = 2.0
#: Points per backbone segment where the distance grid estimates the clearance.
SUBSTEPS = 8
#: Free goals whose starts are sought.
GOALS_KEPT = 40
#: Fractions of the goal's insertion kept by the candidate starts (0: fully retracted), and how far (mm,
#: along the line) a start's tip must lie past the entry.
RETRACTIONS = tuple(np.arange(0.0, 1.0, 0.05))
START_DEPTH_MM = 3.0
#: A retracted start keeps at least this clearance (mm, beyond the margins) where some does: a
#: surrogate plans with its error bound as extra margin.
START_CLEARANCE_MM = 0.5
#: Placements planned at most, and solved ones after which it stops.
VERIFY = 4
ACCEPT = 2
RETRACTED_TRIES = 1
#: Work budget of a verification plan: seconds of search on the reference machine (states from the
#: backend's reference rate, `ctrplan.planning.budget`).
VERIFY_TIME_S = 4.0


@dataclass(frozen=True)
class Candidate:
    """One placement: base pose (4x4, scene frame), start and goal (joints, mm and rad), the insertion
    axis's tilt from the line entry -> target (degrees), how far the start's tip lies past the entry
    (mm along the line), the base's distance to the entry (mm), the goal's and the start's clearance
    beyond every margin as the grid bounds them (mm, capped at `CLEARANCE_CAP_MM`), and -- once
    planned -- the verification plan."""

    base_pose: np.ndarray
    start: np.ndarray
    goal: np.ndarray
    tilt_deg: float
    depth_mm: float
    base_distance_mm: float
    goal_clearance_mm: float
    start_clearance_mm: float
    retracted: bool = False
    plan: PlanResult | None = None

    @property
    def solved(self) -> bool:
        return self.plan is not None and self.plan.solved

    @property
    def path_clearance_mm(self) -> float:
        """The verified path's smallest exact clearance (mm; -inf without one)."""
        v = None if self.plan is None else self.plan.validated
        return -math.inf if v is None or not self.solved else float(v.min_clearance_mm)

    def to_json(self) -> dict:
        p = self.plan
        return {"start_kind": "retracted" if self.retracted else "pulled back",
                "tilt_deg": round(self.tilt_deg, 2), "start_depth_mm": round(self.depth_mm, 2),
                "base_distance_mm": round(self.base_distance_mm, 2),
                "start": np.round(self.start, 6).tolist(), "goal": np.round(self.goal, 6).tolist(),
                "goal_clearance_mm": round(self.goal_clearance_mm, 3),
                "start_clearance_mm": round(self.start_clearance_mm, 3), "solved": self.solved,
                "path_clearance_mm": round(self.path_clearance_mm, 3) if self.solved else None,
                "states": None if p is None else p.states, "message": None if p is None else p.message}


@dataclass(frozen=True)
class PlacementReport:
    """What `place_robot` found: the chosen placement (None: nothing works, ``reason`` says why),
    the verified candidates in the order planned, counts of each step and the time (s)."""

    entry_mm: np.ndarray
    line: np.ndarray
    chosen: Candidate | None
    verified: tuple[Candidate, ...]
    counts: dict[str, int]
    reason: str = ""
    time_s: float = 0.0
    verify_states: int = 0
    backend: str = ""

    def to_json(self) -> dict:
        c = self.chosen
        return {"entry_mm": self.entry_mm.tolist(), "line": np.round(self.line, 6).tolist(),
                "placed": c is not None, "reason": self.reason or None,
                "base_pose": None if c is None else np.round(c.base_pose, 6).tolist(),
                "start": None if c is None else np.round(c.start, 6).tolist(),
                "chosen": None if c is None else c.to_json(),
                "verified": [v.to_json() for v in self.verified], "counts": self.counts,
                "verify_backend": self.backend, "verify_max_states": self.verify_states,
                "time_s": round(self.time_s, 3)}


def entry_points(positions: np.ndarray, distance_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """On each backbone (B, P, 3), the point nearest the tip whose chord to the tip is ``distance_mm``
    long (linear between backbone points): its position (B, 3) and index (B,) of the backbone point
    before it; -1 where no point lies that far from the tip."""
    chord = np.linalg.norm(positions[:, -1:, :] - positions, axis=2)  # (B, P)
    far = chord >= distance_mm
    last = positions.shape[1] - 1 - np.argmax(far[:, ::-1], axis=1)  # last point at least that far
    ok = far.any(axis=1) & (last < positions.shape[1] - 1)
    k = np.where(ok, last, 0)
    rows = np.arange(len(positions))
    c0, c1 = chord[rows, k], chord[rows, np.minimum(k + 1, positions.shape[1] - 1)]
    t = np.clip((c0 - distance_mm) / np.maximum(c0 - c1, 1e-12), 0.0, 1.0)[:, None]
    point = (1 - t) * positions[rows, k] + t * positions[rows, np.minimum(k + 1, positions.shape[1] - 1)]
    return point, np.where(ok, k, -1)


def aligning_rotations(chords: np.ndarray, line: np.ndarray, rolls: np.ndarray) -> np.ndarray:
    """Rotations (B, 3, 3) that turn each chord (B, 3) onto ``line`` (unit (3,)), then roll it by
    ``rolls`` (B,) rad about the line."""
    unit = chords / np.linalg.norm(chords, axis=1, keepdims=True)
    axis = np.cross(unit, line)
    sin = np.linalg.norm(axis, axis=1)
    angle = np.arctan2(sin, unit @ line)
    fallback = np.cross(unit, [1.0, 0.0, 0.0] if abs(line[0]) < 0.9 else [0.0, 1.0, 0.0])
    axis = np.where(sin[:, None] > 1e-9, axis, fallback)
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    align = Rotation.from_rotvec(axis * angle[:, None]).as_matrix()
    return np.einsum("bij,bjk->bik", Rotation.from_rotvec(np.outer(rolls, line)).as_matrix(), align)


def _clearance(world: CollisionWorld, pts: np.ndarray, radius: np.ndarray, margin_mm: float) -> np.ndarray:
    """Estimated clearances (B,) of backbones (B, P, 3) scene frame with radii (B, P) beyond every margin
    (mm, capped at `CLEARANCE_CAP_MM`; -inf where not finite): the distance grid interpolated
    (trilinear) at `SUBSTEPS` points per segment, less the radius. Not a bound (the grid's own bound is
    up to a cell loose, too coarse to rank placements in a narrow airway): what it ranks, FCL judges."""
    finite = np.isfinite(pts).all(axis=(1, 2))
    if world.grid is None:  # no obstacles
        return np.where(finite, CLEARANCE_CAP_MM, -np.inf)
    g = world.grid
    t = (np.arange(SUBSTEPS) + 0.5) / SUBSTEPS
    seg = pts[:, :-1, None, :] + t[None, None, :, None] * (pts[:, 1:, None, :] - pts[:, :-1, None, :])
    r = np.repeat(np.maximum(radius[:, 1:], radius[:, :-1]), SUBSTEPS, axis=1) + margin_mm
    idx = (np.nan_to_num(seg.reshape(len(pts), -1, 3)) - g.lo) / g.cell_mm - 0.5
    d = ndimage.map_coordinates(g.values.astype(np.float32) * g.step_mm, idx.reshape(-1, 3).T, order=1,
                                mode="constant", cval=g.band_mm).reshape(r.shape)
    return np.where(finite, np.minimum((d - r).min(axis=1), CLEARANCE_CAP_MM), -np.inf)


def _judged(clear: np.ndarray, pts: np.ndarray, radius: np.ndarray, checker: RobotCollisionChecker,
            n: int = 200) -> np.ndarray:
    """Clearances (B,) judged by FCL for the ``n`` backbones that ``clear`` (estimates) ranks best: the
    free ones get their exact clearance beyond the robot's margin (mm, capped at `CLEARANCE_CAP_MM`; at
    least 0: free with every structure's own margin too); every other keeps its estimate, made negative
    (not free)."""
    out = np.minimum(clear, -1e-9)
    near = np.array([i for i in np.argsort(-clear)[:n] if np.isfinite(clear[i])], dtype=int)
    if len(near):
        free = near[checker.free_batch(pts[near], radius[near])]
        exact = [float(np.min(checker.clearances(pts[i], radius[i], CLEARANCE_CAP_MM + 1.0))) for i in free]
        out[free] = np.clip(np.asarray(exact) - checker.margin_mm, 0.0, CLEARANCE_CAP_MM)
    return out


@dataclass(frozen=True)
class _Goals:
    """Placed goals: joints (K, 2N), their scaled box coordinates (K, D), base rolls about the line
    (K,) rad, shifts across the line (K, 3) mm, rotations (K, 3, 3), base positions (K, 3), tilts (K,)
    degrees, clearances (K,) mm, and the placed backbones (K, P, 3) and radii (K, P)."""

    q: np.ndarray
    y: np.ndarray
    rolls: np.ndarray
    shifts: np.ndarray
    rotations: np.ndarray
    bases: np.ndarray
    tilts: np.ndarray
    clearance: np.ndarray
    points: np.ndarray
    radius: np.ndarray

    def take(self, idx) -> _Goals:
        return _Goals(*(getattr(self, f)[idx] for f in self.__dataclass_fields__))

    def join(self, other: _Goals) -> _Goals:
        return _Goals(*(np.concatenate([getattr(self, f), getattr(other, f)])
                        for f in self.__dataclass_fields__))


def _placed_goals(scene: Scene, exact: Backend, y: np.ndarray, rolls: np.ndarray, shifts: np.ndarray,
                  entry: np.ndarray, line: np.ndarray, world: CollisionWorld) -> _Goals:
    """Configurations (scaled box coordinates (K, D) of the scene's `BoxSpace`) with base rolls (K,) rad
    placed through the entry with their tips at the target's centre, then moved by ``shifts`` (K, 3)
    (taken across the line and to at most `entry_slack`), screened: clearance -inf where the backbone
    is unstable, too short or its base turned more than `MAX_TILT_DEG` from the line."""
    q = BoxSpace.for_scene(scene).to_joints(y)
    bb = exact.forward(q, points=POINTS, check=False)
    pos = bb.positions_mm
    point, k = entry_points(pos, float(np.linalg.norm(scene.target.center - entry)))
    chord = np.where((k >= 0)[:, None], pos[:, -1] - point, line)
    R = aligning_rotations(chord, line, rolls)
    shifts = _across(shifts, line, entry_slack(scene))
    bases = scene.target.center - np.einsum("kij,kj->ki", R, pos[:, -1]) + shifts
    tilts = np.degrees(np.arccos(np.clip(R[:, :, 2] @ line, -1.0, 1.0)))
    pts = np.einsum("kij,kpj->kpi", R, pos) + bases[:, None, :]
    clear = _clearance(world, pts, bb.radius_mm, scene.settings.margin_mm)
    clear[~((k >= 0) & bb.stable & (tilts <= MAX_TILT_DEG))] = -np.inf
    return _Goals(q, y, rolls, shifts, R, bases, tilts, clear, pts, bb.radius_mm)


def entry_slack(scene: Scene) -> float:
    """How far (mm) a placement may pass beside the entry point (and its tip beside the target's
    centre): `ENTRY_SLACK_MM`, or less where the target is smaller."""
    return min(ENTRY_SLACK_MM, 0.7 * float(np.min(scene.target.semi_axes)))


def _across(shifts: np.ndarray, line: np.ndarray, slack: float) -> np.ndarray:
    """``shifts`` (K, 3) without their part along ``line``, at most ``slack`` long."""
    s = shifts - np.outer(shifts @ line, line)
    n = np.linalg.norm(s, axis=1, keepdims=True)
    return s * np.minimum(1.0, slack / np.maximum(n, 1e-12))


def _search_goals(scene: Scene, exact: Backend, entry: np.ndarray, line: np.ndarray, world: CollisionWorld,
                  rng: np.random.Generator, progress) -> _Goals:
    """Steps 1-2: `REACH_SAMPLES` uniform configurations and rolls placed through the entry, then
    up to `REFINE_ROUNDS` rounds (until `GOALS_KEPT` have the capped clearance) in which the `ELITE`
    placements nearest to free each spawn `CHILDREN` perturbed ones (`REFINE_STEP_MM` in the planning
    metric, shrinking by `REFINE_SHRINK` a round; the roll by as many mm at the tip's distance, the shift
    by half); all placements, their clearances estimated."""
    space = BoxSpace.for_scene(scene)
    slack = entry_slack(scene)
    goals = _placed_goals(scene, exact, space.to_coords(space.sample(REACH_SAMPLES, rng)),
                          rng.uniform(0, 2 * math.pi, REACH_SAMPLES),
                          rng.uniform(-slack, slack, (REACH_SAMPLES, 3)), entry, line, world)
    reach = float(np.linalg.norm(scene.target.center - entry))
    for r in range(REFINE_ROUNDS):
        if (goals.clearance >= CLEARANCE_CAP_MM).sum() >= GOALS_KEPT:
            break  # enough placements with the largest clearance that counts
        progress(f"refining the placements nearest to free ({r + 1}/{REFINE_ROUNDS}): "
                 f"{int((goals.clearance >= 0).sum())} free of {len(goals.q):,}")
        elite = np.argsort(-goals.clearance)[:ELITE]
        elite = elite[np.isfinite(goals.clearance[elite])]
        if not len(elite):
            break
        parent = np.repeat(elite, CHILDREN)
        step = REFINE_STEP_MM * REFINE_SHRINK**r
        y = space.clip(goals.y[parent] + rng.normal(0, step, (len(parent), goals.y.shape[1])))
        rolls = goals.rolls[parent] + rng.normal(0, step / reach, len(parent))
        shifts = goals.shifts[parent] + rng.normal(0, 0.5 * step, (len(parent), 3))
        goals = goals.join(_placed_goals(scene, exact, y, rolls, shifts, entry, line, world))
    return goals


def _starts(scene: Scene, exact: Backend, goals: _Goals, entry: np.ndarray, line: np.ndarray,
            world: CollisionWorld, checker: RobotCollisionChecker
            ) -> list[tuple[int, np.ndarray, float, float, bool]]:
    """Step 3: for each goal, its retracted and its pulled-back start (one if they are the same):
    (goal index, start, its depth past the entry (mm), its clearance (mm), whether retracted)."""
    domain = scene.robot.domain
    n = scene.robot.n_tubes
    lo, hi = scene.joint_box
    retracted = np.concatenate([[lo[0]], hi[1:n]])
    y = domain.to_box(goals.q)
    f = np.asarray(RETRACTIONS)
    cand = np.repeat(y[:, None, :], len(f), axis=1)  # (K, F, 2N)
    cand[..., :n] = retracted + f[None, :, None] * (y[:, None, :n] - retracted)
    q = domain.from_box(cand.reshape(-1, 2 * n))
    bb = exact.forward(q, points=POINTS, check=False)
    rep = np.repeat(np.arange(len(goals.q)), len(f))
    pts = np.einsum("kij,kpj->kpi", goals.rotations[rep], bb.positions_mm) + goals.bases[rep, None, :]
    clear = _clearance(world, pts, bb.radius_mm, scene.settings.margin_mm)
    clear = _judged(clear, pts, bb.radius_mm, checker, n=len(clear))
    depth = (pts[:, -1] - entry) @ line
    free = (bb.stable & (clear >= 0)).reshape(len(goals.q), len(f))
    chain = np.flip(np.logical_and.accumulate(np.flip(free, axis=1), axis=1), axis=1)  # free from here on
    deep = (depth >= START_DEPTH_MM).reshape(chain.shape)
    out = []
    for g in range(len(goals.q)):
        kinds = {}  # start index -> retracted: the pulled-back start may be the retracted one
        roomy = free[g] & deep[g] & (clear.reshape(free.shape)[g] >= START_CLEARANCE_MM)
        retract = roomy if roomy.any() else free[g] & deep[g]
        for usable, retracted in ((chain[g] & deep[g], False), (retract, True)):
            if usable.any():
                kinds[g * len(f) + int(np.argmax(usable))] = retracted
        out += [(g, q[i], float(depth[i]), float(clear[i]), retracted) for i, retracted in kinds.items()]
    return out


def _blocked_reason(goals: _Goals, checker: RobotCollisionChecker) -> str:
    """Why no goal passes through the entry: the structures the nearest-to-free placements touch, with
    how many touch each."""
    hits: Counter = Counter()
    order = np.argsort(-goals.clearance)[:100]
    for i in order:
        hits.update(checker.blockers(goals.points[i], goals.radius[i]).keys())
    named = ", ".join(f"{n} ({k})" for n, k in hits.most_common(4))
    return (f"every configuration through the entry to the target touches the anatomy (of the {len(order)} "
            f"placements nearest to free, how many touch each, with the margins: {named or 'none named'}); "
            f"check the entry point, or make the margins smaller")


def _verify(scene: Scene, backend: Backend, world: CollisionWorld, found: list[Candidate], max_states: int,
            seed: int, progress) -> list[Candidate]:
    """Plan from the candidates (`_candidates`: in the order to try) until a retracted start or
    `ACCEPT` starts are solved or `VERIFY` were tried."""
    done = []
    for c in found[:VERIFY]:
        kind = "retracted" if c.retracted else "pulled-back"
        progress(f"verifying placement {len(done) + 1}/{min(VERIFY, len(found))} (tilt {c.tilt_deg:.0f} deg, "
                 f"{kind} start, tip {c.depth_mm:.0f} mm past the entry)")
        try:
            placed = replace(scene, base_pose=c.base_pose, start=c.start)
            result = plan(placed, backend, max_states=max_states, seed=seed, wall_limit=False, world=world,
                          explain=False, goal_hints=c.goal[None])
        except InputError:
            continue
        done.append(replace(c, plan=result))
        if (c.retracted and result.solved) or sum(v.solved for v in done) >= ACCEPT:
            break
    return done


def _candidates(goals: _Goals, starts, entry: np.ndarray) -> list[Candidate]:
    """The placements with a start in the order to try: the retracted starts of the `RETRACTED_TRIES`
    best placements, then the pulled-back ones, each best first (goal clearance in steps of 0.5 mm,
    start clearance, tilt)."""
    out = []
    for g, start, depth, clear, retracted in starts:
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = goals.rotations[g], goals.bases[g]
        out.append(Candidate(T, start, goals.q[g], float(goals.tilts[g]), depth,
                             float(np.linalg.norm(entry - goals.bases[g])), float(goals.clearance[g]), clear,
                             retracted))
    out.sort(key=lambda c: (-round(c.goal_clearance_mm / 0.5), -round(c.start_clearance_mm / 0.5),
                            c.tilt_deg))
    retracted = [c for c in out if c.retracted][:RETRACTED_TRIES]
    return retracted + [c for c in out if not c.retracted]


def place_robot(scene: Scene, entry_mm, backend: Backend, *, seed: int = 0, max_states: int | None = None,
                progress=lambda _text: None) -> PlacementReport:
    """A base pose and a start that enter through ``entry_mm`` (scene frame, mm) and from which a plan
    with ``backend`` (a work budget of ``max_states``, default `VERIFY_TIME_S` of its reference
    rate) reaches the target; see the module docstring. ``progress(text)`` is told each step."""
    from ctrplan.planning.budget import states_for

    t0 = time.perf_counter()
    entry = np.asarray(entry_mm, dtype=float)
    towards = scene.target.center - entry if entry.shape == (3,) else np.zeros(3)
    if not np.all(np.isfinite(entry)) or np.linalg.norm(towards) < 1e-6:
        raise InputError(f"--entry: a point x,y,z (scene frame, mm) apart from the target's centre, got "
                         f"{np.asarray(entry_mm).tolist()}")
    line = towards / np.linalg.norm(towards)
    exact = exact_backend(scene.robot)
    world = CollisionWorld.from_scene(scene)
    checker = RobotCollisionChecker(world, np.eye(4), POINTS, scene.settings.margin_mm)
    report = dict(entry_mm=entry, line=line, backend=backend.name)

    def failed(reason: str) -> PlacementReport:
        return PlacementReport(chosen=None, verified=(), reason=reason, time_s=time.perf_counter() - t0,
                               **report)

    progress(f"placing {REACH_SAMPLES:,} configurations through the entry (exact model)")
    goals = _search_goals(scene, exact, entry, line, world, np.random.default_rng(seed), progress)
    counts = report["counts"] = {"placements": len(goals.q),
                                 "through_entry": int(np.isfinite(goals.clearance).sum())}
    if not counts["through_entry"]:
        return failed(_unreachable_reason(scene, exact, entry))
    goals = replace(goals, clearance=_judged(goals.clearance, goals.points, goals.radius, checker))
    free = np.flatnonzero(goals.clearance >= 0)
    counts["free_goals"] = len(free)
    if not len(free):
        return failed(_blocked_reason(goals, checker))
    order = free[np.lexsort((goals.tilts[free], -np.round(goals.clearance[free] / 0.5)))][:GOALS_KEPT]
    goals = goals.take(order)
    progress(f"finding starts for the {len(order)} best goals")
    found = _candidates(goals, _starts(scene, exact, goals, entry, line, world, checker), entry)
    counts["with_start"] = len(found)
    if not found:
        return failed(f"none of the {len(order)} best collision-free goals through the entry, pulled back, "
                      f"leaves a free stable start with its tip {START_DEPTH_MM:g} mm past the entry")
    budget = max_states or states_for(backend.name, VERIFY_TIME_S)
    verified = _verify(scene, backend, world, found, budget, seed, progress)
    solved = [c for c in verified if c.solved]
    chosen = max(solved, key=lambda c: (c.retracted, c.path_clearance_mm)) if solved else None
    reason = "" if solved else _unverified_reason(verified, budget)
    return PlacementReport(chosen=chosen, verified=tuple(verified), reason=reason,
                           time_s=time.perf_counter() - t0, verify_states=budget, **report)


def _unreachable_reason(scene: Scene, exact: Backend, entry: np.ndarray) -> str:
    """Why no configuration passes through the entry to the target: the robot's span against the
    distance, or the tilt."""
    distance = float(np.linalg.norm(scene.target.center - entry))
    bb = exact.forward(scene.robot.domain.sample(500, 0), points=POINTS, check=False)
    chords = np.linalg.norm(bb.positions_mm[:, -1:] - bb.positions_mm, axis=2)[bb.stable]
    reach = float(np.nanmax(chords, initial=0.0))
    if reach < distance:
        return (f"the target is {distance:.1f} mm from the entry; no configuration's backbone spans more "
                f"than {reach:.1f} mm: a longer robot, or an entry nearer the target")
    return (f"no configuration reaches the target through the entry with its base within "
            f"{MAX_TILT_DEG:g} deg of the line entry -> target")


def _unverified_reason(verified: list[Candidate], budget: int) -> str:
    """Why none of the verified placements is usable: what their plans said."""
    if not verified:
        return "every candidate start was refused by the plan's start check"
    first = verified[0].plan
    return (f"no plan from the {len(verified)} best placements reached the target ({budget:,} states "
            f"each); the best one's: {first.message}")
