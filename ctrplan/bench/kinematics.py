"""Runtime of single-query forward kinematics, the paper's runtime experiment.

N random snap-free configurations are solved one per call, as a sampling planner issues them, at each
requested number of backbone points. The Cosserat solver is timed cold (no initial guess) and warm
(initial state of a neighbouring configuration, as along a planner's edge); other backends have one
mode, ``-``. Only the `Backend.forward` call is timed; joints are sampled inside the domain, so
``check=False``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np

from ctrplan.base.memory import F8, backbone_bytes
from ctrplan.bench import timing_stats
from ctrplan.kinematics import Backend
from ctrplan.model.robot import Robot

#: Distance of the warm-start neighbour, per joint: 0.5 mm (beta), 0.5 deg (alpha).
NEIGHBOUR_STEP_MM, NEIGHBOUR_STEP_RAD = 0.5, math.radians(0.5)
#: Untimed calls per case before timing (compilation, caches).
WARMUP_CALLS = 3
#: Backbone points of the batched calls of `throughput` in `ctrplan bench kinematics`.
BATCH_POINTS = 64


@dataclass(frozen=True)
class Case:
    """One timed series: a backend, a mode (``cold``, ``warm`` or ``-``) and a number of points."""

    backend: str
    mode: str
    points: int

    @property
    def label(self) -> str:
        return self.backend if self.mode == "-" else f"{self.backend} ({self.mode})"


def modes(backend: Backend) -> tuple[str, ...]:
    """``cold`` and ``warm`` for a warm-startable backend (timed from a neighbour's state), else ``-``."""
    return ("cold", "warm") if backend.warm_startable else ("-",)


def cases(backends: dict[str, Backend], points: Sequence[int]) -> list[Case]:
    return [Case(name, m, p) for name, b in backends.items() for m in modes(b) for p in points]


def neighbours(robot: Robot, q: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Each configuration of q (B, 2N) moved by 0.5 mm / 0.5 deg per joint with random signs, clipped into the
    snap-free box."""
    domain = robot.domain
    n = robot.n_tubes
    step = np.array([NEIGHBOUR_STEP_MM] * n + [NEIGHBOUR_STEP_RAD] * n)
    moved = q + step * rng.choice((-1.0, 1.0), size=q.shape)
    return domain.from_box(np.clip(domain.to_box(moved), domain.box_lower, domain.box_upper))


def bytes_per_configuration(n_tubes: int, n_cases: int) -> int:
    """Memory (bytes) `run` holds per configuration: its joints, a neighbour, their warm start and
    backbone at 2 points, and a time, flags, iterations and residual per case."""
    return F8 * 3 * 2 * n_tubes + 2 * backbone_bytes(n_tubes, 2) + n_cases * (3 * F8 + 1)


def _time_calls(backend: Backend, q: np.ndarray, points: int, guesses: np.ndarray | None,
                tick: Callable[[], None] = lambda: None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per-call times (ms), convergence, iterations and boundary residual (1/m) of one forward call
    per row of q (B, 6)."""
    times = np.empty(len(q))
    converged = np.empty(len(q), dtype=bool)
    iterations = np.empty(len(q), dtype=np.int64)
    residual = np.empty(len(q))
    for i, qi in enumerate(q):
        kwargs = {} if guesses is None else {"guess": guesses[i]}
        start = time.perf_counter_ns()
        backbone = backend.forward(qi, points=points, check=False, **kwargs)
        times[i] = (time.perf_counter_ns() - start) * 1e-6
        converged[i] = backbone.converged[0]
        iterations[i] = backbone.iterations[0]
        residual[i] = backbone.residual[0]
        tick()
    return times, converged, iterations, residual


def run(backends: dict[str, Backend], n: int, points: Sequence[int], seed: int = 0,
        tick: Callable[[Case], None] = lambda case: None
        ) -> tuple[list[dict[str, Any]], dict[Case, np.ndarray]]:
    """Time every case of ``backends`` x modes x ``points`` on n configurations drawn with ``seed``.

    Returns the summary rows (one per case, JSON-ready) and the per-call times (ms) of each case.
    ``tick(case)`` is called after every timed call (progress display; not timed).
    """
    robot = next(iter(backends.values())).robot
    rng = np.random.default_rng(seed)
    q = robot.sample_joints(n, rng)
    q_warmup = robot.sample_joints(WARMUP_CALLS, rng)
    guesses: dict[str, np.ndarray] = {}
    for name in backends:
        if backends[name].warm_startable:
            nearby = neighbours(robot, np.concatenate([q, q_warmup]), rng)
            guesses[name] = backends[name].forward(nearby, points=2, check=False).initial_state
    rows, times = [], {}
    for case in cases(backends, points):
        backend = backends[case.backend]
        guess = guesses[case.backend] if case.mode == "warm" else None
        _time_calls(backend, q_warmup, case.points, None if guess is None else guess[n:])
        t, converged, iterations, residual = _time_calls(backend, q, case.points,
                                               None if guess is None else guess[:n], partial(tick, case))
        times[case] = t
        rows.append({"backend": case.backend, "mode": case.mode, "points": case.points, "n": n,
                     **timing_stats(t), "failures": int(np.count_nonzero(~converged)),
                     "median_iterations": float(np.median(iterations)),
                     "max_residual_per_m": float(residual[converged].max()) if converged.any() else None,
                     "settings": backend.describe()})
    return rows, times


def throughput(backends: dict[str, Backend], points: int, batch: int = 5000, seed: int = 1,
               min_seconds: float = 1.0) -> list[dict[str, Any]]:
    """Batched evaluation rate: one ``forward`` call on ``batch`` configurations, repeated for at
    least ``min_seconds``, on every core the process may use. Rows: backend, points, batch,
    backbones_per_s, calls, failures, settings (`Backend.describe`)."""
    robot = next(iter(backends.values())).robot
    q = robot.sample_joints(batch, np.random.default_rng(seed))
    rows = []
    for name, backend in backends.items():
        backend.forward(q[:8], points=points, check=False)  # compile / warm caches
        calls, failures, start = 0, 0, time.perf_counter()
        while True:
            backbone = backend.forward(q, points=points, check=False)
            calls += 1
            failures += int(np.count_nonzero(~backbone.converged))
            elapsed = time.perf_counter() - start
            if elapsed >= min_seconds:
                break
        rows.append({"backend": name, "points": points, "batch": batch,
                     "backbones_per_s": calls * batch / elapsed, "calls": calls, "failures": failures,
                     "settings": backend.describe()})
    return rows
