"""`ctrplan design`: which tube set reaches every target of a procedure, stable and collision-free."""

from __future__ import annotations

import json
import shlex
import sys
import time
from pathlib import Path
from typing import Annotated

import typer

from ctrplan.base.errors import InputError
from ctrplan.cli.app import app
from ctrplan.cli.options import (
    as_option,
    json_option,
    parse_duration,
    ray_option,
    time_limit_option,
    workers_option,
)
from ctrplan.cli.progress import PlainProgress

OPTIONS = {"workers": "--workers", "ray": "--ray", "storage": "--storage", "study": "--study"}


TaskArg = Annotated[Path, typer.Argument(
    metavar="TASK.yaml", show_default=False,
    help="Design task: scene, named targets, base robot, what may vary, catalogue, constraints, "
         "objectives, budget (docs/design.md §5).")]
TrialsOpt = Annotated[int | None, typer.Option(
    "--trials", metavar="N", show_default=False,
    help="Finished trials the study should have (default: the task's budget); a continued study "
         "runs only the missing ones.")]
TimeLimitOpt = time_limit_option(
    "Wall-clock guard, e.g. 30m or 1.5h; a bare number is minutes: start no trial after it "
    "(trials in flight finish); the outputs say when it stopped the study short of its trials. "
    "Each trial's own planning is budgeted in work (the task's plan_states), not time.", show_default=False)
WorkersOpt = workers_option("Trials at a time: local worker processes, one per core (1: in this process), "
                            "or Ray tasks with --ray.", metavar="W")
RayOpt = ray_option("Run trials as Ray tasks on this cluster ('local' starts one here; needs the 'ray' "
                    "extra).", metavar="ADDRESS")
StorageOpt = Annotated[str | None, typer.Option(
    "--storage", metavar="URL", show_default=False,
    help="Optuna storage, any SQLAlchemy URL (default: sqlite:///OUT/study.db).")]
StudyOpt = Annotated[str | None, typer.Option(
    "--study", metavar="NAME", show_default=False,
    help="Study name (default: the task file's name); an existing study of the same task and seed "
         "is continued.")]
SeedOpt = Annotated[int, typer.Option("--seed", metavar="S", help="Seed of the sampler and of every "
                                                                  "trial's planning.")]
OutOpt = Annotated[Path | None, typer.Option(
    "--out", metavar="DIR", show_default=False, help="Output folder (default: runs/design/TASK).")]
JsonOpt = json_option("Print the JSON summary on stdout (progress goes to stderr).")


@app.command("design")
def design(task_file: TaskArg, trials: TrialsOpt = None, time_limit: TimeLimitOpt = None,
           workers: WorkersOpt = 1, ray: RayOpt = None, storage: StorageOpt = None, study: StudyOpt = None,
           seed: SeedOpt = 0, out: OutOpt = None, as_json: JsonOpt = False) -> None:
    """Search the tube set that reaches the most targets of a procedure, stable and collision-free.

    Optuna (multi-objective TPE) proposes designs within the task's ranges and stock sizes; each is
    kept only if the robot loader accepts it, its strain is within the limit and its joint domain is
    snap-free, and a target counts as reached only when the planner finds a path from the start that
    the exact Cosserat model confirms. Writes best_robot.yaml, designs.csv, pareto.png, report.html,
    design.json and paths/<target>/ (scene.yaml; path.json, plan.png, plan.html when reached).
    """
    from rich.console import Console

    from ctrplan.base.dataio import output_dir
    from ctrplan.base.parallel import check_workers
    from ctrplan.design.outputs import collect, write_summary
    from ctrplan.design.study import default_storage, open_study
    from ctrplan.design.task import load_task
    from ctrplan.viz.design_report import write_study_figures

    if trials is not None and trials < 1:
        raise InputError(f"--trials: need at least 1, got {trials}")
    limit_s = parse_duration(time_limit, "min")
    time_limit = None if limit_s is None else limit_s / 60.0  # minutes
    if seed < 0:
        raise InputError(f"--seed: must be >= 0, got {seed}")
    if study is not None and not study.strip():
        raise InputError("--study: must not be empty")
    try:
        check_workers(workers, ray)
    except InputError as exc:
        raise as_option(exc, OPTIONS) from None
    task = load_task(task_file)
    folder = output_dir(out or Path("runs/design") / task.name)
    url = storage or default_storage(folder)
    try:
        st = open_study(task, url, study or task.name, seed)
    except InputError as exc:
        raise as_option(exc, OPTIONS) from None
    budget = trials or task.trials
    err = Console(stderr=True, highlight=False)
    t0 = time.perf_counter()  # this run: its trials, not the outputs
    try:
        cut_short = _run(err, task, st, budget, seed=seed, workers=workers, ray=ray, time_limit=time_limit)
    except KeyboardInterrupt:
        err.print(continue_hint(url, study or task.name, folder, out is None), soft_wrap=True)
        raise
    executor = f"ray {ray}" if ray else f"{workers} local worker(s), one core each"
    outcome = collect(task, st, folder, storage=url, seed=seed, time_s=time.perf_counter() - t0,
                      executor=executor, cut_short=cut_short)
    write_study_figures(outcome, folder)
    write_summary(outcome, folder)
    doc = outcome.doc
    if as_json:
        typer.echo(json.dumps(doc, indent=2))
    else:
        _summary(Console(highlight=False), task, doc)


def continue_hint(url: str, study: str, folder: Path, default_out: bool) -> str:
    """After Ctrl-C: where the finished trials are and the command that continues the study (this
    one, with its output folder named: the study and its storage are found from it)."""
    args = sys.argv[1:] + (["--out", str(folder)] if default_out else [])
    return (f"interrupted: the finished trials are kept in study {study!r} of {url}; continue the study "
            f"(only the missing trials run) with: ctrplan {shlex.join(args)}")


def _run(err, task, study, budget: int, *, seed: int, workers: int, ray: str | None,
         time_limit: float | None) -> str | None:
    """Run the study to ``budget`` trials under the progress bar; what the time limit (minutes)
    stopped short, said on ``err`` too, or None."""
    from ctrplan.design.study import finished_trials, run_study

    limit_s = None if time_limit is None else 60.0 * time_limit
    already = len(finished_trials(study))
    with _DesignProgress(err, task, budget, already, limit_s) as progress:
        try:
            stopped = run_study(task, study, trials=budget, seed=seed, workers=workers, ray_address=ray,
                                time_limit_s=limit_s, report=progress.update)
        except InputError as exc:
            raise as_option(exc, OPTIONS) from None
    if not stopped:
        return None
    done = len(finished_trials(study))
    cut_short = (f"the time limit of {time_limit:g} min stopped the study after {done} of {budget} trials "
                 f"({done - already} in this run); the same command continues it")
    err.print(f"[bold yellow]{cut_short}[/]")
    return cut_short


class _DesignProgress:
    """A rich progress bar of finished trials on stderr (on a terminal), and one line per event that
    matters (the base design's reach, each trial that beats every design before it, the base design
    included) on stderr in any case.

    The bar counts the trials that will run: the budget, or with a time limit (``limit_s``) an
    estimate from the time per trial so far, marked as such (the limit starts no trial after it)."""

    def __init__(self, console, task, total: int, already: int, limit_s: float | None):
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        self.console = console
        self.task = task
        self.total = total
        self.already = already  # finished trials of a continued study
        self.limit_s = limit_s
        self.t0 = time.monotonic()
        self.jobs = 0
        self.best = -1
        self.bar = Progress(TextColumn(f"design {task.name}"), BarColumn(), MofNCompleteColumn(),
                            TimeElapsedColumn(), TextColumn("{task.fields[note]}"), console=console,
                            disable=not console.is_terminal)
        self.id = self.bar.add_task("trials", total=total, completed=already, note=self._note(""))
        self.plain = PlainProgress(f"design {task.name}", enabled=not console.is_terminal)
        self.plain(f"{already} of {total} trials finished")

    def __enter__(self):
        self.bar.__enter__()
        self.plain.__enter__()
        return self

    def __exit__(self, *exc):
        self.plain.__exit__(*exc)
        self.bar.__exit__(*exc)

    def _note(self, best: str) -> str:
        guard = "" if self.limit_s is None else f" (about: the {self.limit_s / 60:g} min limit ends it)"
        return best + guard

    def _expected(self, finished: int) -> int:
        """Trials that will have finished when the run ends: the budget, or fewer when the time
        limit will stop it first at the time per evaluation so far."""
        if self.limit_s is None or self.jobs == 0:
            return self.total
        elapsed = time.monotonic() - self.t0
        per_job = elapsed / self.jobs
        more = max(0, int((self.limit_s - elapsed) / per_job) + 1)  # started before the limit: finish
        return min(self.total, finished + more)

    def update(self, trial: int | None, record, finished: int) -> None:
        n = len(self.task.targets)
        reached = record.reached
        names = ", ".join(reached) or "none"
        self.jobs += 1
        if trial is None:
            why = "" if record.feasible else f" (infeasible: {record.infeasible.message})"
            self.console.print(f"base design: reaches {len(reached)} of {n} targets ({names}){why}")
            if record.feasible:
                self.best = len(reached)
        elif record.feasible and len(reached) > self.best:
            self.best = len(reached)
            self.console.print(f"trial {trial}: {len(reached)} of {n} targets ({names}) "
                               f"in {record.time_s:.0f} s")
        note = self._note("" if self.best < 0 else f"best {self.best}/{n} targets")
        self.bar.update(self.id, completed=finished, total=self._expected(finished), note=note)
        self.plain(f"{finished} of {self._expected(finished)} trials finished{', ' + note if note else ''}")


def _summary(console, task, doc: dict) -> None:
    from rich.table import Table

    best, nominal = doc["best"], doc["nominal"]
    t = Table(title=f"ctrplan design {task.name}: {doc['trials']} trials, {doc['feasible']} feasible, "
                    f"{doc['time_s']:.0f} s", title_justify="left")
    t.add_column("target")
    t.add_column("base design")
    is_base = best is not None and best["is_base_design"]
    t.add_column("best design" if best is None else
                 "best = base design" if is_base else f"best (trial {best['trial']})")
    for target in doc["targets"]:
        nom = "-" if nominal is None else ("yes" if target in nominal["reached"] else "no")
        b = "-" if best is None else ("yes" if target in best["reached"] else "no")
        t.add_row(target, nom, b)
    t.add_row("total", "-" if nominal is None else str(len(nominal["reached"])),
              "-" if best is None else str(len(best["reached"])))
    console.print(t)
    if is_base:
        console.print(f"[bold]no trial beats the base design[/] in the task's objectives "
                      f"({', '.join(doc['objectives'])}): best_robot.yaml is the base design")
    if doc["guarded_trials"]:
        console.print(f"[yellow]a wall-clock guard cut a search short in {doc['guarded_trials']} design(s) "
                      f"(cut_short of the base design's targets in design.json, of the trials in "
                      f"designs.csv): those verdicts depend on this machine's load[/]")
    if best is not None:
        params = (f"{k} = {v:.4g}" if isinstance(v, float) else f"{k} = {v}"
                  for k, v in best["parameters"].items())
        console.print("best parameters: " + (", ".join(params) or "those of the base design"))
        values = (f"{k} = {v:.4g}" for k, v in best["objectives"].items())
        console.print("best objectives: " + ", ".join(values))
    else:
        console.print("no feasible design")
    tt = doc["trial_time_s"]
    if tt:
        console.print(f"time per trial: median {tt['median']:.1f} s, max {tt['max']:.1f} s; the study's "
                      f"trials {doc['study_wall_s']:.0f} s from first start to last end; this run "
                      f"{doc['time_s']:.0f} s on {doc['executor']}")
    console.print(f"wrote {', '.join(doc['outputs'].values())}")
