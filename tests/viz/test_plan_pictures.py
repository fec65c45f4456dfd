"""What plan.png and plan.html show about clearance (issue 27 item 7): the backbones over the
translucent obstacles, the notes (result, failure reason, clearances; warnings in red), touching
structures in colours told apart, and the viewer's controls hint and hover text per structure."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.colors import to_rgb

from ctrplan.scene.loader import load_scene
from ctrplan.viz import viewer_data, write_viewer
from ctrplan.viz.plan_plot import plan_figure
from ctrplan.viz.style import scene_colors
from tests.paths import SCENES


@pytest.fixture(scope="module")
def skullbase():
    return load_scene(SCENES / "skullbase.yaml")


def midline(scene) -> np.ndarray:
    end = scene.target.center
    start = end + np.array([0.0, -16.0, -100.0])
    line = start + np.linspace(0.0, 1.0, 40)[:, None] * (end - start)
    return np.stack([line, line + 0.5])


def test_backbones_are_drawn_over_every_obstacle(skullbase):
    """Over the obstacles' triangles (overview) and their cuts' fills and outlines (projections)."""
    fig = plan_figure(skullbase, midline(skullbase))
    panels = [ax for ax in fig.axes if ax.collections]
    assert len(panels) == 3  # the overview and two projections
    for ax in panels:
        obstacles = [c.get_zorder() for c in ax.collections
                     if isinstance(c, PolyCollection | LineCollection)]
        backbones = [line.get_zorder() for line in ax.lines if len(line.get_xdata()) == 40]
        assert obstacles and len(backbones) == 2
        assert min(backbones) > max(obstacles)
    overview = next(ax for ax in fig.axes if ax.name == "3d")
    assert overview.computed_zorder is False  # else mplot3d re-sorts by depth and hides the path


def test_notes_print_result_and_clearance_with_warnings_in_red(skullbase):
    notes = [("not solved: the exact robot collides (first with nasal_septum)", True),
             ("min clearance 0.00 mm to nasal_septum", False)]
    fig = plan_figure(skullbase, midline(skullbase), notes=notes)
    texts = {t.get_text(): t for ax in fig.axes for t in ax.texts}
    joined = " ".join(texts)
    assert "not solved: the exact robot collides" in joined and "min clearance 0.00 mm" in joined
    warn = [t for s, t in texts.items() if "not solved" in s or "nasal_septum)" in s]
    plain = texts["min clearance 0.00 mm to nasal_septum"]
    assert all(to_rgb(t.get_color())[0] > 0.6 > to_rgb(t.get_color())[1] for t in warn)  # red
    assert to_rgb(plain.get_color())[0] < 0.3


def bounding_boxes_meet(a, b, gap: float = 2.0) -> bool:
    lo_a, hi_a = a.bounds
    lo_b, hi_b = b.bounds
    return bool(np.all(lo_a - gap / 2 <= hi_b + gap / 2) and np.all(lo_b - gap / 2 <= hi_a + gap / 2))


def test_touching_structures_get_colours_told_apart(skullbase):
    """Every pair of skull-base structures whose boxes come within 2 mm differs by at least 45 of
    255 in RGB distance (with colours given by name alone, the nearest such pair is 36 apart)."""
    colours = scene_colors(skullbase.obstacles)
    obs = skullbase.obstacles
    pairs = [(a, b) for i, a in enumerate(obs) for b in obs[i + 1:] if bounding_boxes_meet(a, b)]
    assert len(pairs) > 20
    gaps = [np.linalg.norm(np.subtract(to_rgb(colours[a.name]), to_rgb(colours[b.name]))) * 255
            for a, b in pairs]
    assert min(gaps) >= 45
    assert len(set(colours.values())) == len(obs)


def test_viewer_has_a_controls_hint_and_names_each_structure_with_its_clearance(skullbase, tmp_path):
    bbs = midline(skullbase)
    listed = {"nasal_septum": ("0.12 mm (required 0.2 mm; state 1, 150.0 mm along the robot)", True),
              "optic_chiasm": ("6.61 mm (required 1.7 mm; state 1, 182.0 mm along the robot)", False)}
    data = viewer_data(skullbase, bbs, np.full((2, 40), 0.75), {"result": "x"}, None, structures=listed)
    notes = {o["name"]: (o["note"], o["warn"]) for o in data["obstacles"]}
    assert notes["nasal_septum"] == listed["nasal_septum"] and notes["optic_chiasm"] == listed["optic_chiasm"]
    assert notes["face"] == ("", False)
    html = write_viewer(tmp_path / "v.html", data).read_text()
    hint = re.search(r'<div id="hint"[^>]*>(.*?)</div>', html).group(1)
    for word in ("drag", "rotate", "pan", "zoom", "hover"):
        assert word in hint
    assert "function hover(" in html and 'id="tip"' in html
    embedded = json.loads(re.search(r'<script id="data" type="application/json">(.*?)</script>', html,
                                    re.S).group(1))
    assert {o["name"]: o["warn"] for o in embedded["obstacles"]}["nasal_septum"] is True


def test_the_nearest_structure_and_those_below_their_margin_are_marked_with_their_clearance():
    """plan.png names the nearest structure and every one below its margin where they are (from the
    robot's point to the structure's); a failed search names its two worst blockers with counts."""
    from ctrplan.planning.failure import Blocker, FailureAnalysis, Rejected
    from ctrplan.viz.plan_outputs import figure_marks

    def row(name, clearance, required, below):
        return {"name": name, "clearance_mm": clearance, "required_mm": required, "below_margin": below,
                "state": 3, "arc_length_mm": 10.0, "robot_point_mm": [0.0, 0.0, clearance],
                "structure_point_mm": [0.0, 0.0, 0.0]}

    doc = {"validated": {"structures": [row("septum", 0.43, 0.2, False), row("carotid", 1.5, 2.2, True),
                                        row("chiasm", 0.9, 1.7, True), row("floor", 6.0, 0.2, False),
                                        row("face", None, 0.2, False)]}}
    marks = figure_marks(doc, None)
    assert [m.structure for m in marks] == ["septum", "chiasm", "carotid"]
    assert marks[0].text == "septum: 0.43 mm (need 0.2)" and not marks[0].warn
    assert marks[1].warn and marks[2].warn
    for m in marks:  # the line drawn is the clearance
        shown = float(m.text.split(": ")[1].split()[0])
        assert np.linalg.norm(m.point - m.structure_point) == pytest.approx(shown)
    failure = FailureAnalysis(Rejected(20, 20, collision=20), Rejected(4, 4, collision=4),
                              (Blocker("sella", 12, 3), Blocker("face", 5, 0), Blocker("septum", 1, 0)))
    marks = figure_marks({"validated": None}, failure)
    assert [(m.structure, m.text, m.point, m.warn) for m in marks] == [
        ("sella", "sella: blocks 12 goal candidates and 3 path attempts", None, True),
        ("face", "face: blocks 5 goal candidates", None, True)]
