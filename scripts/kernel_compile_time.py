#!/usr/bin/env python3
"""Cold-cache compile time of the Cosserat kernels over the calls a session makes, for two robots::

    NUMBA_CACHE_DIR=$(mktemp -d) python scripts/kernel_compile_time.py

Each robot prints the seconds its calls took (compiling every kernel they need: a single row, a
batch, other output points, warm starts, a path, stability, settings given as integers), then the
total. Run it with an empty cache directory: with a warm one it measures loading, not compiling.
"""

from __future__ import annotations

import time
from pathlib import Path

from ctrplan.kinematics.base import ArcFractions
from ctrplan.kinematics.cosserat import CosseratBackend, SolverSettings
from ctrplan.model.robot import Robot

ROOT = Path(__file__).resolve().parents[1]


def session_calls(robot: Robot) -> None:
    """The backend calls planning, training and fitting make, each once."""
    backend = CosseratBackend(robot)
    q = robot.sample_joints(4, rng=0)
    backend.forward(q[0], points=10)
    solved = backend.forward(q, points=10)
    backend.forward(q, points=ArcFractions(12))
    backend.forward(q, points=10, guess=solved.initial_state)
    backend.forward(q[:1], points=10, guess=solved.initial_state[:1])
    backend.forward_path(q, points=10)
    backend.checking_stability().forward(q, points=10)
    CosseratBackend(robot, SolverSettings(step_multi_mm=2, max_iterations=40)).forward(q, points=10)


def main() -> None:
    start = time.perf_counter()
    for robot in (Robot.nominal(), Robot.load(ROOT / "examples" / "robots" / "two_tube.yaml")):
        t = time.perf_counter()
        session_calls(robot)
        print(f"{robot.name}: {time.perf_counter() - t:.1f} s", flush=True)
    print(f"total: {time.perf_counter() - start:.1f} s")


if __name__ == "__main__":
    main()
