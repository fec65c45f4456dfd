"""The one style of ctrplan's figures: how every PNG is drawn and written, and the colours they share.

Every figure is drawn with matplotlib on the Agg backend (`pyplot`: files only, no display) and
written atomically (`write_png`). Colours of the models compared (`MODEL_COLORS`: the nominal model
grey, the extended or surrogate one blue) and of the tubes (`TUBE_COLORS`) are the same in every
figure.

Plan pictures (plan.png and plan.html): obstacles are coloured by what their name says they are, as
an anatomy atlas would: vessels red, nerves yellow, mucosa pinks, bone ivory to brown, skin faint;
within a class each obstacle gets its own shade, so the legend still tells them apart, and given which
obstacles touch (`neighbours`), each takes the shade of its class that differs most from its
neighbours' colours. Other names take distinct hues (no greys). The target has a colour no obstacle
gets, and the clearance along the backbone runs from red (touching) through orange and yellow to
green (`CLEARANCE_CAP_MM` and more).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ctrplan.base.dataio import save_figure
from ctrplan.scene.geometry import opposite
from ctrplan.scene.objects import Obstacle

#: A model as it was (nominal) and as it was extended or replaced (extended robot, surrogate).
NOMINAL_COLOR = "#b0b0b0"
EXTENDED_COLOR = "#1f77b4"
#: Tubes 1 (innermost) to 4.
TUBE_COLORS = ("#d62728", "#2ca02c", "#1f77b4", "#9467bd")

#: The target region: a colour no obstacle gets.
TARGET_COLOR = "#00b4f0"
#: Clearances at or above this (mm) share the "far" colour; also the cap of the computation.
CLEARANCE_CAP_MM = 3.0
#: Clearance colour stops (fraction of `CLEARANCE_CAP_MM`, colour).
CLEARANCE_STOPS = ((0.0, "#d7191c"), (0.33, "#fd8d3c"), (0.66, "#fee08b"), (1.0, "#1a9641"))

#: (name keywords, shades): the first class whose keyword is in an obstacle's name gives its colour.
ANATOMY_CLASSES = (
    (("carotid", "arter", "vessel", "vein"), ("#b2182b", "#d6604d", "#8c0c25")),
    (("chiasm", "optic", "nerve"), ("#e6b400", "#f6d743", "#c79800")),
    (("septum",), ("#b0608c",)),
    (("turbinate", "mucosa", "vestibule", "valve"), ("#f29b9b", "#e0784e", "#c98bbd", "#f6c39a", "#d9607e")),
    (("sella", "sphenoid", "clivus", "bone", "floor", "roof", "wall", "cavity"),
     ("#e3cf94", "#a07a4a", "#f2ead3", "#c49a5c", "#8a7f5a", "#d9b36c", "#b9a98a", "#7a5c3a")),
    (("face", "skin"), ("#f0c9a8",)),
)
#: Hues for obstacles no class names (distinct, no greys, none near the target's).
OTHER_COLORS = ("#4e79a7", "#f28e2b", "#59a14f", "#e15759", "#b07aa1", "#edc948", "#9c755f",
                "#ff9da7", "#8cd17d", "#d37295")


def pyplot() -> Any:
    """matplotlib's pyplot on the Agg backend (figures go to files; no display is needed), imported on
    first use."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def write_png(fig: Any, path: str | Path, dpi: int = 100, **kwargs: Any) -> Path:
    """Write the figure ``fig`` to ``path`` (PNG unless the suffix says otherwise) completely or not at
    all (`ctrplan.base.dataio.save_figure`), close it, and return ``path``."""
    path = save_figure(fig, path, dpi=dpi, **kwargs)
    pyplot().close(fig)
    return Path(path)


def _rgb(colour: str) -> np.ndarray:
    return np.array([int(colour[i:i + 2], 16) for i in (1, 3, 5)], dtype=float)


def obstacle_colors(names: Sequence[str],
                    neighbours: Mapping[str, set[str]] | None = None) -> dict[str, str]:
    """A colour (``#rrggbb``) for every obstacle name: of the shades of its class (`ANATOMY_CLASSES`,
    else `OTHER_COLORS`) not taken yet (all of them once every one is), the one farthest (RGB) from
    the colours of its ``neighbours`` coloured before it (without: the first). Names with the most
    neighbours choose first."""
    taken: dict[int | None, list[str]] = {}
    out: dict[str, str] = {}
    for name in sorted(names, key=lambda n: -len((neighbours or {}).get(n, ()))):
        low = name.lower()
        k = next((i for i, (words, _) in enumerate(ANATOMY_CLASSES) if any(w in low for w in words)), None)
        shades = OTHER_COLORS if k is None else ANATOMY_CLASSES[k][1]
        used = taken.setdefault(k, [])
        free = [c for c in shades if c not in used] or list(shades)
        near = [_rgb(out[n]) for n in (neighbours or {}).get(name, ()) if n in out]
        if near:
            free.sort(key=lambda c: -min(np.linalg.norm(_rgb(c) - q) for q in near))
        out[name] = free[0]
        used.append(free[0])
    return {name: out[name] for name in names}


def touching(obstacles: Sequence[Obstacle], gap_mm: float = 2.0) -> dict[str, set[str]]:
    """For each obstacle, the names of those whose bounding boxes come within ``gap_mm`` of its own
    (mm): the neighbours `obstacle_colors` keeps apart."""
    bounds = np.array([o.bounds for o in obstacles]).reshape(-1, 2, 3)
    lo, hi = bounds[:, 0] - gap_mm / 2, bounds[:, 1] + gap_mm / 2
    meet = np.all((lo[:, None] <= hi[None]) & (hi[:, None] >= lo[None]), axis=-1)
    return {o.name: {obstacles[j].name for j in np.flatnonzero(meet[i]) if j != i}
            for i, o in enumerate(obstacles)}


def scene_colors(obstacles: Sequence[Obstacle]) -> dict[str, str]:
    """`obstacle_colors` of a scene's obstacles with their `touching` neighbours."""
    return obstacle_colors([o.name for o in obstacles], touching(obstacles))


def axis_labels(anatomy: dict[str, str] | None) -> dict[str, tuple[str, str]]:
    """For each scene axis, the names of its positive and negative ends: the patient directions
    when the scene gives them (``("left", "right")``), else ``("+x", "-x")``."""
    if not anatomy:
        return {a: (f"+{a}", f"-{a}") for a in "xyz"}
    return {a: (anatomy[a], opposite(anatomy[a])) for a in "xyz"}


def view_name(anatomy: dict[str, str] | None, hidden: str) -> str:
    """The name of a projection along scene axis ``hidden``: sagittal, coronal or axial when the
    scene gives patient directions, else ``projection along x``."""
    if not anatomy:
        return f"projection along {hidden}"
    return {"left": "sagittal", "right": "sagittal", "anterior": "coronal", "posterior": "coronal",
            "superior": "axial", "inferior": "axial"}[anatomy[hidden]] + " view"
