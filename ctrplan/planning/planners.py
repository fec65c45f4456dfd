"""The one table of OMPL planners ctrplan runs, by name (as OMPL's Python demos allocate theirs).

Adding a planner is one row of `PLANNERS`: the CLI help (``plan --planner``, ``bench plan --planner``),
the benchmark's default set, the docs script (update_readme.py) and the name in OMPL's logs all read
it. A scene file
names its planner as a string (``planner: {planner: ...}``, the model layer knows no planners); it is
checked against this table where the scene is used for planning (`scene_planner`: ``plan``,
``scene check``), with the file and line of the name.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ctrplan.base.errors import InputError


@dataclass(frozen=True)
class PlannerSpec:
    """One OMPL geometric planner (the class ``ompl.geometric.<ompl_name>``) and how ctrplan runs it.

    Attributes:
        ompl_name: OMPL's class name (also used in logs and benchmark databases).
        optimizing: asymptotically optimal: gets a path-length objective and uses its whole budget.
        fixed_goal_set: drains every goal sample whenever it (re)starts a batch (BIT*): give it a
            fixed set of goal configurations before the search.
        benchmarked: in the default set of ``ctrplan bench plan``.
        own: ctrplan's own ``ob.Planner`` (`ctrplan.planning.corridor`), built from the whole
            `PlanningProblem` (it checks batches of states with its checker), not an OMPL class.
    """

    ompl_name: str
    optimizing: bool = False
    fixed_goal_set: bool = False
    benchmarked: bool = False
    own: bool = False

    def make(self, si: Any, range_mm: float | None = None, problem: Any = None) -> Any:
        """The planner on the OMPL ``SpaceInformation`` ``si``, its maximum edge length set to
        ``range_mm`` (planning metric, mm) where it has one (None: OMPL's default, a fifth of the
        box's diagonal). An ``own`` planner needs the `PlanningProblem` ``problem`` of ``si``. OMPL
        is imported here, not with this module: the CLI help reads the table without loading OMPL."""
        from ompl import geometric as og

        if self.own:
            from ctrplan.planning.corridor import CorridorRRTConnect

            if problem is None or problem.si is not si:
                raise ValueError(f"{self.ompl_name} is built from the PlanningProblem of si")
            return CorridorRRTConnect.for_problem(problem, range_mm)
        planner = getattr(og, self.ompl_name)(si)
        if range_mm is not None and hasattr(planner, "setRange"):
            planner.setRange(float(range_mm))
        return planner


#: The planners by ctrplan name.
PLANNERS: dict[str, PlannerSpec] = {
    "corridor": PlannerSpec("CorridorRRTConnect", benchmarked=True, own=True),
    "rrtconnect": PlannerSpec("RRTConnect", benchmarked=True),
    "rrt": PlannerSpec("RRT", benchmarked=True),
    "rrtstar": PlannerSpec("RRTstar", optimizing=True, benchmarked=True),
    "bitstar": PlannerSpec("BITstar", optimizing=True, fixed_goal_set=True),
    "kpiece": PlannerSpec("KPIECE1"),
}
#: Names OMPL uses for the planners (for logs and benchmark databases).
OMPL_NAMES = {name: spec.ompl_name for name, spec in PLANNERS.items()}
#: Planners of ``ctrplan bench plan`` by default: the feasible ones and one asymptotically optimal one.
BENCHMARKED = tuple(name for name, spec in PLANNERS.items() if spec.benchmarked)
#: Planners that run until their budget is spent (their time says nothing).
OPTIMIZING = tuple(name for name, spec in PLANNERS.items() if spec.optimizing)


def planner_spec(name: str, where: str = "planner") -> PlannerSpec:
    """The `PlannerSpec` of a planner name; `InputError` naming ``where`` (the parameter or the scene
    file's key) otherwise."""
    try:
        return PLANNERS[name]
    except (KeyError, TypeError):
        raise InputError(f"{where}: unknown planner {name!r} (choose from {', '.join(PLANNERS)})") \
            from None


def scene_planner(scene, name: str | None = None) -> tuple[str, PlannerSpec]:
    """The planner to plan ``scene`` with: ``name`` if given (an error names the ``planner``
    parameter), else the scene's (an error names its file, line and key) -- and its spec."""
    if name is not None:
        return name, planner_spec(name)
    name = scene.settings.planner
    return name, planner_spec(name, scene.where("planner.planner"))


def make_planner(name: str, si: Any, problem: Any = None) -> Any:
    """A planner on ``si`` by ctrplan name (see `PLANNERS`; ctrplan's own need the `PlanningProblem`
    ``problem`` of ``si``)."""
    return planner_spec(name).make(si, problem=problem)
