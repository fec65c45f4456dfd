"""Why a search failed, in numbers (issue 41, item 5): which structures block the goal candidates and
the path attempts, collision told apart from elastic instability and non-convergence, and what would
help where a quick test shows it.

A search keeps what it rejected: the goal sampler the IK solutions that reached the target but were
invalid (`GoalSampler.rejected`), the checker the invalid state of every failed extension or edge
(`ConfigurationChecker.blocked`), the latest few hundred of each, as references -- nothing on a
successful plan's path. Only when the search fails does `explain_failure` look at them again, with
the search's own backend and collision checker (its margins): each state's backbone (not converged?
unstable?) and, for one in collision, the structures it touches with the margins and its distance to
each without them (`RobotCollisionChecker.blockers`). From those distances follow the margin
suggestions exactly: a state touching structures S is free with margins m_S when its distance to
each exceeds the robot's margin plus m_S. Where no goal configuration was found, the other
registered backends (`ctrplan.kinematics.registry.BACKEND_KINDS`) sample goals for a couple of IK
batches each; one that finds some is suggested, with the work it took.
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import asdict, dataclass

import numpy as np

from ctrplan.base.errors import InputError
from ctrplan.kinematics.registry import BACKEND_KINDS
from ctrplan.planning.goal import GoalSampler
from ctrplan.planning.model import PlanningModel
from ctrplan.planning.validity import ConfigurationChecker

#: States of each kind examined at most (the latest the search kept).
EXAMINED = 250
#: Margins are tried in steps of this (mm), down to 0.
MARGIN_STEP_MM = 0.25
#: Structures whose margin is tried (the ones blocking most).
MARGIN_TRIES = 3
#: IK batches another backend gets to find a goal configuration.
BACKEND_BATCHES = 2
#: Seconds the backend test needs left before the deadline to run at all.
BACKEND_TEST_MIN_S = 4.0


@dataclass(frozen=True)
class Rejected:
    """What the examination of one kind of rejected state found: ``total`` rejected in the search,
    ``examined`` of them (the latest), and of those how many collide, are elastically unstable, or
    did not converge."""

    total: int
    examined: int
    collision: int = 0
    unstable: int = 0
    not_converged: int = 0

    def describe(self, what: str) -> str:
        """e.g. ``436 goal candidates (250 examined): 240 in collision, 10 elastically unstable``."""
        seen = f" ({self.examined} examined)" if self.examined < self.total else ""
        parts = [f"{n} {word}" for n, word in ((self.collision, "in collision"),
                                               (self.unstable, "elastically unstable"),
                                               (self.not_converged, "not converged")) if n]
        return f"{self.total} {what}{seen}" + (f": {', '.join(parts)}" if parts else "")


@dataclass(frozen=True)
class Blocker:
    """One structure and how many of the examined goal candidates and path attempts it blocks."""

    name: str
    goal_candidates: int
    path_attempts: int


@dataclass(frozen=True)
class Suggestion:
    """A change a quick test showed would help: ``kind`` margin | scene_margin | backend, what to
    change (``structure`` and ``margin_mm`` for a margin, ``backend`` for a backend), the states it
    frees or the goals it finds (``freed``), and the sentence."""

    kind: str
    text: str
    freed: int
    structure: str | None = None
    margin_mm: float | None = None
    backend: str | None = None


@dataclass(frozen=True)
class FailureAnalysis:
    """Why a search failed (`explain_failure`): the rejected goal candidates and path attempts, the
    structures blocking them (most first), suggestions, the time the analysis took (s) and what it
    left untested."""

    goals: Rejected
    paths: Rejected
    blockers: tuple[Blocker, ...]
    suggestions: tuple[Suggestion, ...] = ()
    time_s: float = 0.0
    untested: str = ""

    def summary(self, top: int = 4) -> str:
        """One line: what blocks (structures with counts), collision against instability, and the
        suggestions."""
        parts = []
        if self.goals.total:
            parts.append(self.goals.describe("goal candidates rejected"))
        if self.paths.total:
            parts.append(self.paths.describe("path attempts failed"))
        if self.blockers:
            named = ", ".join(f"{b.name} ({_counts(b)})" for b in self.blockers[:top])
            more = f" and {len(self.blockers) - top} more" if len(self.blockers) > top else ""
            parts.append(f"blocked by {named}{more}")
        line = "; ".join(parts)
        if self.suggestions:
            line += ". " + " ".join(s.text[0].upper() + s.text[1:] + "." for s in self.suggestions)
        if self.untested:
            line += f" ({self.untested})"
        return line

    def to_json(self) -> dict:
        return {"goal_candidates": asdict(self.goals), "path_attempts": asdict(self.paths),
                "blockers": [asdict(b) for b in self.blockers],
                "suggestions": [{k: v for k, v in asdict(s).items() if v is not None}
                                for s in self.suggestions],
                "time_s": round(self.time_s, 4), "untested": self.untested or None}


def _counts(b: Blocker) -> str:
    parts = [f"{n} {what}" for n, what in ((b.goal_candidates, "goal candidates"),
                                           (b.path_attempts, "path attempts")) if n]
    return ", ".join(parts)


@dataclass(frozen=True)
class _Examined:
    """Per examined state: its kind (``collision`` | ``unstable`` | ``not_converged`` | ``free``) and,
    in collision, the structures it touches with their distances without margins (mm)."""

    kinds: tuple[str, ...]
    touches: tuple[dict[str, float], ...]

    def rejected(self, total: int) -> Rejected:
        c = Counter(self.kinds)
        return Rejected(total, len(self.kinds), c["collision"], c["unstable"], c["not_converged"])

    def per_structure(self) -> Counter:
        return Counter(name for touch in self.touches for name in touch)


def _examine(checker: ConfigurationChecker, q: np.ndarray) -> _Examined:
    """Classify the states (K, 2N) with the search's backend and collision checker."""
    if not len(q):
        return _Examined((), ())
    bb = checker.backend.forward(q, points=checker.points, check=False)
    kinds, touches = [], []
    for i in range(len(q)):
        touch: dict[str, float] = {}
        if not bb.converged[i]:
            kind = "not_converged"
        elif not bb.stable[i]:
            kind = "unstable"
        else:
            touch = checker.collision.blockers(bb.positions_mm[i], bb.radius_mm[i])
            kind = "collision" if touch else "free"
        kinds.append(kind)
        touches.append(touch)
    return _Examined(tuple(kinds), tuple(touches))


def _latest(states, n: int) -> np.ndarray:
    rows = list(states)[-n:]
    return np.array(rows) if rows else np.zeros((0, 0))


def explain_failure(checker: ConfigurationChecker, sampler: GoalSampler, *, deadline: float | None = None,
                    seed: int | None = None) -> FailureAnalysis:
    """Examine what the failed search with ``checker`` (and its goal ``sampler``) rejected; with
    ``deadline`` (``time.perf_counter()`` value) tests that would not end by then are left out and
    said so."""
    t0 = time.perf_counter()
    goals = _examine(checker, _latest(sampler.rejected, EXAMINED))
    paths = _examine(checker, _latest(checker.blocked, EXAMINED))
    g_count, p_count = goals.per_structure(), paths.per_structure()
    names = sorted(set(g_count) | set(p_count), key=lambda n: (-g_count[n], -p_count[n], n))
    blockers = tuple(Blocker(n, g_count[n], p_count[n]) for n in names)
    # where no goal was found, goals are the problem; else the path attempts
    focus, what = (goals, "goal candidates") if not sampler.goals else (paths, "failed path attempts")
    suggestions = _margin_suggestions(checker, focus, what, blockers)
    untested = ""
    if not sampler.goals and sampler.stats.rejected:
        left = None if deadline is None else deadline - time.perf_counter()
        if left is not None and left < BACKEND_TEST_MIN_S:
            untested = "other backends not tried: no time left within the time limit"
        else:
            suggestions += _backend_suggestions(checker.model, sampler, seed, deadline)
    return FailureAnalysis(goals.rejected(sampler.stats.rejected), paths.rejected(checker.blocked_total),
                           blockers, tuple(suggestions), time.perf_counter() - t0, untested)


def _freed(examined: _Examined, robot_margin: float, margins: dict[str, float]) -> int:
    """How many examined collision states are free with the robot's margin ``robot_margin`` and the
    structures' ``margins`` (mm)."""
    return sum(bool(touch) and all(d > robot_margin + margins[n] for n, d in touch.items())
               for touch in examined.touches)


def _margin_steps(margin: float) -> np.ndarray:
    """Smaller margins than ``margin`` (mm), largest first, down to 0."""
    steps = np.arange(margin - MARGIN_STEP_MM, -1e-9, -MARGIN_STEP_MM)
    return np.unique(np.append(np.round(steps, 6), 0.0))[::-1] if margin > 0 else np.zeros(0)


def _margin_suggestions(checker: ConfigurationChecker, examined: _Examined, what: str,
                        blockers: tuple[Blocker, ...]) -> list[Suggestion]:
    """The largest smaller margin of each of the `MARGIN_TRIES` main blockers with a margin of its
    own, and of the scene, that frees examined states (if any does)."""
    scene = checker.scene
    own = {o.name: float(o.margin_mm) for o in scene.obstacles}
    robot = checker.margin_mm
    n = sum(kind == "collision" for kind in examined.kinds)
    out = []
    for b in [b for b in blockers if own.get(b.name, 0.0) > 0][:MARGIN_TRIES]:
        for m in _margin_steps(own[b.name]):
            freed = _freed(examined, robot, {**own, b.name: float(m)})
            if freed:
                out.append(Suggestion("margin", f"with margin {m:g} mm instead of {own[b.name]:g} mm on "
                                                f"{b.name}, {freed} of the {n} {what} in collision are free",
                                      freed, structure=b.name, margin_mm=float(m)))
                break
    scene_margin = scene.settings.margin_mm
    for m in _margin_steps(scene_margin):
        freed = _freed(examined, robot - scene_margin + m, own)
        if freed:
            out.append(Suggestion("scene_margin", f"with the scene's margin_mm {m:g} instead of "
                                                  f"{scene_margin:g}, {freed} of the {n} {what} in "
                                                  f"collision are free", freed, margin_mm=float(m)))
            break
    return out


def _backend_suggestions(model: PlanningModel, sampler: GoalSampler, seed: int | None,
                         deadline: float | None) -> list[Suggestion]:
    """Other registered backends that find goal configurations here within `BACKEND_BATCHES` IK
    batches (a backend that cannot be built for the robot, e.g. without a trained model, is
    skipped; so is one that would not finish by ``deadline``)."""
    out = []
    current = model.backend.name
    kinds = sorted((k for k in BACKEND_KINDS.values() if k.name != current),
                   key=lambda k: -k.reference_states_per_s)
    for kind in kinds:
        if deadline is not None and deadline - time.perf_counter() < BACKEND_TEST_MIN_S:
            break
        try:
            backend = kind.build(model.scene.robot, None)
        except InputError:
            continue
        other = ConfigurationChecker(PlanningModel.build(model.scene, backend, world=model.world))
        test = GoalSampler(other, sampler.region, np.random.default_rng(seed), start=sampler.start,
                           seeds_per_batch=sampler.seeds_per_batch)
        for _ in range(BACKEND_BATCHES):
            if test.sample_batch() or (deadline is not None and time.perf_counter() > deadline):
                break
        if test.goals:
            states = other.counters.kinematics_calls
            out.append(Suggestion("backend", f"the {kind.name} backend finds {len(test.goals)} goal "
                                             f"configurations here ({test.stats.batches} IK batches, "
                                             f"{states:,} states): try --backend {kind.name}",
                                  len(test.goals), backend=kind.name))
    return out
