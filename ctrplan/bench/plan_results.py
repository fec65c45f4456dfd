"""What `ctrplan bench plan` writes from its run records: the summary, the OMPL benchmark logs and
the Planner Arena database, and the results document (the plots: `ctrplan.viz.bench_plots`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ctrplan.base.machine import machine_info
from ctrplan.bench.ompl_log import write_database, write_logs
from ctrplan.bench.planning import summarize


def write_plan_results(records: list[dict[str, Any]], out: Path, limits: list[tuple[str, float]],
                       settings: dict[str, Any], check_rates: list[dict[str, Any]]
                       ) -> tuple[dict[str, Any], list[Path]]:
    """Summarise ``records`` and write the OMPL logs and ``benchmark.db`` into ``out``
    (an existing folder). ``settings`` are the run's (backends, planners, runs, first_seed,
    max_states, executor, wall_time_s); the scenes' time budgets come from ``limits`` (scene file,
    s); ``check_rates``: validity checks per second, one state vs a batch per call
    (`ctrplan.bench.planning.check_rates`). Returns the results document (machine, settings, summary,
    check_rates, runs) and the logs."""
    summary = summarize(records)
    machine = machine_info()
    settings = {**{k: settings[k] for k in ("backends", "planners", "runs", "first_seed")},
                "time_limit_s": {Path(f).name: limit for f, limit in limits},
                **{k: settings[k] for k in ("max_states", "executor", "wall_time_s")}, "out": str(out)}
    logs = write_logs(records, out, machine, settings)
    write_database(logs, out / "benchmark.db")
    doc = {"machine": machine, "settings": settings, "summary": summary, "check_rates": check_rates,
           "runs": records}
    return doc, logs
