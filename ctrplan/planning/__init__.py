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

`plan` runs the whole pipeline (search, simplification, exact validation and repair).
"""

from ctrplan.planning.goal import GoalSampler, TipGoal
from ctrplan.planning.ik import IKResult, backend_tip_jacobian, fd_tip_jacobian, solve_ik
from ctrplan.planning.planner import (
    OMPL_NAMES,
    PlanningProblem,
    PlanResult,
    build_problem,
    compile_kernels,
    make_planner,
    plan,
    resolve_backend,
    search,
    seed_ompl,
)
from ctrplan.planning.space import BoxSpace
from ctrplan.planning.validate import ValidatedPath, Validation, repair_path, validate_path
from ctrplan.planning.validity import (
    BatchMotionValidator,
    ConfigurationChecker,
    Counters,
    ValidityChecker,
)

__all__ = [
    "OMPL_NAMES", "BatchMotionValidator", "BoxSpace", "ConfigurationChecker",
    "Counters", "GoalSampler", "IKResult", "PlanResult", "PlanningProblem", "TipGoal", "Validation",
    "ValidatedPath", "ValidityChecker", "backend_tip_jacobian", "build_problem", "compile_kernels",
    "fd_tip_jacobian", "make_planner", "plan", "repair_path", "resolve_backend", "search", "seed_ompl",
    "solve_ik", "validate_path",
]
