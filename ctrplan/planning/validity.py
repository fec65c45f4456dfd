"""State validity and batched motion validation for OMPL.

A configuration is valid when the kinematics backend converged and the capsule chain around its
backbone touches no obstacle. `ConfigurationChecker` does that for batches of joint vectors (one
backend call per batch) for a frozen `PlanningModel`, keeps a small cache (tip, validity, warm start)
per checked state and counts kinematics calls: the per-search data of the model. `ValidityChecker`
and `BatchMotionValidator` adapt it to OMPL; both are usable with any OMPL planner from user code
(see ``examples/custom_planner.py``).
"""

from __future__ import annotations

import time
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from ompl import base as ob

from ctrplan.collision.checker import RobotCollisionChecker
from ctrplan.collision.world import CollisionWorld
from ctrplan.kinematics.backbone import Backbone
from ctrplan.kinematics.base import ArcFractions, Backend, Body, Points, arc_fractions
from ctrplan.planning.model import PlanningModel
from ctrplan.planning.space import BoxSpace
from ctrplan.scene.objects import Scene


@dataclass
class Counters:
    """Work done so far: configurations sent to the backend, backend calls, collision checks (and of
    those, the ones the broadphase could not decide alone, the ones its grid showed in contact; FCL
    narrow-phase tests)."""

    kinematics_calls: int = 0
    kinematics_batches: int = 0
    collision_checks: int = 0
    narrow_checks: int = 0
    grid_contacts: int = 0
    fcl_tests: int = 0
    motions: int = 0
    valid_motions: int = 0
    kinematics_s: float = 0.0
    collision_s: float = 0.0


#: States of failed path attempts a checker keeps (the latest), for the explanation of a failed search
#: (`ctrplan.planning.failure`).
BLOCKED_KEPT = 400


@dataclass
class _Entry:
    valid: bool
    tip_robot: np.ndarray  # robot frame, mm (NaN when not converged); `ConfigurationChecker.tip` maps it
    initial_state: np.ndarray | None = None


@dataclass
class ConfigurationChecker:
    """The per-search data of a `PlanningModel` (as Pinocchio's ``Data`` to its ``Model``): checks
    batches of configurations with the model's backend and collision world, and keeps what one search
    learns -- a state cache, counters, a progress hook, recently found valid states.

    Args:
        model: the frozen planning model (scene, backend, margin, world, space).
        cache_size: states kept in the cache.
    """

    model: PlanningModel
    cache_size: int = 200_000
    counters: Counters = field(default_factory=Counters)
    hook: Callable[[], None] | None = None
    #: the invalid state of each failed path attempt (an extension or edge of a planner: its end, or
    #: its first invalid interior state), the latest `BLOCKED_KEPT`, and how many failed in all
    blocked: deque = field(default_factory=lambda: deque(maxlen=BLOCKED_KEPT))
    blocked_total: int = 0

    def __post_init__(self) -> None:
        m = self.model
        self.collision = RobotCollisionChecker(m.world, m.scene.base_pose, m.points, m.margin_mm)
        self.warm_start = m.backend.warm_startable
        self._cache: OrderedDict[bytes, _Entry] = OrderedDict()
        #: joints and scene-frame tips of recently found valid states (seeds for goal sampling)
        self.valid_q: list[np.ndarray] = []
        self.valid_tips: list[np.ndarray] = []
        #: arc fractions checked in turn (see `_stages`), and the backend's prepared query of each
        self.stages = self._stages()
        self.last_invalid: np.ndarray | None = None  # the failing row of the last `validate` that stopped
        self._stage_queries = tuple(self.backend.body_query(stage) for stage in self.stages)

    @property
    def scene(self) -> Scene:
        return self.model.scene

    @property
    def backend(self) -> Backend:
        return self.model.backend

    @property
    def space(self) -> BoxSpace:
        return self.model.space

    @property
    def points(self) -> int:
        return self.model.points

    @property
    def margin_mm(self) -> float:
        return self.model.margin_mm

    @property
    def world(self) -> CollisionWorld:
        return self.model.world

    def _stages(self) -> tuple[ArcFractions, ...]:
        """Arc fractions of the backbone points checked in turn. Where the backend makes part of a
        backbone cheaper (``partial_backbones_cheap``): the distal half first -- a robot probing
        anatomy meets it there first, and an invalid state then costs half a backbone -- and the
        proximal half (sharing the middle point, so every capsule is checked) only for states the
        first half leaves valid. Otherwise the whole backbone at once. Either way a state is valid
        exactly when every capsule of the ``points``-point backbone is free."""
        frac = arc_fractions(self.points)
        if not self.backend.partial_backbones_cheap:
            return (ArcFractions(frac),)
        k = self.points // 2
        return ArcFractions(frac[k:]), ArcFractions(frac[:k + 1])

    # ---- kinematics ------------------------------------------------------------------------------
    def _counted(self, call: Callable[[], Any], n_states: int) -> Any:
        """``call()`` of the backend, timed and counted (``n_states`` new configurations)."""
        t = time.perf_counter()
        out = call()
        self._count_kinematics(time.perf_counter() - t, n_states)
        return out

    def _count_kinematics(self, seconds: float, new_states: int) -> None:
        """Count one backend call of ``seconds`` on ``new_states`` configurations not counted yet,
        and report progress."""
        c = self.counters
        c.kinematics_s += seconds
        c.kinematics_calls += new_states
        c.kinematics_batches += 1
        if self.hook is not None:
            self.hook()

    def forward(self, q: np.ndarray, guess: np.ndarray | None = None,
                points: Points | None = None) -> Backbone:
        """Backbones of joints (B, 2N) (no joint checks: planner states lie in the domain)."""
        q = np.atleast_2d(q)
        return self._counted(lambda: self.backend.forward(
            q, points=self.points if points is None else points,
            guess=guess if self.warm_start else None, check=False), q.shape[0])

    def tips(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Tips (B, 3) mm, unit tip tangents (B, 3) -- robot frame -- and convergence (B,) of joints
        (B, 2N) (`Backend.tip_and_tangent`; counted like `forward`)."""
        q = np.atleast_2d(q)
        return self._counted(lambda: self.backend.tip_and_tangent(q, check=False), q.shape[0])

    def validate(self, q: np.ndarray, guess: np.ndarray | None = None,
                 stop_at_first: bool = False) -> tuple[np.ndarray, Body]:
        """Validity (B,) of configurations q (B, 2N), checked in `stages`, and the `Body` of the
        first stage (its tips -- the first stage ends at the tip -- and initial states serve the
        cache). With ``stop_at_first`` (an edge: only whether all rows are valid matters) the rows are
        tested in order, the work stops at the first invalid one and then every row is reported
        invalid."""
        first = None
        rows = None  # rows still valid after the stages so far: None while all are
        for stage in self.stages:
            qk, gk = (q, guess) if rows is None else (q[rows], None if guess is None else guess[rows])
            t0 = time.perf_counter()
            body = self.backend.body(qk, stage, guess=gk, check=False)
            t1 = time.perf_counter()
            pos = body.positions_mm
            if not body.usable.all():
                pos = np.where(body.usable[:, None, None], pos, np.nan)
            ok = self.collision.free_batch(pos, body.radius_mm, stop_at_first=stop_at_first)
            self._count(t0, t1, len(qk), first is None)
            first = body if first is None else first
            if ok.all():
                continue
            if stop_at_first:  # the first row it left not free is the one that failed
                self.last_invalid = qk[int(np.argmin(ok))]
                return np.zeros(len(q), dtype=bool), first
            rows = np.flatnonzero(ok) if rows is None else rows[ok]
            if not rows.size:
                break
        valid = np.ones(len(q), dtype=bool)
        if rows is not None:
            valid[:] = False
            valid[rows] = True
        return valid, first

    def note_blocked(self, q: np.ndarray) -> None:
        """Record the invalid states (K, 2N) of K failed path attempts (appending references: no
        work on the planner's path beyond that)."""
        self.blocked.extend(q)
        self.blocked_total += len(q)

    def _validate_one(self, q1: np.ndarray) -> tuple[bool, Body]:
        """`validate` of a single configuration (1, 2N) without per-row arrays (the planner's hot
        path): the same stages (`Backend.body_query`), each checked by `RobotCollisionChecker.is_free`."""
        first = None
        for query in self._stage_queries:
            t0 = time.perf_counter()
            body = query(q1)
            t1 = time.perf_counter()
            free = bool(body.usable[0]) and self.collision.is_free(body.positions_mm[0], body.radius_mm[0])
            self._count(t0, t1, 1, first is None)
            first = body if first is None else first
            if not free:
                return False, first
        return True, first

    def _count(self, t0: float, t1: float, states: int, new: bool) -> None:
        """Count one validation stage of ``states`` configurations: kinematics from t0 to t1 and
        collision from t1 to now (`time.perf_counter` s); ``new``: their first stage."""
        c = self.counters
        c.collision_s += time.perf_counter() - t1
        c.collision_checks += states
        c.narrow_checks = self.collision.narrow_checks
        c.grid_contacts = self.collision.grid_contacts
        c.fcl_tests = self.collision.chain.tests
        self._count_kinematics(t1 - t0, states if new else 0)

    # ---- cache ---------------------------------------------------------------------------------
    @staticmethod
    def key(q: np.ndarray) -> bytes:
        return np.asarray(q, dtype=float).round(9).tobytes()

    def lookup(self, q: np.ndarray) -> _Entry | None:
        return self._cache.get(self.key(q))

    def _store(self, key: bytes, q: np.ndarray, entry: _Entry) -> None:
        if entry.valid and key not in self._cache:
            self.valid_q.append(np.array(q, dtype=float))
            self.valid_tips.append(self.scene.to_scene(entry.tip_robot))
            if len(self.valid_q) > 20_000:
                del self.valid_q[:5_000], self.valid_tips[:5_000]
        self._cache[key] = entry
        if len(self._cache) > self.cache_size:
            self._cache.popitem(last=False)

    # ---- public checks -----------------------------------------------------------------------------
    def check(self, q: np.ndarray) -> np.ndarray:
        """Validity of configurations (B, 2N) -> (B,) bool (cached; one backend call for the misses)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        keys = [self.key(qi) for qi in q]
        entries = [self._cache.get(k) for k in keys]
        miss = [i for i, e in enumerate(entries) if e is None]
        if miss:
            valid, body = self.validate(q[miss])
            for j, i in enumerate(miss):
                entries[i] = self._new_entry(keys[i], q[i], body, j, bool(valid[j]))
        return np.array([e.valid for e in entries])

    def is_valid(self, q: np.ndarray) -> bool:
        """Validity of one configuration (2N,) (cached): the planner's hot path."""
        key = self.key(q)
        e = self._cache.get(key)
        if e is None:
            q1 = np.asarray(q, dtype=float)[None]
            valid, body = self._validate_one(q1)
            e = self._new_entry(key, q1[0], body, 0, valid)
        return e.valid

    def _new_entry(self, key: bytes, q: np.ndarray, body: Body, i: int, valid: bool) -> _Entry:
        """Cache row i of a first-stage `Body` under ``key``."""
        if body.usable[i]:
            init = None if body.initial_state is None else body.initial_state[i].copy()
            e = _Entry(valid, body.positions_mm[i, -1].copy(), init)
        else:
            e = _Entry(valid, np.full(3, np.nan))
        self._store(key, q, e)
        return e

    def tip(self, q: np.ndarray) -> np.ndarray:
        """Tip position in the scene frame (NaN if the backend did not converge)."""
        e = self.lookup(q)
        if e is None:
            self.check(q)
            e = self.lookup(q)
        return self.scene.to_scene(e.tip_robot)

    def check_motion(self, q1: np.ndarray, q2: np.ndarray, resolution: float) -> bool:
        """Whether the straight coordinate line q1 -> q2 is valid at ``resolution`` (mm in the
        planning metric); q1 is assumed valid. The end state is checked alone first (cached) --
        most failing edges fail there, and every backend here pays per configuration -- then the
        interior states in bisection order, in batched backend calls of `EDGE_BATCHES` states
        (a short edge in one call; a long one, e.g. a path shortcut, stops computing kinematics at
        the first batch with an invalid state), stopping at the first invalid one."""
        self.counters.motions += 1
        if not self.is_valid(q2):
            self.note_blocked(q2[None])
            return False
        d = float(self.space.distance(q1, q2))
        n = max(1, int(np.ceil(d / resolution)))
        e1 = self.lookup(q1)
        guess = e1.initial_state[None, :] if (e1 is not None and e1.initial_state is not None) else None
        order = np.asarray(bisection_order(n), dtype=float)
        for a, b in edge_batches(len(order)):
            qs = self.space.interpolate(q1, q2, order[a:b] / n)
            g = None if guess is None else np.repeat(guess, len(qs), axis=0)
            if not self.validate(qs, guess=g, stop_at_first=True)[0].all():
                self.note_blocked(self.last_invalid[None])
                return False
        self.counters.valid_motions += 1
        return True


#: Sizes of the successive backend calls for an edge's interior states (the last one repeats).
EDGE_BATCHES = (15, 16, 32, 64)


def edge_batches(k: int) -> list[tuple[int, int]]:
    """Index ranges [a, b) splitting k interior states into batches of `EDGE_BATCHES` sizes."""
    out, a, i = [], 0, 0
    while a < k:
        b = min(k, a + EDGE_BATCHES[min(i, len(EDGE_BATCHES) - 1)])
        out.append((a, b))
        a, i = b, i + 1
    return out


def bisection_order(n: int) -> list[int]:
    """Interior indices 1..n-1 of a segment split in n, in bisection order (midpoints first)."""
    out: list[int] = []
    queue = [(0, n)]
    while queue:
        nxt = []
        for a, b in queue:
            if b - a < 2:
                continue
            m = (a + b) // 2
            out.append(m)
            nxt += [(a, m), (m, b)]
        queue = nxt
    return out


class ValidityChecker(ob.StateValidityChecker):
    """OMPL state validity: backend converged and collision-free (cached)."""

    def __init__(self, si, checker: ConfigurationChecker):
        super().__init__(si)
        self.checker = checker
        self.space = checker.space

    def isValid(self, state) -> bool:  # noqa: N802 - OMPL API
        return self.checker.is_valid(self.space.state_to_q(state))


class BatchMotionValidator(ob.MotionValidator):
    """OMPL motion validator: end state first, then the edge interior in one batched kinematics call
    at ``resolution`` mm (see `ConfigurationChecker.check_motion`)."""

    def __init__(self, si, checker: ConfigurationChecker, resolution: float | None = None):
        super().__init__(si)
        self.checker = checker
        self.space = checker.space
        self.resolution = float(resolution or checker.scene.settings.resolution_mm)

    def checkMotion(self, s1, s2, *rest) -> bool:  # noqa: N802 - OMPL API
        # The 2.0.1 bindings route the lastValid overload to this two-argument form.
        return self.checker.check_motion(self.space.state_to_q(s1), self.space.state_to_q(s2),
                                         self.resolution)
