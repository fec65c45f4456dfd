"""`ctrplan roadmap build` (grow a roadmap for a scene) and `ctrplan plan --roadmap` (answer targets
from it). See `ctrplan.planning.roadmap`."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import numpy as np
import typer

from ctrplan.base.errors import InputError
from ctrplan.cli.app import HELP_SETTINGS, app
from ctrplan.cli.bench import bench_app, publish
from ctrplan.cli.options import ModelOpt, RobotOpt, as_option, load_backend, parse_duration
from ctrplan.cli.progress import PlainProgress, StatusLine
from ctrplan.kinematics.registry import DEFAULT_PLANNING_BACKEND, PLANNING_ORDER

if TYPE_CHECKING:
    from ctrplan.planning.roadmap.store import Roadmap

ROADMAP_HELP = "Multi-query roadmaps: build once per scene, then answer targets in milliseconds."
roadmap_app = typer.Typer(help=ROADMAP_HELP, short_help=ROADMAP_HELP, no_args_is_help=True,
                          rich_markup_mode=None, context_settings=HELP_SETTINGS)
app.add_typer(roadmap_app, name="roadmap")

#: Columns of a targets file (scene frame, mm).
TARGET_COLUMNS = ("x", "y", "z", "tolerance_mm")


@roadmap_app.command("build")
def build_command(
    scene: Annotated[Path, typer.Argument(metavar="SCENE.yaml", show_default=False,
                                          help="Scene file (robot, base pose, obstacles, start).")],
    out: Annotated[Path, typer.Option(
        "--out", metavar="DIR", show_default=False,
        help="Roadmap folder (roadmap.npz + roadmap.json); a build there for the same scene, robot and "
             "model is continued.")],
    time_limit: Annotated[str, typer.Option(
        "--time-limit", metavar="DURATION",
        help="Total build time, e.g. 90s, 10m; a bare number is seconds (a continued build counts its "
             "earlier time).")] = "10m",
    seed: Annotated[int, typer.Option("--seed", min=0, help="Random seed.")] = 0,
    workers: Annotated[int, typer.Option(
        "--workers", help="Local worker processes, one per core (1: in this process).")] = 1,
    ray: Annotated[str | None, typer.Option(
        "--ray", metavar="ADDRESS", show_default=False,
        help="Shard the build over a Ray cluster at this address ('local' starts one here).")] = None,
    backend: Annotated[str, typer.Option(
        "--backend", metavar="NAME",
        help=f"Planning backend: {' | '.join(PLANNING_ORDER)}.")] = DEFAULT_PLANNING_BACKEND,
    model: ModelOpt = None,
    robot: RobotOpt = None,
    focus: Annotated[Path | None, typer.Option(
        "--focus", metavar="TARGETS.csv", show_default=False,
        help="Grow towards these regions too, in turn with the scene's target (header x,y,z,tolerance_mm; "
             "scene frame, mm; as plan --targets).")] = None,
) -> None:
    """Build (or continue) a roadmap of valid states and edges for a scene.

    States and edges are checked as `ctrplan plan` checks them (the PINN with its calibrated margin,
    stable states only); the build is saved every minute and at the end, with the fingerprints of
    scene, robot and model. --robot replaces the scene's robot (as `plan --robot`; queries then need
    the same --robot). The build ends by saying how close the roadmap came to the target and to each
    --focus region: a region it never reached is named with the distance of its nearest tip.
    """
    from ctrplan.base.dataio import check_output_dir, output_dir
    from ctrplan.base.machine import limit_threads
    from ctrplan.base.parallel import check_workers, open_pool
    from ctrplan.model.robot import BUILTIN_ROBOTS, Robot
    from ctrplan.planning.roadmap.build import Source, build, planning_context
    from ctrplan.planning.roadmap.store import fingerprints, load_roadmap, read_meta
    from ctrplan.scene.loader import load_scene

    limit_s = parse_duration(time_limit, "s")
    rows = [] if focus is None else read_targets(focus)
    regions = [("target", None)] + [(f"{focus.name} row {i}", r) for i, r in enumerate(rows, 2)]
    flags = {"workers": "--workers", "ray": "--ray"}
    try:
        check_workers(workers, ray)
    except InputError as exc:
        raise as_option(exc, flags) from None
    check_output_dir(out)

    sc = load_scene(scene, robot=None if robot is None else Robot.load(robot))
    be = load_backend(backend, sc.robot, model)
    if read_meta(out) is not None:  # refuse a foreign roadmap before any work
        load_roadmap(out, fingerprints(sc, be))
    robot_file = robot if robot is None or robot in BUILTIN_ROBOTS else str(Path(robot).resolve())
    source = Source(str(scene.resolve()), backend, model, robot_file)
    executor = f"ray {ray}" if ray else f"{workers} local worker(s)"
    with _BuildProgress(limit_s) as status:
        status("compiling kernels (first run only)")
        ctx = planning_context(sc, be)
        output_dir(out)

        if workers > 1 or ray:  # the main process only makes jobs and adds results: one thread
            limit_threads()
        here = workers == 1 and not ray  # jobs run in this process: they use the context built above
        with open_pool(workers, ray, context=(lambda: ctx) if here else source) as pool:
            rm = build(ctx, source, out, pool, time_limit_s=limit_s, seed=seed, workers=workers,
                       executor=executor, progress=_build_progress(status, executor),
                       focus=[(name, region or sc.target) for name, region in regions])
    _report_build(out, rm, executor)


def _build_progress(status: Callable[..., None], executor: str) -> Callable[[dict], None]:
    """The build's progress callback: its phases and growth as status lines."""

    def progress(info: dict) -> None:
        if "starting" in info:
            status(f"starting {executor} (each loads the model and the scene)")
            return
        if "indexing" in info:
            done, total = info["indexing"]
            status(f"indexing the workspace each node and edge sweeps: {done:,}/{total:,}")
            return
        st = info["stats"]
        status(f"{info['nodes']:,} nodes ({info['connected']:,} connected), {st.edges_valid:,} edges, "
               f"{st.jobs} jobs; {_reach_text(st.reach)}", info["elapsed_s"])

    return progress


def _report_build(out: Path, rm: Roadmap, executor: str) -> None:
    """The build's summary line, and a warning for each focus region it never reached."""
    run = rm.meta["runs"][-1]
    minutes = max(run["seconds"], 1e-9) / 60.0
    added = run["nodes_after"] - run["nodes_before"]
    typer.echo(f"roadmap {out}: {rm.n_nodes:,} nodes ({int(rm.connected.sum()):,} connected to the start), "
               f"{len(rm.edges):,} edges; this run added {added:,} nodes in {run['seconds']:.0f} s "
               f"({added / minutes:,.0f} per minute, {executor}); total build time "
               f"{rm.meta['build_s']:.0f} s; {_reach_text(rm.meta['reach'])}")
    for name, r in rm.meta["reach"].items():
        if not r["inside"]:
            typer.echo(f"ctrplan: warning: the roadmap never reached {name} (nearest tip "
                       f"{r['closest_mm']:.1f} mm away): queries there will fail; build longer, or grow "
                       f"towards it with --focus", err=True)


def _reach_text(reach: dict) -> str:
    """How close the roadmap came to each focus region, in words."""
    parts = [f"{name}: {r['inside']:,} tips inside" if r["inside"] else
             f"{name}: NOT reached, nearest tip {r['closest_mm']:.1f} mm away" for name, r in reach.items()]
    return "; ".join(parts) if parts else "focus not reached yet"


class _BuildProgress:
    """The build's progress on stderr: a transient bar of build time against the limit on a terminal,
    else a plain line about every 10 s (`PlainProgress`). Call it with the latest text and, once
    growing, the build time so far (s)."""

    def __init__(self, limit_s: float):
        from rich.console import Console

        self.console = Console(stderr=True, highlight=False)
        self.limit_s = limit_s
        self.plain = PlainProgress("roadmap build", enabled=not self.console.is_terminal)
        self.bar = self.task = None

    def __enter__(self) -> _BuildProgress:
        if self.console.is_terminal:
            from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

            self.bar = Progress(BarColumn(), TextColumn("{task.completed:.0f}/{task.total:.0f} s"),
                                TimeRemainingColumn(), TextColumn("{task.description}"),
                                console=self.console, transient=True)
            self.bar.__enter__()
            self.task = self.bar.add_task("starting", total=self.limit_s)
        self.plain.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        self.plain.__exit__(*exc)
        if self.bar is not None:
            self.bar.__exit__(*exc)

    def __call__(self, text: str, elapsed_s: float | None = None) -> None:
        shown = text if elapsed_s is None else f"{elapsed_s:.0f}/{self.limit_s:.0f} s of build time, {text}"
        self.plain(shown)
        if self.bar is not None:
            self.bar.update(self.task, description=text,
                            **({} if elapsed_s is None else {"completed": min(elapsed_s, self.limit_s)}))


def read_targets(path: Path):
    """Target spheres of a targets CSV (header x,y,z,tolerance_mm; scene frame, mm); `InputError`
    naming the file and row for anything else."""
    from ctrplan.base.dataio import read_table
    from ctrplan.scene.objects import TargetRegion

    table = read_table(path, TARGET_COLUMNS)
    tol = table.column("tolerance_mm")
    bad = np.flatnonzero(tol <= 0)
    if bad.size:
        raise InputError(f"{path}: row {table.lines[bad[0]]}: tolerance_mm = {tol[bad[0]]:g} must be > 0 "
                         f"(mm)")
    return [TargetRegion.sphere(row[:3], row[3]) for row in table.values]


def plan_from_roadmap(scene: Path, roadmap_dir: Path, targets: Path | None, *, backend: str,
                      model: str | None, robot, out: Path | None, json_out: bool) -> None:
    """`ctrplan plan SCENE --roadmap DIR [--targets T.csv]`: answer the scene's target (or every row
    of T.csv) from the roadmap; exit 0 when all are solved, 1 otherwise."""
    from rich.console import Console

    from ctrplan.base.dataio import check_output_dir
    from ctrplan.planning.roadmap.build import planning_context
    from ctrplan.planning.roadmap.query import RoadmapPlanner
    from ctrplan.planning.roadmap.store import fingerprints, load_roadmap
    from ctrplan.scene.loader import load_scene

    if out is not None:
        check_output_dir(out)
    sc = load_scene(scene, robot=robot)
    regions = [sc.target] if targets is None else read_targets(targets)
    be = load_backend(backend, sc.robot, model)
    rm = load_roadmap(roadmap_dir, fingerprints(sc, be))  # a foreign roadmap: one line, exit 2
    err = Console(stderr=True, highlight=False)
    with StatusLine(err, "plan --roadmap", "compiling kernels (first run only)", timed=True) as status:
        planner = RoadmapPlanner(planning_context(sc, be), rm)
        results = []
        for i, region in enumerate(regions, 1):
            status(f"target {i}/{len(regions)}")
            results.append(planner.answer(region))
    doc = roadmap_document(sc, scene, roadmap_dir, rm, results)
    if out is not None:
        write_roadmap_outputs(out, sc, results)
    _summary(Console(stderr=json_out, highlight=False), doc)
    if json_out:
        typer.echo(json.dumps(doc))
    if not all(r.solved for r in results):
        raise typer.Exit(1)


def _stats_ms(values: list[float]) -> dict:
    v = np.asarray(values, dtype=float)
    if not v.size:
        return {"median_ms": None, "p95_ms": None, "max_ms": None}
    return {"median_ms": round(float(np.median(v)) * 1e3, 3),
            "p95_ms": round(float(np.percentile(v, 95)) * 1e3, 3), "max_ms": round(float(v.max()) * 1e3, 3)}


def roadmap_document(sc, scene_file: Path, roadmap_dir: Path, rm, results: list) -> dict:
    """The JSON document of `plan --roadmap` (DESIGN §3)."""
    solved = [r for r in results if r.solved]
    return {"results": [r.to_json() for r in results], "base_pose": np.asarray(sc.base_pose).tolist(),
            "scene": str(scene_file), "roadmap": str(roadmap_dir), "backend": rm.meta.get("backend"),
            "model": rm.meta.get("model"), "nodes": rm.n_nodes,
            "summary": {"targets": len(results), "solved": len(solved),
                        "query_time": _stats_ms([r.query_time_s for r in results]),
                        "validation_time": _stats_ms([r.validation_time_s for r in solved]),
                        "unsafe": sum(r.validated is not None and r.solved and not r.validated.ok
                                      for r in results)}}


def write_roadmap_outputs(out: Path, sc, results: list) -> None:
    """obstacles.ply (scene frame, mm, as `plan --out`) and ``path_<row>.json`` per target (the result,
    its dense exactly validated path and the exact tip path, scene frame, mm)."""
    from ctrplan.base.dataio import atomic_write, output_dir

    output_dir(out)
    with atomic_write(out / "obstacles.ply", "wb") as fh:
        fh.write(sc.merged_obstacles().export(file_type="ply"))
    width = max(3, len(str(len(results))))
    for i, r in enumerate(results, 1):
        doc = r.to_json()
        if r.dense is not None:
            doc["dense_path"] = r.dense.dense_q.tolist()
            tips = sc.to_scene(r.dense.exact.tip_mm)
            doc["exact_tip_path_mm"] = np.round(np.where(np.isfinite(tips), tips, 0.0), 4).tolist()
        doc["frame"] = "scene (mm)"
        with atomic_write(out / f"path_{i:0{width}d}.json") as fh:
            json.dump(doc, fh)


def _summary(console, doc: dict) -> None:
    s = doc["summary"]
    q, v = s["query_time"], s["validation_time"]
    console.print(f"plan --roadmap ({doc['nodes']:,} nodes): {s['solved']}/{s['targets']} solved; query "
                  f"median {q['median_ms']} ms, p95 {q['p95_ms']} ms; exact validation median "
                  f"{v['median_ms']} ms")
    for i, r in enumerate(doc["results"], 1):
        if not r["solved"]:
            console.print(f"  target {i} {np.round(r['target_mm'], 2).tolist()}: {r['message']}")


@bench_app.command("roadmap")
def bench_roadmap(
    scene: Annotated[Path, typer.Argument(metavar="SCENE.yaml", show_default=False, help="Scene file.")],
    roadmap: Annotated[Path, typer.Option(
        "--roadmap", metavar="DIR", show_default=False,
        help="Roadmap of the scene (`ctrplan roadmap build`).")],
    n: Annotated[int, typer.Option("--n", help="Random targets, uniform in the scene's target region.")] = 30,
    tolerance_mm: Annotated[float, typer.Option(
        "--tolerance-mm", help="Radius of each target sphere (mm).")] = 1.0,
    seed: Annotated[int, typer.Option("--seed", min=0, help="Seed of the targets and the planners.")] = 0,
    single_time_limit: Annotated[str, typer.Option(
        "--single-time-limit", metavar="DURATION",
        help="Time budget of the single-query RRTConnect run per target (as `plan --time-limit`); 0: "
             "skip the single-query runs.")] = "10s",
    backend: Annotated[str, typer.Option("--backend", metavar="NAME",
                                         help="Planning backend.")] = DEFAULT_PLANNING_BACKEND,
    model: ModelOpt = None,
    out: Annotated[Path, typer.Option(
        "--out", help="Directory for results.json, the OMPL log, benchmark.db and the plot.")
    ] = Path("runs/bench_roadmap"),
    as_json: Annotated[bool, typer.Option("--json", help="Print the JSON summary on stdout.")] = False,
) -> None:
    """Roadmap query times against single-query planning on N random targets in the scene's target
    region: query and exact-validation time distributions, solve rates, unsafe paths, a plot, and
    roadmap rows in the Planner Arena database."""
    from rich.console import Console

    from ctrplan.base.dataio import check_output_dir, output_dir
    from ctrplan.base.machine import machine_info
    from ctrplan.bench import roadmap as roadmap_bench
    from ctrplan.bench.ompl_log import write_database, write_logs
    from ctrplan.planning.roadmap.build import planning_context
    from ctrplan.planning.roadmap.query import RoadmapPlanner
    from ctrplan.planning.roadmap.store import fingerprints, load_roadmap
    from ctrplan.scene.loader import load_scene
    from ctrplan.viz.bench_plots import roadmap_times_figure

    if n < 1:
        raise InputError(f"--n: need at least 1 target, got {n}")
    if not tolerance_mm > 0:
        raise InputError(f"--tolerance-mm: must be > 0 (mm), got {tolerance_mm}")
    limit = None if single_time_limit.strip() in ("0", "0s") else parse_duration(
        single_time_limit, "s", "--single-time-limit")
    check_output_dir(out)
    sc = load_scene(scene)
    be = load_backend(backend, sc.robot, model)
    rm = load_roadmap(roadmap, fingerprints(sc, be))
    err = Console(stderr=True, highlight=False)
    with StatusLine(err, "bench roadmap", "compiling kernels (first run only)", timed=True) as status:
        ctx = planning_context(sc, be)
        planner = RoadmapPlanner(ctx, rm)
        targets = roadmap_bench.random_targets(sc.target, n, tolerance_mm, seed)
        records = roadmap_bench.run(planner, targets, backend_name=be.name, seed=seed,
                                    single=None if limit is None else (be, ctx.exact, limit),
                                    tick=lambda done, total: status(f"{done}/{total} runs"))
    out = output_dir(out)
    machine = machine_info()
    settings = {"roadmap": str(roadmap), "nodes": rm.n_nodes, "build_s": rm.meta.get("build_s"), "n": n,
                "tolerance_mm": tolerance_mm, "region": sc.target.to_dict(), "first_seed": seed,
                "single_time_limit_s": limit, "executor": "this process (not pinned)"}
    for r in records:
        if r["planner"] == roadmap_bench.ROADMAP_PLANNER:
            r["time_limit_s"] = limit or 0.0
    logs = write_logs(records, out, machine, settings)
    write_database(logs, out / "benchmark.db")
    roadmap_times_figure(records, out / "roadmap_times.png")
    doc = {"machine": machine, "settings": settings, "summary": roadmap_bench.summarize(records),
           "runs": records}
    if publish(doc, out, as_json):
        return
    for name, s in doc["summary"].items():
        typer.echo(f"{name}: {s}")
    typer.echo(f"wrote {out / 'results.json'}, {out / 'benchmark.db'} and {out / 'roadmap_times.png'}",
               err=True)
