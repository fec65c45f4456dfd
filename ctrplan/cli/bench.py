"""`ctrplan bench ...`: the paper's experiments, with a JSON summary and plots."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Annotated

import typer
from rich import box
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from ctrplan.bench import kinematics as kinematics_bench
from ctrplan.bench import machine_info, single_core
from ctrplan.bench.plots import timing_boxplot
from ctrplan.cli import app
from ctrplan.cli.kinematics import RobotOpt
from ctrplan.dataio import atomic_write, output_dir
from ctrplan.errors import InputError
from ctrplan.kinematics import BACKENDS, make_backend
from ctrplan.robot import Robot

bench_app = typer.Typer(help="Benchmarks: timings, JSON summaries and plots.", no_args_is_help=True)
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


def progress_bar() -> Progress:
    """A progress bar on stderr, refreshed only from the caller's thread (no background thread that
    would share the pinned core with the timed calls); silent when stderr is not a terminal."""
    console = Console(stderr=True)
    return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                    TimeRemainingColumn(), console=console, auto_refresh=False,
                    disable=not console.is_terminal)


@bench_app.command("kinematics")
def kinematics(
    backend: Annotated[str, typer.Option(
        "--backend", help="Comma-separated backends to time.")] = ",".join(BACKENDS),
    n: Annotated[int, typer.Option("--n", help="Configurations per case (random, snap-free).")] = 5000,
    points: Annotated[str, typer.Option(
        "--points", help="Comma-separated numbers of backbone points.")] = "30,60,90,150",
    seed: Annotated[int, typer.Option("--seed", help="Seed of the random configurations.")] = 0,
    robot: RobotOpt = None,
    out: Annotated[Path, typer.Option(
        "--out", help="Directory for results.json and the plot.")] = Path("runs/bench_kinematics"),
    as_json: Annotated[bool, typer.Option("--json", help="Print the JSON summary on stdout.")] = False,
    batch: Annotated[int, typer.Option(
        "--batch", help="Also time batched calls of this many configurations, all cores (0: skip).")] = 5000,
) -> None:
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
    backends = {name: make_backend(name, model) for name in dict.fromkeys(names)}
    out = output_dir(out)
    cases = kinematics_bench.cases(list(backends), point_counts)
    with progress_bar() as bar, single_core() as core:
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
    batched = [] if batch < 1 else kinematics_bench.throughput(backends, points=64, batch=batch)
    doc = {"machine": {**machine_info(), "pinned_core": core},
           "settings": {"n": n, "points": point_counts, "seed": seed, "robot": model.name,
                        "check_joints": False, "warm_neighbour": "0.5 mm / 0.5 deg per joint",
                        "batched": f"one call on {batch} configurations, 64 points, all cores"},
           "results": results, "batched": batched}
    timing_boxplot({(case.label, case.points): t for case, t in times.items()},
                   out / "kinematics_times.png",
                   title=f"Single-query forward kinematics, n = {n} per box, one core")
    with atomic_write(out / "results.json") as fh:
        json.dump(doc, fh, indent=2)
    if as_json:
        typer.echo(json.dumps(doc, indent=2))
        return
    table = Table(title=f"bench kinematics: ms per call, n = {n}, one core of {doc['machine']['cpu']}",
                  box=box.SIMPLE_HEAD, collapse_padding=True, pad_edge=False)
    for header, _, fmt in TABLE_COLUMNS:
        table.add_column(header, justify="left" if fmt == "{}" else "right")
    for row in results:
        table.add_row(*(fmt.format(row[key]) for _, key, fmt in TABLE_COLUMNS))
    Console().print(table)
    for row in batched:
        typer.echo(f"batched {row['backend']}: {row['backbones_per_s']:.0f} backbones/s "
                   f"({row['batch']} configurations x {row['points']} points per call, all cores)")
    typer.echo(f"wrote {out / 'results.json'} and {out / 'kinematics_times.png'}", err=True)
