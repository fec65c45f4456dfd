"""`ctrplan design`: which tube set reaches every target of a procedure through an anatomy, stable and
collision-free.

One idea per module: `task` (the task file, docs/design.md §5), `space` (study parameters <-> robot files),
`evaluate` (feasibility and proven reach of one design), `record` (what an evaluation found, typed),
`objectives` (what a design is judged by), `study` (the Optuna study and its executors), `ranking`
(best design, Pareto front) and `outputs` (what the outputs show, with best robot, per-target scenes,
designs.csv and design.json; its figures and report.html are `ctrplan.viz.design_report`).
"""

from ctrplan.design.evaluate import DesignContext, DesignJob, evaluate, evaluate_job
from ctrplan.design.study import open_study, run_study
from ctrplan.design.task import DesignTask, load_task

__all__ = ["DesignContext", "DesignJob", "DesignTask", "evaluate", "evaluate_job", "load_task", "open_study",
           "run_study"]
