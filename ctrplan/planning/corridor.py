"""Corridor RRT-Connect: a bidirectional RRT that checks a batch of extensions per kinematics call and
draws most of its samples around the straight lines from the start to the goals found.

Why (skull base, PINN; numbers in docs/benchmarks.md): 0.1 % of the joint box is valid, and RRT-Connect's
uniform samples pull 97 % of its extensions out of the narrow valid set, each failure paying one
single-state kinematics call. The valid set of an insertion through anatomy is a corridor whose ends
are the start and the goal configurations, so this planner samples there: with probability
``corridor_share`` a point of the segment from the start to a random goal root, plus isotropic Gaussian
noise of ``corridor_width_mm`` (planning metric); otherwise uniformly in the box, which keeps every
region of the domain reachable (the noise covers the whole box too). Extensions are then checked
``batch`` at a time in one backend call (`ConfigurationChecker.check`, cached), their edges' interior
states in another, at the motion validator's resolution -- the same checks as RRT-Connect's, batched.

The trees, nearest-neighbour search and steering are numpy (states in the `BoxSpace` coordinates OMPL
uses; a rotation whose interval is a full turn wraps: neighbours, steps and edges go the short way
round, `BoxSpace.difference`); the planner is an ``ob.Planner``, so the wiring (problem definition,
termination condition, solution path, goal sampling through `TipGoal`) is OMPL's.
"""

from __future__ import annotations

import math

import numpy as np
from ompl import base as ob
from ompl import geometric as og
from ompl import util as ou

from ctrplan.planning.space import BoxSpace, split_segments
from ctrplan.planning.validity import ConfigurationChecker

#: Share of samples drawn around the start-goal segments (the rest: uniform in the box).
CORRIDOR_SHARE = 0.9
#: Standard deviation (mm, planning metric) of the samples about a start-goal segment.
CORRIDOR_WIDTH_MM = 25.0
#: Most extensions checked per kinematics call; the batch is the expected number of attempts per
#: successful extension so far (narrow anatomy: many; open space: one), capped here.
MAX_BATCH = 8


class CorridorSampler:
    """Samples (n, D) in box coordinates: a mixture of points about the segments from ``start`` to
    ``goals`` (share ``share``, Gaussian of ``width_mm``) and uniform points in the box. The random
    numbers are drawn `BLOCK` rows at a time (a search asks for a few samples at a time, and each
    call of the generator costs microseconds whatever its size)."""

    BLOCK = 256

    def __init__(self, space: BoxSpace, rng: np.random.Generator, share: float = CORRIDOR_SHARE,
                 width_mm: float = CORRIDOR_WIDTH_MM):
        self.space, self.rng = space, rng
        self.share, self.width_mm = float(share), float(width_mm)
        self._next = self._rows = 0  # next unused row of the block, rows in it

    def _draw(self, n: int) -> None:
        rng, space = self.rng, self.space
        self._box = rng.uniform(space.lower, space.upper, size=(n, space.dimension))
        self._near = rng.uniform(size=n) < self.share
        self._which = rng.uniform(size=n)  # which goal: floor(which * goals)
        self._t = rng.uniform(size=(n, 1))
        self._noise = rng.normal(scale=self.width_mm, size=(n, space.dimension))
        self._next, self._rows = 0, n

    def sample(self, n: int, start: np.ndarray, goals: np.ndarray) -> np.ndarray:
        """``n`` samples; ``start`` (D,), ``goals`` (G, D) box coordinates (none: uniform only)."""
        if self._rows == 0 or self._next + n > self._rows:
            self._draw(max(n, self.BLOCK))
        rows = slice(self._next, self._next + n)
        self._next += n
        y = self._box[rows].copy()
        if len(goals):
            near = self._near[rows]
            g = goals[(self._which[rows][near] * len(goals)).astype(int)]
            step = self.space.difference(start, g)  # the short way round a wrapping rotation
            y[near] = self.space.clip(start + self._t[rows][near] * step + self._noise[rows][near])
        return y


class _Tree:
    """States (K, D) in box coordinates and each one's parent (-1: a root); nearest in the planning
    metric of ``space`` (wrapping rotations the short way)."""

    def __init__(self, space: BoxSpace):
        self.space = space
        self.y = np.empty((64, space.dimension))
        self.parent = np.empty(64, dtype=np.int64)
        self.size = 0

    def add(self, y: np.ndarray, parent: np.ndarray) -> np.ndarray:
        """Append states (k, D) with their parents (k,); returns their indices."""
        k = len(y)
        while self.size + k > len(self.y):
            self.y = np.concatenate([self.y, np.empty_like(self.y)])
            self.parent = np.concatenate([self.parent, np.empty_like(self.parent)])
        idx = np.arange(self.size, self.size + k)
        self.y[idx], self.parent[idx] = y, parent
        self.size += k
        return idx

    @property
    def roots(self) -> np.ndarray:
        return self.y[:self.size][self.parent[:self.size] < 0]

    def nearest(self, y: np.ndarray) -> np.ndarray:
        """Index of the nearest state to each row of y (k, D)."""
        nodes = self.y[:self.size]
        if self.space.wraps.any():
            step = self.space.difference(y[:, None, :], nodes[None, :, :])
            return np.argmin(np.einsum("knd,knd->kn", step, step), axis=1)
        d2 = np.einsum("nd,nd->n", nodes, nodes)[None, :] - 2.0 * y @ nodes.T
        return np.argmin(d2, axis=1)

    def branch(self, i: int) -> list[int]:
        """Indices from the root to state i."""
        out = [int(i)]
        while self.parent[out[-1]] >= 0:
            out.append(int(self.parent[out[-1]]))
        return out[::-1]


class CorridorRRTConnect(ob.Planner):
    """Bidirectional RRT with batched checks and corridor sampling (see the module docstring).

    Args:
        si: OMPL space information (its state space is ``checker.space``'s).
        checker: validity of states (cached) and batches of edge states.
        start: start joints (2N,) mm, rad (the problem definition's: its ``getStartState`` crashes
            in the OMPL 2 Python bindings here).
        range_mm: longest extension (planning metric).
        resolution_mm: spacing of the checked states along an edge (the motion validator's).
        rng: numpy generator (seed it for repeatable searches).
    """

    def __init__(self, si, checker: ConfigurationChecker, start: np.ndarray, range_mm: float,
                 resolution_mm: float, rng: np.random.Generator, max_batch: int = MAX_BATCH):
        super().__init__(si, "CorridorRRTConnect")
        self.checker, self.space = checker, checker.space
        self.start = np.asarray(start, dtype=float)
        self.range_mm, self.resolution_mm = float(range_mm), float(resolution_mm)
        self.max_batch = int(max_batch)
        self.sampler = CorridorSampler(self.space, rng)
        self._state = si.allocState()

    @classmethod
    def for_problem(cls, problem, range_mm: float | None = None) -> CorridorRRTConnect:
        """The planner of a `PlanningProblem`: its checker, start and motion resolution; ``range_mm``
        None: a fifth of the box's diagonal (OMPL's default range). Its numpy generator is seeded
        from OMPL's (`seed_ompl` makes it repeatable)."""
        space = problem.checker.space
        if range_mm is None:
            range_mm = 0.2 * float(np.linalg.norm(space.upper - space.lower))
        rng = np.random.default_rng(ou.RNG().uniformInt(0, 2**31 - 2))
        return cls(problem.si, problem.checker, problem.start, range_mm, problem.motion_validator.resolution,
                   rng)

    # ---- checks --------------------------------------------------------------------------------
    def _valid(self, y: np.ndarray) -> np.ndarray:
        return self.checker.check(self.space.to_joints(y)).astype(bool)

    def _motions_valid(self, y1: np.ndarray, y2: np.ndarray) -> np.ndarray:
        """Whether each edge y1[k] -> y2[k] is valid inside (its ends are checked already): its
        interior states at ``resolution_mm``, all edges in one backend call."""
        step = self.space.difference(y1, y2)
        pieces = np.maximum(1, np.ceil(np.linalg.norm(step, axis=1) / self.resolution_mm)).astype(int)
        segment, t = split_segments(pieces)
        if not len(segment):
            return np.ones(len(y1), dtype=bool)
        valid, _ = self.checker.validate(self.space.to_joints(y1[segment] + t[:, None] * step[segment]))
        return np.bincount(segment[~valid], minlength=len(y1)) == 0

    def _edges_valid(self, y1: np.ndarray, y2: np.ndarray) -> np.ndarray:
        """Validity of edges y1[k] -> y2[k] (y1 valid): end states first, then the interiors of the
        edges whose ends are valid."""
        ok = self._valid(y2)
        if ok.any():
            ok[ok] = self._motions_valid(y1[ok], y2[ok])
        return ok

    # ---- tree growth ---------------------------------------------------------------------------
    def _grow(self, tree: _Tree, goals: _Tree) -> np.ndarray:
        """Extend ``tree`` towards a batch of samples by at most ``range_mm`` each; returns the indices
        of the states added."""
        batch = min(self.max_batch, math.ceil(self._tries / self._successes))
        sample = self.sampler.sample(batch, self._start_y, goals.roots)
        near = tree.nearest(sample)
        step = self.space.difference(tree.y[near], sample)
        d = np.linalg.norm(step, axis=1, keepdims=True)
        new = self.space.clip(tree.y[near] + np.minimum(1.0, self.range_mm / np.maximum(d, 1e-300)) * step)
        ok = self._edges_valid(tree.y[near], new)
        self._tries += batch
        self._successes += int(ok.sum())
        return tree.add(new[ok], near[ok])

    def _connect(self, tree: _Tree, target: np.ndarray) -> tuple[bool, int]:
        """Extend ``tree`` from its state nearest ``target`` straight towards it in steps of
        ``range_mm``, checked 1, 2, 4, ... steps per call, until a step fails or the target is
        reached; returns (reached, index of the last state added or of the nearest)."""
        last = int(tree.nearest(target[None])[0])
        origin = tree.y[last].copy()
        step = self.space.difference(origin, target)
        d = float(np.linalg.norm(step))
        steps = max(1, math.ceil(d / self.range_mm))
        frac = np.minimum(1.0, np.arange(1, steps + 1) * self.range_mm / max(d, 1e-300))
        frac[-1] = 1.0
        line = self.space.clip(origin + frac[:, None] * step)
        k, chunk = 0, 1
        while k < steps:
            stop = min(steps, k + chunk)
            ends = line[k:stop]
            starts = np.vstack([tree.y[last][None], ends[:-1]])
            ok = self._edges_valid(starts, ends)
            n = len(ok) if ok.all() else int(np.argmin(ok))
            if n:  # a chain: each state's parent is the one before
                last = int(tree.add(ends[:n], np.concatenate([[last], tree.size + np.arange(n - 1)]))[-1])
            if n < len(ok):
                return False, last
            k, chunk = stop, 2 * chunk
        return True, last

    def _draw_goal(self, goal, goals: _Tree) -> None:
        """One more goal root from the problem's goal (`TipGoal`: IK-sampled), if it can give one."""
        if not goal.couldSample() or goal.maxSampleCount() <= self._drawn:
            return
        goal.sampleGoal(self._state)
        self._drawn += 1
        y = self.space.state_coords(self._state)
        inside = np.all(y >= self.space.lower) and np.all(y <= self.space.upper)
        if inside and self._valid(y[None])[0]:
            goals.add(y[None], np.array([-1]))

    # ---- OMPL ----------------------------------------------------------------------------------
    def _solution(self, starts: _Tree, i_start: int, goals: _Tree, i_goal: int) -> None:
        """Write the path start root -> starts[i_start] = goals[i_goal] -> goal root into the problem."""
        y = np.concatenate([starts.y[starts.branch(i_start)], goals.y[goals.branch(i_goal)[::-1][1:]]])
        si = self.getSpaceInformation()
        path = og.PathGeometric(si)
        for row in y:
            for j, v in enumerate(row):
                self._state[j] = float(v)
            path.append(self._state)
        self.getProblemDefinition().addSolutionPath(path, False, 0.0, self.getName())

    def solve(self, ptc):  # noqa: D102 - OMPL API
        goal = self.getProblemDefinition().getGoal()
        self._start_y = self.space.clip(self.space.to_coords(self.start))
        self._tries, self._successes = 1, 1  # extension attempts and successes (a prior of one each)
        self._drawn = 0  # goal samples drawn
        starts, goals = _Tree(self.space), _Tree(self.space)
        if not self._valid(self._start_y[None])[0]:
            return ob.PlannerStatus(ob.PlannerStatus.INVALID_START)
        starts.add(self._start_y[None], np.array([-1]))
        active, other = starts, goals
        while not ptc():
            if not goals.size or self._drawn < goals.size / 2:
                self._draw_goal(goal, goals)
            if not goals.size:
                if not goal.couldSample() or goal.maxSampleCount() <= self._drawn:
                    return ob.PlannerStatus(ob.PlannerStatus.INVALID_GOAL)
                continue
            for i in self._grow(active, goals):
                reached, last = self._connect(other, active.y[i])
                if reached:
                    ends = (i, last) if active is starts else (last, i)
                    self._solution(starts, ends[0], goals, ends[1])
                    return ob.PlannerStatus(ob.PlannerStatus.EXACT_SOLUTION)
            active, other = other, active
        return ob.PlannerStatus(ob.PlannerStatus.TIMEOUT)
