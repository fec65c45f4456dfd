"""`ctrplan bench ...`: the paper's experiments, with a JSON summary and plots."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Annotated

import typer
from rich import box
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeRemainingColumn
from rich.table import Table

from ctrplan.base.dataio import atomic_write, check_output_dir, output_dir
from ctrplan.base.errors import InputError
from ctrplan.base.machine import machine_info, single_core
from ctrplan.base.memory import check_backbones, check_fits
from ctrplan.base.parallel import available_cores, check_workers
from ctrplan.bench import kinematics as kinematics_bench
from ctrplan.bench import planning as planning_bench
from ctrplan.cli.app import HELP_SETTINGS, app
from ctrplan.cli.options import (
    JsonSummaryOpt,
    RobotOpt,
    as_option,
    check_max_states,
    load_backend,
    max_states_option,
    parse_duration,
    ray_option,
    seed_option,
    time_limit_option,
    workers_option,
)
from ctrplan.cli.progress import CountProgress
from ctrplan.kinematics import BACKEND_KINDS, BACKENDS, PLANNING_ORDER
from ctrplan.kinematics.pinn import ROW_BLOCKS
from ctrplan.model.robot import Robot
from ctrplan.planning.planners import BENCHMARKED, PLANNERS, planner_spec

BENCH_HELP = "Benchmarks: timings, JSON summaries and plots."
bench_app = typer.Typer(help=BENCH_HELP, short_help=BENCH_HELP, no_args_is_help=True,
                        rich_markup_mode=None, context_settings=HELP_SETTINGS)
app.add_typer(bench_app, name="bench")

PROGRESS_REFRESH_S = 0.25
#: Terminal table of `bench kinematics`: (header, result key, format).
TABLE_COLUMNS = (("backend", "backend", "{}"), ("mode", "mode", "{}"), ("points", "points", "{}"),
                 ("median", "median_ms", "{:.3f}"), ("p90", "p90_ms", "{:.3f}"),
                 ("p99", "p99_ms", "{:.3f}"), ("max", "max_ms", "{:.3f}"),
                 ("p99/med", "p99_over_median", "{:.1f}"), ("fail", "failures", "{}"),
                 ("iters", "median_iterations", "{:g}"))


def parse_list(value: str, option: str) -> list[str]:
    """``"a,b,c"`` -> ``["a", "b", "c"]``; an empty list or item is an `InputError`."""
    items = [v.strip() for v in value.split(",")]
    if not all(items):
        raise InputError(f"{option}: expected a comma-separated list, got {value!r}")
    return items


def parse_ints(value: str, option: str, minimum: int) -> list[int]:
    """``"30,60"`` -> ``[30, 60]``, each at least ``minimum``."""
    out = []
    for item in parse_list(value, option):
        try:
            number = int(item)
        except ValueError:
            raise InputError(f"{option}: {item!r} is not an integer") from None
        if number < minimum:
            raise InputError(f"{option}: {number} is below the minimum {minimum}")
        out.append(number)
    return out


def progress_bar(what: str, thread: bool = True) -> CountProgress:
    """A progress bar on stderr, refreshed only from the caller's thread (no background thread that
    would share the pinned core with the timed calls); when stderr is not a terminal, a plain line
    about every 10 s instead (from the caller only, without ``thread``)."""
    return CountProgress(Console(stderr=True), what, (TextColumn("{task.description}"), BarColumn(),
                                                      MofNCompleteColumn(), TimeRemainingColumn()),
                         thread=thread)


def publish(doc: dict, out: Path, as_json: bool) -> bool:
    """Write ``doc`` to ``out/results.json``; with ``as_json`` also print it (then True: no table)."""
    with atomic_write(out / "results.json") as fh:
        json.dump(doc, fh, indent=2)
    if as_json:
        typer.echo(json.dumps(doc, indent=2))
    return as_json


def result_table(title: str, columns: list[tuple[str, bool]]) -> Table:
    """An empty terminal table with ``(header, left_aligned)`` columns."""
    table = Table(title=title, box=box.SIMPLE_HEAD, collapse_padding=True, pad_edge=False)
    for header, left in columns:
        table.add_column(header, justify="left" if left else "right")
    return table


#: Defaults of ``--backend`` (`bench kinematics`: every backend; `bench plan`: the planning default
#: first) and ``--planner``, from the registries.
ALL_BACKENDS, PLAN_BACKENDS = ",".join(BACKENDS), ",".join(PLANNING_ORDER)
PLAN_PLANNERS = ",".join(BENCHMARKED)
KinBackendsOpt = Annotated[str, typer.Option("--backend", help="Comma-separated backends to time.")]
ConfigurationsOpt = Annotated[int, typer.Option("--n", help="Configurations per case (random, snap-free).")]
PointsListOpt = Annotated[str, typer.Option("--points", help="Comma-separated numbers of backbone points.")]
KinSeedOpt = seed_option("Seed of the random configurations.")
KinOutOpt = Annotated[Path, typer.Option("--out", help="Directory for results.json and the plot.")]
BatchOpt = Annotated[int, typer.Option(
    "--batch", help="Also time batched calls of this many configurations, all cores (0: skip).")]


@bench_app.command("kinematics")
def kinematics(backend: KinBackendsOpt = ALL_BACKENDS, n: ConfigurationsOpt = 5000,
               points: PointsListOpt = "30,60,90,150", seed: KinSeedOpt = 0, robot: RobotOpt = None,
               out: KinOutOpt = Path("runs/bench_kinematics"), as_json: JsonSummaryOpt = False,
               batch: BatchOpt = 5000) -> None:
    """Single-query forward-kinematics runtime on one core (paper's runtime experiment), and the
    batched rate (backbones per second) on all cores.

    Each configuration is solved in its own call, as a planner issues them. The Cosserat solver is
    timed cold and warm-started from a neighbouring configuration (0.5 mm / 0.5 deg per joint).
    """
    names = parse_list(backend, "--backend")
    point_counts = parse_ints(points, "--points", minimum=2)
    if n < 1:
        raise InputError(f"--n: need at least 1 configuration, got {n}")
    model = Robot.load(robot)
    backends = {name: load_backend(name, model, None) for name in dict.fromkeys(names)}
    cases = kinematics_bench.cases(backends, point_counts)
    check_backbones(None, 1, "--points", max(point_counts), model.n_tubes, 2)
    check_fits("--n", n, kinematics_bench.bytes_per_configuration(model.n_tubes, len(cases)),
               "configurations")
    check_backbones("--batch", batch, None, kinematics_bench.BATCH_POINTS, model.n_tubes, 2)
    check_output_dir(out)  # created when the results are written
    with progress_bar("bench kinematics", thread=False) as bar, single_core() as core:
        task = bar.add_task("bench kinematics", total=n * len(cases))
        last = 0.0

        def tick(case: kinematics_bench.Case) -> None:
            nonlocal last
            bar.advance(task)
            if time.monotonic() - last > PROGRESS_REFRESH_S:
                last = time.monotonic()
                bar.update(task, description=f"{case.label}, {case.points} points")
                bar.refresh()

        results, times = kinematics_bench.run(backends, n, point_counts, seed=seed, tick=tick)
    batched = [] if batch < 1 else kinematics_bench.throughput(
        backends, points=kinematics_bench.BATCH_POINTS, batch=batch)
    out = output_dir(out)
    doc = {"machine": {**machine_info(), "pinned_core": core},
           "settings": {"n": n, "points": point_counts, "seed": seed, "robot": model.name,
                        "check_joints": False, "warm_neighbour": "0.5 mm / 0.5 deg per joint",
                        "batched": f"one call on {batch} configurations, "
                                   f"{kinematics_bench.BATCH_POINTS} points, all cores"},
           "results": results, "batched": batched}
    from ctrplan.viz.bench_plots import timing_boxplot

    timing_boxplot({(case.label, case.points): t for case, t in times.items()},
                   out / "kinematics_times.png",
                   title=f"Single-query forward kinematics, n = {n} per box, one core")
    if publish(doc, out, as_json):
        return
    table = result_table(f"bench kinematics: ms per call, n = {n}, one core of {doc['machine']['cpu']}",
                         [(header, fmt == "{}") for header, _, fmt in TABLE_COLUMNS])
    for row in results:
        table.add_row(*(fmt.format(row[key]) for _, key, fmt in TABLE_COLUMNS))
    Console().print(table)
    for row in batched:
        typer.echo(f"batched {row['backend']}: {row['backbones_per_s']:.0f} backbones/s "
                   f"({row['batch']} configurations x {row['points']} points per call, all cores)")
    typer.echo(f"wrote {out / 'results.json'} and {out / 'kinematics_times.png'}", err=True)


ScenesArg = Annotated[list[Path], typer.Argument(metavar="SCENE.yaml", help="Scene files (YAML).",
                                                  show_default=False)]
PlanBackendsOpt = Annotated[str, typer.Option("--backend", help="Comma-separated kinematics backends.")]
PlannersOpt = Annotated[str, typer.Option(
    "--planner", help=f"Comma-separated planners ({', '.join(PLANNERS)}).")]
RunsOpt = Annotated[int, typer.Option("--runs", help="Seeded runs per scene x backend x planner.")]
PlanTimeLimitOpt = time_limit_option(
    "Time budget per run, e.g. 10s; a bare number is seconds (default: each scene's setting): the default "
    "work budget and the wall-clock guard, as for `ctrplan plan`.")
MaxStatesOpt = max_states_option(
    "Work budget per run: states the backend evaluates (default: each scene's max_states, else what the "
    "time budget buys with the backend on the reference machine).")
PlanSeedOpt = seed_option("First seed; runs use seed, seed+1, ...")
PlanOutOpt = Annotated[Path, typer.Option(
    "--out", help="Directory for results.json, the OMPL logs, benchmark.db and plots.")]
WorkersOpt = workers_option("Local worker processes, one per core (1: in this process).")
RayOpt = ray_option("Run on a Ray cluster at this address ('local' starts one here; needs the 'ray' extra).")
ThreadsOpt = Annotated[int | None, typer.Option(
    "--threads", help="Cores each run may use (numba threads for batched kinematics; more than 1 needs "
                      "--workers 1). Default: with one worker the cores a plan uses (2: its kinematics "
                      "runs in two blocks; the latency of a plan alone on the machine, as `ctrplan plan` "
                      "runs), else 1 (one-core timings).")]


@bench_app.command("plan")
def plan(scenes: ScenesArg, backend: PlanBackendsOpt = PLAN_BACKENDS,
         planner: PlannersOpt = PLAN_PLANNERS, runs: RunsOpt = 20,
         time_limit: PlanTimeLimitOpt = None, max_states: MaxStatesOpt = None, seed: PlanSeedOpt = 0,
         out: PlanOutOpt = Path("runs/bench_plan"), as_json: JsonSummaryOpt = False, workers: WorkersOpt = 1,
         ray: RayOpt = None, threads: ThreadsOpt = None) -> None:
    """Planning benchmark: every backend x planner on each scene, N seeded runs each.

    Reports success (confirmed by the exact model), the planning-time distribution, the time split
    between kinematics, collision checking and the planner, validity checks per second, path length
    and the exact-model validation outcome. Writes an OMPL benchmark log per scene and the Planner
    Arena database (benchmark.db), plots and results.json.
    """
    from ctrplan.bench.plan_results import write_plan_results
    from ctrplan.viz.bench_plots import planning_plots

    backends = parse_list(backend, "--backend")
    planners = parse_list(planner, "--planner")
    for name in backends:
        if name not in BACKEND_KINDS:
            raise InputError(f"--backend: unknown backend {name!r} (choose from {', '.join(BACKEND_KINDS)})")
    flags = {"planner": "--planner", "workers": "--workers", "ray": "--ray", "threads": "--threads"}
    for name in planners:
        try:
            planner_spec(name)
        except InputError as exc:
            raise as_option(exc, flags) from None
    if runs < 1:
        raise InputError(f"--runs: need at least 1 run, got {runs}")
    time_limit = parse_duration(time_limit, "s")
    check_max_states(max_states)
    if threads is None:  # a search runs its kernels in ROW_BLOCKS blocks: that many cores at most
        threads = min(len(available_cores()), ROW_BLOCKS) if workers == 1 and not ray else 1
    try:
        check_workers(workers, ray, threads)
    except InputError as exc:
        raise as_option(exc, flags) from None
    limits = planning_bench.prepare(scenes, backends, time_limit)
    specs = planning_bench.make_specs(limits, backends, planners, runs, seed, max_states)
    check_output_dir(out)  # created when the results are written
    t0 = time.perf_counter()
    with progress_bar("bench plan") as bar:
        task = bar.add_task("bench plan", total=len(specs))

        def tick(done: int, total: int) -> None:
            bar.update(task, completed=done)
            bar.refresh()

        try:
            records = planning_bench.run_all(specs, workers=workers, ray_address=ray, tick=tick,
                                             threads=threads)
        except InputError as exc:
            raise as_option(exc, flags) from None
    rates = [planning_bench.check_rates(f, b) for f, _ in limits for b in backends]  # one state vs a batch
    out = output_dir(out)
    executor = f"ray {ray}" if ray else \
        f"{workers} local worker(s), {'one core' if threads == 1 else f'{threads} cores'} each"
    doc, logs = write_plan_results(records, out, limits, {
        "backends": backends, "planners": planners, "runs": runs, "first_seed": seed,
        "max_states": max_states, "executor": executor, "wall_time_s": round(time.perf_counter() - t0, 1)},
        rates)
    plots = planning_plots(doc["summary"], records, out)
    if publish(doc, out, as_json):
        return
    _plan_table(doc, runs)
    typer.echo("\n".join(map(planning_bench.describe_rates, doc["check_rates"])))
    typer.echo(f"wrote {out / 'results.json'}, {len(logs)} OMPL log(s), {out / 'benchmark.db'} and "
               f"{', '.join(p.name for p in plots)}", err=True)


def _plan_table(doc: dict, runs: int) -> None:
    """The terminal table of `bench plan`: one row per scene x planner x backend."""
    table = result_table(f"bench plan: {runs} runs each, one core of {doc['machine']['cpu']} per run",
                         [(h, h in ("scene", "planner", "backend")) for h in (
                             "scene", "planner", "backend", "solved", "median s", "p90 s", "max s",
                             "kin %", "coll %", "plan %", "checks/s", "repaired", "unsafe")])
    for s in doc["summary"]:
        t, share = s["planning_time_s"], s["time_share"]
        table.add_row(s["scene"], s["planner"], s["backend"], f"{s['solved']}/{s['runs']}",
                      f"{t['median']:.2f}", f"{t['p90']:.2f}", f"{t['max']:.2f}",
                      f"{100 * share['kinematics']:.0f}", f"{100 * share['collision']:.0f}",
                      f"{100 * share['planner']:.0f}", f"{s['checks_per_s']['median']:.0f}",
                      str(s["repaired"]), str(s["unsafe"]))
    Console().print(table)
