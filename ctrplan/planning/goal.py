"""The goal: the robot tip inside the target region, made sampleable by inverse kinematics.

`GoalSampler` produces collision-free goal configurations in batches: it draws random
configurations, keeps those whose tip lies nearest the target, moves them into the region with
damped-least-squares IK (`ctrplan.planning.ik`, one batched Jacobian call per iteration) and keeps the
valid ones; later batches also start from perturbed copies of goals already found, which matters when
the valid goal set is thin. A target with an approach direction keeps only goals whose tip tangent is
within its angular tolerance, and prefers seeds that point that way. `TipGoal` exposes it to OMPL as
a ``GoalSampleableRegion`` so bidirectional planners (RRTConnect) and goal-biased ones work.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
from ompl import base as ob

from ctrplan.kinematics.backbone import Backbone
from ctrplan.kinematics.base import tangent_of
from ctrplan.planning.budget import SearchBudget
from ctrplan.planning.ik import IKResult, TipJacobian, backend_tip_jacobian, solve_ik
from ctrplan.planning.validity import ConfigurationChecker
from ctrplan.scene.objects import Scene, TargetRegion

#: Seed ranking: mm of tip distance that one radian of approach-angle excess counts as.
ANGLE_WEIGHT_MM_PER_RAD = 20.0
#: IK iterations of a goal batch, and after how many the batch stops if it found a goal already. The
#: seeds start near the target (the nearest of many random ones, goals found, the start): those that
#: reach it mostly do so within a few iterations, and each iteration costs a Jacobian for every seed
#: still running. Where none of those is a goal (their solutions, near the seeds, collide) the seeds
#: run on exactly as without the check: the farther solutions can be the valid ones. Skull base, PINN:
#: goal sampling 44 -> 29 ms median a plan, 14 % fewer kinematics calls (docs/benchmarks.md).
IK_ITERATIONS = 25
IK_CHECK_AFTER = 8
#: Rejected goal candidates a sampler keeps for the explanation of a failed search.
REJECTED_KEPT = 400


def tip_tangents(scene: Scene, bb: Backbone) -> np.ndarray:
    """Unit tangent of the backbone at the tip (B, 3), scene frame."""
    return scene.direction_to_scene(tangent_of(bb.quaternions[:, -1]))


@dataclass
class GoalStats:
    batches: int = 0
    seeds: int = 0
    ik_reached: int = 0
    wrong_direction: int = 0
    rejected: int = 0
    valid: int = 0
    closest_mm: float = float("inf")


class GoalSampler:
    """Collision-free configurations whose tip (scene frame) lies in ``region``.

    Args:
        checker: validity + kinematics (its backend is used for IK; calls are counted).
        region: the target region (scene frame).
        rng: numpy generator (seeded by the planner).
        jacobian: tip Jacobian (default: the backend's ``tip_jacobian`` or finite differences).
        seeds_per_batch: IK seeds per batch.
        candidates_per_seed: random configurations drawn per seed to pick seeds near the target.
        start: the start configuration (seeds are derived from it).
        rotation_weight: IK cost of rotations relative to translations (see `solve_ik`).
        hints: configurations (K, 2N) near the target to start the first batches from, e.g. the goals
            another backend found (an exact repair starts from the PINN's).
    """

    def __init__(self, checker: ConfigurationChecker, region: TargetRegion, rng: np.random.Generator,
                 jacobian: TipJacobian | None = None, seeds_per_batch: int = 24,
                 candidates_per_seed: int = 10, start: np.ndarray | None = None,
                 rotation_weight: float = 8.0, hints: np.ndarray | None = None):
        self.checker = checker
        self.region = region
        self.rng = rng
        self.space = checker.space
        self.jacobian = jacobian or backend_tip_jacobian(checker.backend, self.space,
                                                         forward=checker.forward, tips=checker.tips)
        self.seeds_per_batch = int(seeds_per_batch)
        self.candidates_per_seed = int(candidates_per_seed)
        self.goals: list[np.ndarray] = []
        self.stats = GoalStats()
        self._near: list[np.ndarray] = []  # IK solutions that reached the region but collide
        #: the goal candidates rejected (IK solutions in the region, along its approach direction,
        #: invalid), the latest `REJECTED_KEPT`: what a failed search's explanation examines
        self.rejected: deque[np.ndarray] = deque(maxlen=REJECTED_KEPT)
        self.start = None if start is None else np.asarray(start, dtype=float)
        self.rotation_weight = float(rotation_weight)
        self.hints = np.zeros((0, checker.scene.robot.n_joints)) if hints is None else np.atleast_2d(hints)

    def _random_seeds(self, n: int) -> np.ndarray:
        m = n * self.candidates_per_seed
        q = self.space.sample(m, self.rng)
        tip, tangent, converged = self.checker.tips(q)
        scene = self.checker.scene
        d = self.region.distance(scene.to_scene(tip))
        if self.region.direction is not None:
            angle = self.region.angle_rad(scene.direction_to_scene(tangent))
            excess = angle - self.region.angle_tolerance_rad
            d = d + ANGLE_WEIGHT_MM_PER_RAD * np.maximum(excess, 0.0)
        d = np.where(converged & np.isfinite(d), d, np.inf)
        return q[np.argsort(d)[:n]]

    def directions_ok(self, q: np.ndarray) -> np.ndarray:
        """Whether the tips of configurations (B, 2N) respect the target's approach direction."""
        if self.region.direction is None or len(q) == 0:
            return np.ones(len(q), dtype=bool)
        _, tangent, converged = self.checker.tips(q)
        return self.region.direction_ok(self.checker.scene.direction_to_scene(tangent)) & converged

    def _frontier(self, m: int) -> np.ndarray:
        """Valid states met so far (e.g. by the planner's trees) whose tips are nearest the target,
        slightly perturbed: IK from there stays in the free space more often than from random
        seeds."""
        if m <= 0 or not self.checker.valid_q:
            return np.zeros((0, self.checker.scene.robot.n_joints))
        tips = np.asarray(self.checker.valid_tips)
        d = self.region.distance(tips)
        d = np.where(np.isfinite(d), d, np.inf)
        best = np.argsort(d)[: max(m, 1) * 3]
        pick = self.rng.choice(best, size=m, replace=len(best) < m)
        return self._perturbed([self.checker.valid_q[i] for i in pick], m, sigma=1.0)

    def _perturbed(self, base: list[np.ndarray], n: int, sigma: float) -> np.ndarray:
        pick = self.rng.integers(len(base), size=n)
        y = self.space.to_coords(np.stack([base[i] for i in pick]))
        y = y + self.rng.normal(scale=sigma, size=y.shape)
        return self.space.to_joints(self.space.clip(y))

    def _seeds(self, n: int) -> np.ndarray:
        """IK seeds (about n, 2N) for a batch: perturbed goals (or near misses), turned and redrawn
        copies of the start, the frontier of valid states nearest the target, random configurations
        whose tips lie nearest it."""
        parts = []
        if self.goals:
            parts.append(self._perturbed(self.goals, n // 3, sigma=3.0))
        elif self._near:
            parts.append(self._perturbed(self._near, n // 4, sigma=3.0))
        if self.start is not None:
            # the start is valid: in narrow anatomy its shape leads to valid goals (IK that prefers
            # insertion over rotation); one coordinate per seed is redrawn at random so that e.g.
            # one tube's rotation can change entirely
            m = n // 3 if self.goals else n // 2
            y = self.space.to_coords(self._perturbed([self.start], m, sigma=1.0))
            # each tube turned by a quarter, half and three-quarter turn; the rest: one
            # coordinate redrawn at random (mostly a rotation)
            rot = np.flatnonzero(self.space.is_rotation)
            trans = np.flatnonzero(~self.space.is_rotation)
            rot = rot if rot.size else trans
            trans = trans if trans.size else rot
            j = np.where(self.rng.uniform(size=m) < 0.75, self.rng.choice(rot, size=m),
                         self.rng.choice(trans, size=m))
            quarters = self.rng.integers(1, 4, size=m)
            use_turn = np.zeros(m, dtype=bool)
            if self.space.is_rotation.any():
                k = min(m, 3 * rot.size)  # every (tube, quarter turn) pair once per batch
                j[:k] = rot[np.arange(k) // 3]
                quarters[:k] = 1 + np.arange(k) % 3
                use_turn[:k] = True
            redrawn = self.rng.uniform(self.space.lower[j], self.space.upper[j])
            w = self.space.mm_per_rad
            turn = y[np.arange(m), j] + w * (quarters * 0.5 * np.pi + self.rng.normal(scale=0.1, size=m))
            lo, hi = self.space.lower[j], self.space.upper[j]
            turn = lo + np.mod(turn - lo, hi - lo)  # wrap into the box
            y[np.arange(m), j] = np.where(use_turn, turn, redrawn)
            parts.append(self.space.to_joints(y))
        frontier = self._frontier(min(n // 4, n - sum(len(p) for p in parts)))
        if len(frontier):
            parts.append(frontier)
        k = max(n // 6, n - sum(len(p) for p in parts))
        parts.append(self._random_seeds(k))
        return np.concatenate(parts)

    def _reached(self, res: IKResult) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Of an IK result: each row's tip distance to the region (B,) mm (inf: not converged), the
        rows inside it along the approach direction (K,), which of those are valid for the checker
        (K,) (cached), and which are goals (K,): valid, with the planning backend's own tip inside."""
        dist = self.region.distance(self.checker.scene.to_scene(res.tip))
        dist = np.where(np.isfinite(dist), dist, np.inf)
        inside = np.flatnonzero(dist <= 0.0)
        inside = inside[self.directions_ok(res.q[inside])]
        valid = self.checker.check(res.q[inside]) if inside.size else np.zeros(0, dtype=bool)
        goal = np.array([v and self.region.contains(self.checker.tip(res.q[i]))
                         for i, v in zip(inside, valid, strict=True)], dtype=bool)
        return dist, inside, valid, goal

    def sample_batch(self) -> list[np.ndarray]:
        """Run one IK batch; return the new valid goal configurations (also kept in ``goals``). While
        ``hints`` remain, a batch starts from them alone (unperturbed)."""
        if len(self.hints):
            seeds, self.hints = self.hints[:self.seeds_per_batch], self.hints[self.seeds_per_batch:]
        else:
            seeds = self._seeds(self.seeds_per_batch)
        targets_scene = self.region.sample(len(seeds), self.rng)
        shrink = 0.7  # aim well inside the region
        targets_scene = self.region.center + shrink * (targets_scene - self.region.center)
        targets = self.checker.scene.to_robot(targets_scene)
        tol = min(0.3, 0.25 * self.region.tolerance_mm)
        res = solve_ik(self.jacobian, self.space, seeds, targets, tol_mm=tol, max_iterations=IK_ITERATIONS,
                       rotation_weight=self.rotation_weight, check_after=IK_CHECK_AFTER,
                       enough=lambda partial: bool(self._reached(partial)[3].any()))
        dist, inside, valid, goal = self._reached(res)
        self.stats.batches += 1
        self.stats.seeds += len(seeds)
        self.stats.closest_mm = float(min(self.stats.closest_mm, dist.min(initial=np.inf)))
        reached = int((dist <= 0.0).sum())
        self.stats.ik_reached += reached
        self.stats.wrong_direction += reached - inside.size
        new = [res.q[i] for i in inside[goal]]
        self._near.extend(res.q[i] for i in inside[~valid])  # reached the region, collide
        self._near = self._near[-200:]
        self.rejected.extend(res.q[i] for i in inside[~valid])
        self.stats.rejected += int((~valid).sum())
        self.stats.valid += len(new)
        self.goals.extend(new)
        return new


class TipGoal(ob.GoalSampleableRegion):
    """OMPL goal region: the tip inside the target region; samples come from a `GoalSampler`.

    ``sampleGoal`` hands out the goals found so far in turn and runs a new IK batch once all have
    been handed out -- at most once every ``refill_states`` states the checker evaluates since the
    last batch, the batches sampled before the search included (always while none is known), never
    once ``budget`` (a `SearchBudget`) is exhausted and at most ``max_batches`` times. Counting work,
    not seconds, keeps a seeded search the same under any load. ``maxSampleCount`` only promises more
    samples when such a batch may run, so planners that drain all goal samples up front (BIT*)
    terminate. With nothing to give, ``sampleGoal`` writes an out-of-bounds state, which OMPL's goal
    sampling rejects.
    """

    def __init__(self, si, sampler: GoalSampler, max_batches: int = 200, refill_states: int = 2000,
                 budget: SearchBudget | None = None):
        super().__init__(si)
        self.sampler = sampler
        self.checker = sampler.checker
        self.space = sampler.space
        self.max_batches = int(max_batches)
        self.refill_states = int(refill_states)
        self.budget = budget
        self.setThreshold(1e-9)
        self.calls = 0
        self.handed_out = 0
        self._last_refill: int | None = None  # the checker's state count at the last batch

    def _may_refill(self) -> bool:
        if self.sampler.stats.batches >= self.max_batches:
            return False
        if self.budget is not None and self.budget.exhausted():
            return False
        states = self.checker.counters.kinematics_calls
        return (not self.sampler.goals or self._last_refill is None
                or states - self._last_refill >= self.refill_states)

    def sample_batch(self) -> list[np.ndarray]:
        """Run one IK batch of the sampler now (the goals sampled before a search too: the next
        batch follows ``refill_states`` states after it); returns the new goals."""
        self._last_refill = self.checker.counters.kinematics_calls
        return self.sampler.sample_batch()

    def distanceGoal(self, state) -> float:  # noqa: N802 - OMPL API
        q = self.space.state_to_q(state)
        d = float(self.sampler.region.distance(self.checker.tip(q)))
        if d == 0.0 and not self.sampler.directions_ok(q[None])[0]:
            return 1.0  # tip inside, approach direction wrong: not satisfied
        return d if np.isfinite(d) else 1e9

    def sampleGoal(self, state) -> None:  # noqa: N802 - OMPL API
        self.calls += 1
        goals = self.sampler.goals
        if self.handed_out >= len(goals) and self._may_refill():
            self.sample_batch()
            goals = self.sampler.goals
        if not goals:
            for i in range(self.space.dimension):
                state[i] = float(self.space.upper[i] + 1.0)
            return
        q = goals[self.handed_out % len(goals)]
        self.handed_out += 1
        self.space.set_state(state, q)

    def maxSampleCount(self) -> int:  # noqa: N802 - OMPL API
        # absolute, like OMPL's own goals: planners compare it with their count of samples drawn
        # (every `sampleGoal` call), so while a batch may run, one more than drawn so far -- with no
        # goal yet, RRTConnect would otherwise wait out its whole budget for one
        goals = len(self.sampler.goals)
        return max(goals, self.calls + 1) if self._may_refill() else goals

    def couldSample(self) -> bool:  # noqa: N802 - OMPL API
        return bool(self.sampler.goals) or self._may_refill()
