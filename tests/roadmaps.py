"""Small roadmaps of open.yaml built in a test process (a budget in work: the same every run), for the
roadmap, repair and serve tests."""

from __future__ import annotations

from pathlib import Path

from ctrplan.base.parallel import InlinePool
from ctrplan.planning.roadmap.build import Source, build
from tests.paths import SCENES

OPEN = SCENES / "open.yaml"


def small_roadmap(folder: Path, seed: int, nodes: int, focus: list | None = None):
    """(planning context, source, roadmap) of a roadmap of open.yaml grown in ``folder`` to ``nodes``
    nodes in this process, with its sweep index; ``focus``: (name, region or None for the scene's
    target) pairs, as `build` takes them."""
    source = Source(str(OPEN), "pinn")
    ctx = source()
    regions = None if focus is None else [(n, r if r is not None else ctx.scene.target) for n, r in focus]
    rm = build(ctx, source, folder, InlinePool(context=lambda: ctx), time_limit_s=600.0, seed=seed, workers=1,
               executor="test", max_nodes=nodes, focus=regions)
    return ctx, source, rm
