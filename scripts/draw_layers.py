#!/usr/bin/env python3
"""Draw docs/figures/layers.svg, the layer map of docs/design.md §2 (keep it in step with the
import-linter contract in pyproject.toml when a layer changes).

    python scripts/draw_layers.py [OUT.svg|OUT.png ...]
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.patches import FancyArrowPatch, FancyBboxPatch  # noqa: E402

#: Top to bottom: the boxes of each layer (name, what it holds).
LAYERS = [
    [("cli", "one module per command group (typer); the console entry point imports it lazily")],
    [("bench", "benchmarks: kinematics and planning runs, Planner Arena logs, plots")],
    [("design", "design task, search space, proven evaluation, Optuna study, outputs, report")],
    [("viz", "plan plot, offline HTML viewer, PINN figures")],
    [("planning", "planning model, validity, IK goal, planner table, roadmaps, validation"),
     ("training", "eq. 9 in torch, samples, losses, trainer, fine-tuning")],
    [("calibration", "measured data, fitting causes, selection, diagnosis, experiments")],
    [("collision", "capsule chain vs FCL"), ("broadphase", "distance grid"),
     ("stability", "snap-free sweeps, certificates")],
    [("kinematics", "Backend, Backbone; cosserat (numba shooting), pinn, hybrid, model files")],
    [("model", "robot (frozen), effects, measurement, scene, segmentation, scene_labels")],
    [("base", "errors, yamlio, dataio, memory, machine (machine info), parallel (worker pools)")],
]
NOTE = (4, "planning never imports training; training may import calibration")  # under layer 4 (0-based)
COLOURS = ["#dbe9f6", "#e3f1dc", "#fbe7cf", "#f3dcef", "#fff4c2", "#e8e2f7", "#d9f2ee", "#fde0dc",
           "#e6e6e6", "#f4f4f4"]
LEFT, RIGHT, HEIGHT = 1.0, 9.9, 0.78  # box extent in axis units (one layer per unit)


def draw(outputs: list[Path]) -> None:
    plt.rcParams.update({"svg.hashsalt": "ctrplan", "svg.fonttype": "none"})  # stable ids, text as text
    n = len(LAYERS)
    fig, ax = plt.subplots(figsize=(10, 0.62 * n + 0.9))
    ax.set_xlim(0, 10)
    ax.set_ylim(-0.3, n + 0.55)
    ax.axis("off")
    for i, boxes in enumerate(LAYERS):
        y = n - 1 - i
        ax.text(LEFT - 0.15, y + HEIGHT / 2, str(n - i), ha="right", va="center", fontsize=10, color="#666")
        width = (RIGHT - LEFT - 0.1 * (len(boxes) - 1)) / len(boxes)
        for j, (name, text) in enumerate(boxes):
            x = LEFT + j * (width + 0.1)
            ax.add_patch(FancyBboxPatch((x, y), width, HEIGHT, boxstyle="round,pad=0,rounding_size=0.08",
                                        fc=COLOURS[i], ec="#777", lw=0.8))
            ax.text(x + 0.1, y + HEIGHT - 0.2, name, fontsize=11.5, fontweight="bold", va="center")
            ax.text(x + 0.1, y + 0.27, text, fontsize=8.3, va="center", color="#333")
        if i < n - 1:
            ax.add_patch(FancyArrowPatch((0.45, y + HEIGHT / 2), (0.45, y - 1 + HEIGHT / 2 + 0.12),
                                         arrowstyle="-|>", mutation_scale=10, color="#555", lw=1))
    ax.text(0.45, n - 1 + HEIGHT + 0.08, "imports", ha="center", fontsize=9, color="#555")
    ax.text(LEFT + (RIGHT - LEFT) / 2, n - 1 - NOTE[0] - 0.11, NOTE[1], ha="center", va="center",
            fontsize=8.5, style="italic", color="#a33")
    ax.set_title("ctrplan's layers: a module imports only from the layers below it", fontsize=12.5,
                 fontweight="bold")
    fig.tight_layout()
    for out in outputs:
        fig.savefig(out, dpi=110, metadata={"Date": None} if out.suffix == ".svg" else None)
    plt.close(fig)


if __name__ == "__main__":
    root = Path(__file__).resolve().parents[1]
    draw([Path(a) for a in sys.argv[1:]] or [root / "docs" / "figures" / "layers.svg"])
