#!/usr/bin/env python3
"""Train a PINN for each robot with the default recipe and measure it on 5,000 unseen configurations:
the time-to-target table of docs/benchmarks.md (issue 40).

For every robot this runs exactly what a user runs:

    ctrplan train --robot ROBOT --name NAME --time-limit 20m --threads 2 --json
    ctrplan eval-model --robot ROBOT --model NAME --n 5000 --json

and writes one JSON document (the eval-model metrics; the card's wall time, steps, hardware, where it
started from, its verdict, its time-to-target curve and extrapolation, where its tail lies; the load
of the machine while it trained) that `update_readme.py robots` renders:

    python scripts/pinn_robots.py --out docs/training/robots.json --lock /work/heavy.lock \\
        nominal=nominal two_tube=examples/robots/two_tube.yaml ...

``--lock FILE`` holds an exclusive lock on FILE for each robot's training and evaluation (so that no
other timed job overlaps it) and releases it between robots. ``--transfer`` is passed on to `ctrplan
train` (``NAME=ROBOT:none`` trains that robot from scratch).
"""

from __future__ import annotations

import argparse
import fcntl
import json
import os
import resource
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path


def ctrplan(*args: str) -> dict:
    """Run ``ctrplan ARGS --json`` with this interpreter and return its JSON document (stderr passes
    through)."""
    entry = "from ctrplan.cli.app import main; raise SystemExit(main())"
    out = subprocess.run([sys.executable, "-c", entry, *args, "--json"], check=True, text=True,
                         stdout=subprocess.PIPE)
    return json.loads(out.stdout)


def _children_cpu_s() -> float:
    """CPU seconds (user + system) of the finished child processes so far: what a run got of the
    machine, which on a shared machine is less than its wall time times its threads."""
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


@contextmanager
def locked(path: Path | None):
    """An exclusive `flock` on ``path`` while inside (nothing without a path)."""
    if path is None:
        yield
        return
    with open(path, "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def measure(item: str, ns: argparse.Namespace) -> dict:
    """Train and evaluate one ``NAME=ROBOT[:TRANSFER]``; its row of the JSON document."""
    name, _, spec = item.partition("=")
    robot, _, transfer = spec.partition(":")
    with locked(ns.lock):
        load_before = os.getloadavg()
        cpu0 = _children_cpu_s()
        t0 = time.monotonic()
        card = ctrplan("train", "--robot", robot, "--name", name, "--threads", str(ns.threads),
                       "--time-limit", ns.time_limit, "--clock", ns.clock,
                       "--transfer", transfer or ns.transfer, "--out-dir", str(ns.models_dir))
        command_s = time.monotonic() - t0
        train_cpu_s = _children_cpu_s() - cpu0
        load_after = os.getloadavg()
        metrics = ctrplan("eval-model", "--robot", robot, "--model", str(ns.models_dir / name),
                          "--n", str(ns.n), "--out", f"runs/eval_{name}")
    tip = metrics["tip_error_mm"]["tube1"]
    print(f"{name}: tube-1 tip mean {tip['mean']:.3f}, p99.9 {tip['p99_9']:.3f}, max {tip['max']:.3f} mm "
          f"(card: {'meets' if card.get('meets_target') else 'misses'} its target)", file=sys.stderr)
    return {"name": name, "robot": robot, "command_s": round(command_s, 1),
            "train_cpu_s": round(train_cpu_s, 1), "clock": ns.clock, "wall_time_s": card["wall_time_s"],
            "data_generation_s": card["data_generation_s"], "steps": card["steps"],
            "hardware": card["hardware"], "recipe": card["recipe"]["name"],
            "dense_batch": card["recipe"]["dense_batch"],
            "mining_share": (card["recipe"].get("mining") or {}).get("share"), "threads": ns.threads,
            "load_average": {"before": [round(x, 2) for x in load_before],
                             "after": [round(x, 2) for x in load_after]},
            "transferred_from": card.get("transferred_from"), "frame_tube": card["network"].get("frame_tube"),
            "meets_target": card.get("meets_target"), "time_to_target": card.get("time_to_target"),
            "card_worst": card["metrics"].get("worst"),
            "mining_worker": {k: (card.get("mining") or {}).get(k) for k in ("solved_in", "solve_cpu_s",
                                                                            "waited_s")},
            "unsolved_in_training": card["unsolved_configurations"]["count"], **metrics}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("robots", nargs="+", metavar="NAME=ROBOT[:TRANSFER]",
                        help="model name and robot (built-in name or robot file), optionally the "
                             "--transfer of that robot's run")
    parser.add_argument("--out", type=Path, required=True, help="JSON file to write (rows are added)")
    parser.add_argument("--n", type=int, default=5000, help="evaluation configurations")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--time-limit", default="20m")
    parser.add_argument("--clock", default="wall", choices=["wall", "cpu"],
                        help="the clock --time-limit is read on (ctrplan train --clock)")
    parser.add_argument("--transfer", default="auto")
    parser.add_argument("--lock", type=Path, default=None, help="flock this file around each robot")
    parser.add_argument("--models-dir", type=Path, default=Path("models"))
    ns = parser.parse_args(argv)
    doc = json.loads(ns.out.read_text()) if ns.out.exists() else {"robots": []}
    for item in ns.robots:
        row = measure(item, ns)
        doc["robots"] = [r for r in doc["robots"] if r["name"] != row["name"]] + [row]
        ns.out.parent.mkdir(parents=True, exist_ok=True)
        ns.out.write_text(json.dumps(doc, indent=2, allow_nan=False) + "\n")  # after every robot


if __name__ == "__main__":
    main()
