"""OMPL benchmark logs and the Planner Arena SQLite database, from `ctrplan bench plan` records.

One experiment per scene (named after it); one "planner" per backend x planner pair, named
``RRTConnect [pinn]`` so Planner Arena (plannerarena.org) shows the backend. The log follows the format
of ``ompl::tools::Benchmark::saveResultsToStream``; the database is made by the converter that ships
with the ``ompl`` wheel (``ompl_benchmark_statistics.py``), so it is exactly what Planner Arena reads.
"""

from __future__ import annotations

import contextlib
import io
import socket
from datetime import datetime
from importlib.metadata import version
from pathlib import Path
from typing import Any

from ctrplan.base.dataio import atomic_write
from ctrplan.planning.planners import OMPL_NAMES

#: OMPL's PlannerStatus names, in enum order (the ``status`` column is an index into them).
STATUS = ("Unknown status", "Invalid start", "Invalid goal", "Unrecognized goal type", "Timeout",
          "Approximate solution", "Exact solution", "Crash", "Abort", "Infeasible")
_STATUS_ALIASES = {"invalid_start": "Invalid start", "invalid_goal": "Invalid goal"}
#: (run property in the log, its SQL type, record key); booleans and Nones are converted.
PROPERTIES = (
    ("time", "REAL", "planning_time_s"),
    ("solved", "BOOLEAN", "solved"),
    ("status", "ENUM", "status"),
    ("path found", "BOOLEAN", "found"),
    ("repaired", "BOOLEAN", "repaired"),
    ("exact collision free", "BOOLEAN", "exact_collision_free"),
    ("exact tip in target", "BOOLEAN", "exact_tip_in_target"),
    ("solution length", "REAL", "path_length_mm"),
    ("tip travel mm", "REAL", "tip_travel_mm"),
    ("kinematics time", "REAL", "kinematics_s"),
    ("collision time", "REAL", "collision_s"),
    ("planner time", "REAL", "planner_s"),
    ("validation time", "REAL", "validation_s"),
    ("kinematics calls", "INTEGER", "kinematics_calls"),
    ("collision checks", "INTEGER", "collision_checks"),
    ("checks per second", "REAL", "checks_per_s"),
    ("min clearance mm", "REAL", "min_clearance_mm"),
    ("max position error mm", "REAL", "max_position_error_mm"),
    ("seed", "INTEGER", "seed"),
)


def planner_label(planner: str, backend: str) -> str:
    """The planner name in logs and databases, e.g. ``RRTConnect [pinn]``."""
    return f"{OMPL_NAMES.get(planner, planner)} [{backend}]"


def status_index(status: str) -> int:
    """Index of a status string (OMPL's or ctrplan's ``INVALID_GOAL``...) in `STATUS` (0: unknown)."""
    name = _STATUS_ALIASES.get(status.lower(), status)
    lowered = [s.lower() for s in STATUS]
    return lowered.index(name.lower()) if name.lower() in lowered else 0


def _value(record: dict[str, Any], key: str, kind: str) -> str:
    value = record.get(key)
    if key == "status":
        return str(status_index(str(value or "")))
    if value is None:
        return ""
    if kind == "BOOLEAN":
        return "1" if value else "0"
    return repr(value) if isinstance(value, float) else str(value)


def experiment_log(scene_name: str, records: list[dict[str, Any]], machine: dict[str, Any],
                   settings: dict[str, Any]) -> str:
    """The benchmark log text of one scene's records (same-seed runs of each backend x planner)."""
    pairs = list(dict.fromkeys((r["backend"], r["planner"]) for r in records))
    runs = {pair: [r for r in records if (r["backend"], r["planner"]) == pair] for pair in pairs}
    lines = [f"OMPL version {version('ompl')}",
             f"Experiment {scene_name}",
             "2 experiment properties",
             f"scene VARCHAR = {scene_name}",
             f"ctrplan_version VARCHAR = {machine.get('ctrplan') or '?'}",
             f"Running on {socket.gethostname()}",
             f"Starting at {datetime.now().strftime('%Y-%m-%d %H:%M:%S')}",
             "<<<|", *(f"{k}: {v}" for k, v in settings.items()), "|>>>",
             "<<<|", f"{machine.get('cpu')}, {machine.get('cores')} cores", "|>>>",
             f"{min(r['seed'] for r in records)} is the random seed",
             f"{max(r['time_limit_s'] for r in records)} seconds per run",
             "0 MB per run",
             f"{max(len(v) for v in runs.values())} runs per planner",
             f"{sum(r['planning_time_s'] for r in records):.3f} seconds spent to collect the data",
             "1 enum type",
             "status|" + "|".join(STATUS),
             f"{len(pairs)} planners"]
    for (backend, planner), rs in runs.items():
        lines += [planner_label(planner, backend),
                  "2 common properties",
                  f"backend = {backend}",
                  f"time limit s = {rs[0]['time_limit_s']}",
                  f"{len(PROPERTIES)} properties for each run",
                  *(f"{name} {kind}" for name, kind, _ in PROPERTIES),
                  f"{len(rs)} runs",
                  *("".join(f"{_value(r, key, kind)}; " for _, kind, key in PROPERTIES) for r in rs),
                  "."]
    return "\n".join(lines) + "\n"


def write_logs(records: list[dict[str, Any]], out: Path, machine: dict[str, Any],
               settings: dict[str, Any]) -> list[Path]:
    """One ``<scene>.log`` per scene in ``out``; their paths."""
    paths = []
    for scene in dict.fromkeys(r["scene_name"] for r in records):
        path = out / f"{scene}.log"
        with atomic_write(path) as fh:
            fh.write(experiment_log(scene, [r for r in records if r["scene_name"] == scene], machine,
                                    settings))
        paths.append(path)
    return paths


def write_database(logs: list[Path], path: Path) -> Path:
    """The Planner Arena database of ``logs`` (replaces ``path``), via OMPL's own converter."""
    from ompl._benchmark_statistics import computeViews, readBenchmarkLog

    tmp = path.with_name(path.name + ".tmp")
    tmp.unlink(missing_ok=True)
    with contextlib.redirect_stdout(io.StringIO()):  # the converter prints progress on stdout
        readBenchmarkLog(str(tmp), [str(p) for p in logs], False)
        computeViews(str(tmp), False)
    tmp.replace(path)
    return path
