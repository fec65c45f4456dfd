"""The search space of a design task: study parameters <-> robot files.

A design is a dict of parameters: one float per `Vary` (named ``tube1.curvature_1_per_m``, file
units) and, with a catalogue, one categorical ``diameters`` naming a nested set of stock sizes
(``"0.4/0.5 0.7/0.9 1.2/1.5"``: inner/outer diameter per tube, innermost first). Parameters left out
keep the base robot's values, so ``{}`` is the base design itself. `robot_dict` gives the robot file
of a design; the robot loader (`ctrplan.model.robot.robot_from_yaml`) decides whether it can be built.
"""

from __future__ import annotations

from typing import Any

import optuna

from ctrplan.design.task import DesignTask, StockSize

#: Name of the categorical parameter that picks the stock sizes of all tubes.
DIAMETERS = "diameters"

Parameters = dict[str, Any]


def diameters_label(sizes: tuple[StockSize, ...]) -> str:
    """The ``diameters`` value of a nested set of sizes (innermost first)."""
    return " ".join(s.label for s in sizes)


def distributions(task: DesignTask) -> dict[str, optuna.distributions.BaseDistribution]:
    """Optuna distributions of the task's parameters, in a fixed order."""
    out: dict[str, optuna.distributions.BaseDistribution] = {
        v.name: optuna.distributions.FloatDistribution(v.low, v.high) for v in task.vary}
    if task.diameter_sets:
        out[DIAMETERS] = optuna.distributions.CategoricalDistribution(
            [diameters_label(c) for c in task.diameter_sets])
    return out


def robot_dict(task: DesignTask, parameters: Parameters) -> dict[str, Any]:
    """The robot file (as a dict, file units) of the design ``parameters``; the base robot's name
    becomes ``name`` only for the base design (``{}``)."""
    d = task.robot.to_dict()
    for v in task.vary:
        if v.name in parameters:
            d["tubes"][v.tube - 1][v.field] = float(parameters[v.name])
    if DIAMETERS in parameters:
        sets = {diameters_label(c): c for c in task.diameter_sets}
        for tube, size in zip(d["tubes"], sets[parameters[DIAMETERS]], strict=True):
            tube["inner_diameter_mm"] = size.inner_diameter_mm
            tube["outer_diameter_mm"] = size.outer_diameter_mm
    if parameters:
        d["name"] = f"{task.name}_design"
    return d


def max_strain(data: dict[str, Any]) -> float:
    """Largest pre-curvature strain of the tubes of a robot-file dict: kappa * OD / 2 (the strain of
    straightening the curved part; 0 for tubes without one)."""
    return max((1e-3 * t["curvature_1_per_m"] * 0.5 * t["outer_diameter_mm"]
                for t in data["tubes"] if t["curved_length_mm"] > 0), default=0.0)


def total_length_mm(data: dict[str, Any]) -> float:
    """Sum of the tube lengths of a robot-file dict (mm)."""
    return float(sum(t["straight_length_mm"] + t["curved_length_mm"] for t in data["tubes"]))
