"""Colours and orientation labels shared by plan.png and plan.html.

Obstacles are coloured by what their name says they are, as an anatomy atlas would: vessels red,
nerves yellow, mucosa pinks, bone ivory, skin faint; within a class each obstacle gets its own
shade, so the legend still tells them apart. Other names take distinct hues (no greys). The target
has a colour no obstacle gets, and the clearance along the backbone runs from red (touching) through
orange and yellow to green (`CLEARANCE_CAP_MM` and more).
"""

from __future__ import annotations

from collections.abc import Sequence

from ctrplan.scene import opposite

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
    (("septum",), ("#c9778f",)),
    (("turbinate", "mucosa", "vestibule", "valve"), ("#f4a6a6", "#e98989", "#f7c6c0", "#ec9c8c")),
    (("sella", "sphenoid", "clivus", "bone", "floor", "roof", "wall", "cavity"),
     ("#d8c8a0", "#c9b27c", "#e7dcc0", "#b89f6b", "#efe6cf", "#a8926a", "#dccfae", "#c2ad86")),
    (("face", "skin"), ("#f0c9a8",)),
)
#: Hues for obstacles no class names (distinct, no greys, none near the target's).
OTHER_COLORS = ("#4e79a7", "#f28e2b", "#59a14f", "#e15759", "#b07aa1", "#edc948", "#9c755f",
                "#ff9da7", "#8cd17d", "#d37295")


def obstacle_colors(names: Sequence[str]) -> dict[str, str]:
    """A colour (``#rrggbb``) for every obstacle name."""
    used: dict[int, int] = {}
    out = {}
    for name in names:
        low = name.lower()
        k = next((i for i, (words, _) in enumerate(ANATOMY_CLASSES) if any(w in low for w in words)), None)
        shades = OTHER_COLORS if k is None else ANATOMY_CLASSES[k][1]
        n = used.get(k, 0)
        used[k] = n + 1
        out[name] = shades[n % len(shades)]
    return out


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
