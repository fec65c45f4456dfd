#!/usr/bin/env python3
"""Train a PINN with the default recipe for each robot and measure it on 5,000 unseen configurations.

For every robot this runs exactly what a user runs:

    ctrplan train --robot ROBOT --name NAME --json
    ctrplan eval-model --robot ROBOT --model NAME --n 5000 --json

and writes one JSON document (the eval-model metrics, the card's wall time, steps, hardware and the
configurations the exact solver could not solve) that `update_readme.py robots` renders:

    python scripts/pinn_robots.py --out docs/training/robots.json nominal=nominal \\
        two_tube=examples/robots/two_tube.yaml three_tube_fixed=examples/robots/three_tube_fixed.yaml

``--jobs J`` trains J robots at once (each with ``--threads``), e.g. three robots on one thread each.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path


def ctrplan(*args: str) -> dict:
    """Run ``ctrplan ARGS --json`` and return its JSON document (stderr passes through)."""
    exe = shutil.which("ctrplan") or sys.exit("ctrplan is not on PATH (pip install -e .)")
    out = subprocess.run([exe, *args, "--json"], check=True, text=True, stdout=subprocess.PIPE)
    return json.loads(out.stdout)


def measure(item: str, ns: argparse.Namespace) -> dict:
    """Train and evaluate one ``NAME=ROBOT``; its row of the JSON document."""
    name, _, robot = item.partition("=")
    card = ctrplan("train", "--robot", robot, "--name", name, "--threads", str(ns.threads),
                   "--out-dir", str(ns.models_dir))
    metrics = ctrplan("eval-model", "--robot", robot, "--model", str(ns.models_dir / name),
                      "--n", str(ns.n), "--out", f"runs/eval_{name}")
    print(f"{name}: tube-1 tip mean {metrics['tip_error_pct_length']['mean']:.3f} %, max "
          f"{metrics['tip_error_pct_length']['max']:.3f} % of arc length", file=sys.stderr)
    return {"name": name, "robot": robot, "wall_time_s": card["wall_time_s"],
            "data_generation_s": card["data_generation_s"], "steps": card["steps"],
            "hardware": card["hardware"], "recipe": card["recipe"]["name"], "threads": ns.threads,
            "jobs": ns.jobs, "unsolved_in_training": card["unsolved_configurations"]["count"], **metrics}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("robots", nargs="+", metavar="NAME=ROBOT",
                        help="model name and robot (built-in name or robot file)")
    parser.add_argument("--out", type=Path, required=True, help="JSON file to write")
    parser.add_argument("--n", type=int, default=5000, help="evaluation configurations")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--jobs", type=int, default=1, help="robots trained at once")
    parser.add_argument("--models-dir", type=Path, default=Path("models"))
    ns = parser.parse_args(argv)
    with ThreadPoolExecutor(max_workers=ns.jobs) as pool:
        rows = list(pool.map(lambda item: measure(item, ns), ns.robots))
    ns.out.parent.mkdir(parents=True, exist_ok=True)
    ns.out.write_text(json.dumps({"robots": rows}, indent=2, allow_nan=False) + "\n")


if __name__ == "__main__":
    main()
