#!/usr/bin/env python3
"""Refresh a generated block of README.md from the command that produces its numbers.

A block sits between ``<!-- MARKER:start -->`` and ``<!-- MARKER:end -->`` (e.g. MARKER =
``bench:kinematics``). This script runs the block's ``ctrplan ... --json`` command (extra arguments
are passed on), renders the JSON as markdown (a table, the machine, the exact command) and rewrites
only that block, so README numbers always come from the command. Add a block to `BLOCKS`.

    python scripts/update_readme.py kinematics --n 300
"""

from __future__ import annotations

import argparse
import json
import re
import shlex
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

README = Path(__file__).resolve().parents[1] / "README.md"


@dataclass(frozen=True)
class Block:
    """A generated README block: its marker, the ctrplan arguments that produce its JSON, and its
    renderer."""

    marker: str
    args: tuple[str, ...]
    render: Callable[[dict[str, Any]], str]


def machine_line(machine: dict[str, Any]) -> str:
    versions = ", ".join(f"{k} {machine[k]}" for k in ("python", "numpy", "numba", "torch")
                         if machine.get(k))
    return (f"Machine: {machine['cpu']}, {machine['cores']} cores (pinned to one), "
            f"{machine['platform']}; {versions}.")


def markdown_table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def render_kinematics(doc: dict[str, Any]) -> str:
    """Table of `ctrplan bench kinematics --json` (times in ms per single-query call)."""
    header = ["backend", "mode", "points", "n", "min ms", "median ms", "p90 ms", "p99 ms", "max ms",
              "p99/median", "failures", "median iterations"]
    rows = [[r["backend"], r["mode"], str(r["points"]), str(r["n"]), f"{r['min_ms']:.3f}",
             f"{r['median_ms']:.3f}", f"{r['p90_ms']:.3f}", f"{r['p99_ms']:.3f}", f"{r['max_ms']:.3f}",
             f"{r['p99_over_median']:.1f}", str(r["failures"]), f"{r['median_iterations']:g}"]
            for r in doc["results"]]
    text = markdown_table(header, rows)
    batched = doc.get("batched")
    if batched:
        rates = "; ".join(f"{r['backend']} {r['backbones_per_s']:,.0f} backbones/s" for r in batched)
        text += (f"\n\nBatched calls (all cores): {rates} ({batched[0]['batch']} configurations x "
                 f"{batched[0]['points']} points per call).")
    return text + "\n\n" + machine_line(doc["machine"])


def render_pinn(doc: dict[str, Any]) -> str:
    """Accuracy of a PINN vs the exact solver, from `ctrplan eval-model --json`."""
    e, t = doc["backbone_error_pct"], doc["tip_error_mm"]
    rows = [["backbone error / arc length", f"{e['mean']:.3f} %", f"{e['max']:.3f} %"]]
    rows += [[f"{tube} tip error", f"{v['mean']:.3f} mm", f"{v['max']:.3f} mm"] for tube, v in t.items()]
    rows += [["orientation error", f"{doc['orientation_error_deg']['mean']:.2f} deg",
              f"{doc['orientation_error_deg']['max']:.2f} deg"],
             ["u_z RMSE", f"{doc['u_z_rmse_1_per_m']:.3f} 1/m", ""],
             ["theta RMSE", f"{doc['theta_rmse_rad']:.4f} rad", ""]]
    tr = doc.get("training", {})
    stages = "; ".join(
        f"{s['recipe']} {s['steps']} steps, {s['wall_time_s'] / 60:.1f} min on {s['hardware']}"
        for s in tr.get("stages", [])) or f"{tr.get('recipe')}, {tr.get('wall_time_s')} s"
    return (markdown_table(["metric (" + str(doc["configurations"]) + " unseen configurations)", "mean",
                            "max"], rows) + f"\n\nModel `{doc['model']}`; training: {stages}.")


def render_training(cards: list[dict[str, Any]]) -> str:
    """Accuracy vs training time of each recipe run, from the model cards `ctrplan train` wrote."""
    rows = []
    for c in cards:
        m = c["metrics"]["backbone_error_pct"]
        start = " (from the previous row)" if c["recipe"]["name"] == "polish" else ""
        rows.append([c["recipe"]["name"] + start, c["hardware"], str(c["steps"]),
                     f"{c['wall_time_s'] / 60:.1f}", f"{m['mean']:.3f}", f"{m['max']:.3f}"])
    return markdown_table(["recipe", "hardware", "steps", "minutes", "mean error %", "max error %"], rows)


BLOCKS = {
    "kinematics": Block(marker="bench:kinematics", args=("bench", "kinematics"), render=render_kinematics),
    "pinn": Block(marker="pinn:accuracy", args=("eval-model",), render=render_pinn),
}
TRAINING_CARDS = README.parent / "docs" / "training"


def replace_block(text: str, marker: str, content: str) -> str:
    """``text`` with the body of block ``marker`` replaced by ``content``; the markers must exist once."""
    start, end = f"<!-- {marker}:start -->", f"<!-- {marker}:end -->"
    pattern = re.compile(re.escape(start) + r".*?" + re.escape(end), re.DOTALL)
    if len(pattern.findall(text)) != 1:
        raise SystemExit(f"README: need exactly one {start} ... {end} block")
    return pattern.sub(lambda _: f"{start}\n{content}\n{end}", text)


def run_block(name: str, extra: list[str]) -> str:
    """Run block ``name``'s command with ``extra`` arguments; its rendered markdown."""
    args = [*BLOCKS[name].args, *extra, "--json"]
    entry = "from ctrplan.cli import main; raise SystemExit(main())"  # `ctrplan` of this interpreter
    result = subprocess.run([sys.executable, "-c", entry, *args], stdout=subprocess.PIPE, check=False,
                            text=True)
    if result.returncode != 0:
        raise SystemExit(f"ctrplan {shlex.join(args)} failed with exit code {result.returncode}")
    doc = json.loads(result.stdout)
    command = shlex.join(["ctrplan", *args])
    return f"{BLOCKS[name].render(doc)}\n\nGenerated by `{command}` (via `scripts/update_readme.py`)."


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     epilog="Other arguments are passed on to the block's command.")
    parser.add_argument("block", choices=sorted([*BLOCKS, "training"]), help="README block to regenerate")
    parser.add_argument("--readme", type=Path, default=README, help="README file to update")
    ns, extra = parser.parse_known_args(argv)  # the rest goes to the ctrplan command
    text = ns.readme.read_text()
    if ns.block == "training":
        cards = [json.loads(p.read_text()) for p in sorted(TRAINING_CARDS.glob("*.json"))]
        body = render_training(cards) + ("\n\nFrom the model cards in `docs/training/` (written by "
                                         "`ctrplan train`; errors on 100 unseen configurations).")
        ns.readme.write_text(replace_block(text, "pinn:training", body))
    else:
        ns.readme.write_text(replace_block(text, BLOCKS[ns.block].marker, run_block(ns.block, extra)))
    print(f"updated the {ns.block} block of {ns.readme}", file=sys.stderr)


if __name__ == "__main__":
    main()
