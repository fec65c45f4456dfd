"""Motion planning for CTRs with OMPL: state space, validity, goal, IK, planners, exact validation.

The pieces are usable with any OMPL planner from user code::

    from ompl import geometric as og
    from ctrplan.planning import build_problem, resolve_backend
    from ctrplan.scene import load_scene

    scene = load_scene("scenes/open.yaml")
    problem = build_problem(scene, resolve_backend("cosserat", scene.robot))
    planner = og.RRTstar(problem.si)
    planner.setProblemDefinition(problem.pdef)
    planner.setup()
    planner.solve(5.0)
    path_q = problem.solution()

`plan` runs the whole pipeline (search, simplification, exact validation and repair) on one frozen
`PlanningModel` (scene, backends, margins, collision world, the stability decision), with per-search
data in a `ConfigurationChecker`.

The names below load their modules on first use (PEP 562), so that ``ctrplan.planning.planners`` -- the
planner table the CLI help reads -- loads without OMPL, torch or numba.
"""

from __future__ import annotations

import importlib
from typing import Any

_MODULES = {
    "goal": ("GoalSampler", "TipGoal"),
    "ik": ("IKResult", "backend_tip_jacobian", "fd_tip_jacobian", "solve_ik"),
    "model": ("PlanningModel", "StabilityDecision", "exact_backend"),
    "planner": ("compile_kernels", "plan", "resolve_backend"),
    "result": ("PlanResult", "PlanWork"),
    "search": ("PlanningProblem", "build_problem", "problem_for", "search", "seed_ompl"),
    "planners": ("OMPL_NAMES", "PLANNERS", "PlannerSpec", "make_planner"),
    "space": ("BoxSpace",),
    "validate": ("FailingState", "ValidatedPath", "Validation", "measure_clearance", "repair_path",
                 "validate_planned_path", "validate_path"),
    "validity": ("BatchMotionValidator", "ConfigurationChecker", "Counters", "ValidityChecker"),
}
_WHERE = {name: module for module, names in _MODULES.items() for name in names}
__all__ = sorted(_WHERE)


def __getattr__(name: str) -> Any:
    if name not in _WHERE:
        raise AttributeError(f"module 'ctrplan.planning' has no attribute {name!r}")
    return getattr(importlib.import_module(f"ctrplan.planning.{_WHERE[name]}"), name)


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
