"""What plan.png and plan.html show a surgeon: the target in its own colour, anatomy told apart,
orientation named, the result as labelled lines, the clearance along the backbone, projections that
draw the anatomy cut along the path in the hidden axis; every obstacle named in the figure's legend, and
a scale bar in the viewer."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from matplotlib.colors import to_hex

from ctrplan.base.errors import InputError
from ctrplan.scene.loader import load_scene
from ctrplan.viz import viewer_data, write_viewer
from ctrplan.viz.plan_plot import _outline, plan_figure
from ctrplan.viz.style import TARGET_COLOR, obstacle_colors, scene_colors
from tests.paths import REPO, SCENES

OPEN = (SCENES / "open.yaml").read_text()


def midline_path(scene) -> np.ndarray:
    """Two straight backbones (2, 40, 3) from in front of the face to the target centre, 2.5 mm
    right of the midline like the approach through the right nostril."""
    end = scene.target.center
    start = end + np.array([0.0, -16.0, -100.0])
    line = start + np.linspace(0.0, 1.0, 40)[:, None] * (end - start)
    return np.stack([line, line])


def test_skull_base_anatomy_has_its_own_colours_and_directions(skullbase):
    names = [o.name for o in skullbase.obstacles]
    colours = obstacle_colors(names)
    assert len(set(colours.values())) == len(names)  # every obstacle told apart (septum, chiasm ...)
    assert TARGET_COLOR not in colours.values()
    assert skullbase.anatomy == {"x": "left", "y": "superior", "z": "posterior"}


def test_viewer_marks_target_tip_orientation_clearance_and_result(skullbase, tmp_path):
    bbs = midline_path(skullbase)
    clearance = np.full((2, 39), 1.5)
    info = {"result": "solved", "min clearance": "0.63 mm to optic_chiasm"}
    data = viewer_data(skullbase, bbs, np.full((2, 40), 0.75), info, clearance)
    assert data["target"]["color"] == TARGET_COLOR
    assert data["axes"] == {"x": ("left", "right"), "y": ("superior", "inferior"),
                            "z": ("posterior", "anterior")}
    assert data["info"] == [["result", "solved"], ["min clearance", "0.63 mm to optic_chiasm"]]
    assert np.shape(data["clearance"]) == (2, 39)
    faint = {o["name"] for o in data["obstacles"] if o["alpha"] < 0.1}
    assert faint == {"face"}  # the 220 mm face plate does not dominate the view
    lo, hi = bbs[-1].min(axis=0), bbs[-1].max(axis=0) + 8.0
    assert np.all((np.array(data["view"]["center"]) >= lo - 8.0) & (np.array(data["view"]["center"]) <= hi))
    html = write_viewer(tmp_path / "v.html", data).read_text()
    for drawn in ("function marks(", "function triad(", "function clearanceBar(", "function scaleBar(",
                  "<th>"):
        assert drawn in html


def test_projections_do_not_draw_the_carotids_over_a_midline_path(skullbase):
    """The carotids lie 7-11 mm lateral of the sella: the sagittal section (cut at the path's x) leaves
    them out, the axial one (cut at the path's height) shows them beside the path."""
    fig = plan_figure(skullbase, midline_path(skullbase))
    colours = scene_colors(skullbase.obstacles)
    carotids = {to_hex(_outline(c)) for n, c in colours.items() if "carotid" in n}
    views = {ax.get_title().split(" ")[0]: ax for ax in fig.axes if ax.name != "3d" and ax.get_title()}
    drawn = {v: {to_hex(c.get_edgecolor()[0], keep_alpha=False) for c in ax.collections
                 if len(c.get_paths()) and len(c.get_edgecolor())} for v, ax in views.items()}
    assert not carotids & drawn["sagittal"]
    assert carotids <= drawn["axial"]
    assert views["sagittal"].get_xlabel() == "z (mm): anterior to posterior"
    assert views["sagittal"].get_ylabel() == "y (mm): inferior to superior"


@pytest.mark.parametrize(("anatomy", "fragment"), [
    ("{x: left, y: up, z: posterior}", "anatomy.y: expected one of"),
    ("{x: left, y: right, z: posterior}", "anatomy: each axis needs its own pair"),
    ("{x: left, y: superior}", "missing required key 'z'"),
])
def test_scene_anatomy_errors_name_the_key(tmp_path, anatomy, fragment):
    text = (SCENES / "open.yaml").read_text().replace("target:", f"anatomy: {anatomy}\ntarget:", 1)
    (tmp_path / "s.yaml").write_text(text)
    with pytest.raises(InputError, match=fragment):
        load_scene(tmp_path / "s.yaml")


def test_plan_figure_names_every_obstacle_target_and_tip_trace(tmp_path):
    from ctrplan.scene.loader import load_scene
    from ctrplan.viz.plan_plot import plan_figure, plot_plan

    balls = "".join(f"- name: ball{i:02d}\n  sphere:\n    center: [{-60 + 8 * i}.0, 40.0, 150.0]\n"
                    f"    radius: 2.0\n" for i in range(16))
    text = OPEN.replace(OPEN[OPEN.index("- name: ball"):OPEN.index("target:")], balls)
    (tmp_path / "many.yaml").write_text(text)
    scene = load_scene(tmp_path / "many.yaml")
    z = np.linspace(0, 180, 30)
    bbs = np.stack([np.column_stack([np.zeros(30) + k, np.zeros(30), z]) for k in range(5)])
    fig = plan_figure(scene, bbs, tip_path=bbs[:, -1])
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert labels[:16] == [f"ball{i:02d}" for i in range(16)]
    assert {"target", "tip trace", "start", "end"} <= set(labels)
    ax3 = next(a for a in fig.axes if a.name == "3d")
    for axis in (ax3.xaxis, ax3.yaxis, ax3.zaxis):
        assert len(axis.get_major_locator()()) <= 6
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the old tight_layout call warned on every figure
        plot_plan(scene, bbs, tmp_path / "p.png", tip_path=bbs[:, -1])
    assert (tmp_path / "p.png").stat().st_size > 0


def test_viewer_has_a_scale_bar(tmp_path):
    from ctrplan.scene.loader import load_scene
    from ctrplan.viz import viewer_data, write_viewer

    scene = load_scene(REPO / "scenes" / "open.yaml")
    bbs = np.zeros((2, 5, 3))
    bbs[..., 2] = np.linspace(0, 100, 5)
    html = write_viewer(tmp_path / "v.html", viewer_data(scene, bbs, np.full((2, 5), 0.75))).read_text()
    assert "function scaleBar()" in html and "scaleBar();" in html and '" mm (at the view centre)"' in html


def test_a_failed_plan_shows_the_anatomy_between_its_start_and_the_target(skullbase):
    """A start that ends in the nasal cavity, 50 mm short of the target (a failed plan draws only it):
    the sections follow it, then the line to the target, so the walls on the way are cut in both
    projections; a cut that lies wholly outside the overview's box is left out, not an error."""
    start = np.array([-4.0, 8.0, -99.0]) + np.linspace(0.0, 1.0, 40)[:, None] * np.array([0.0, 17.0, 129.0])
    fig = plan_figure(skullbase, start[None])
    views = [ax for ax in fig.axes if ax.name != "3d" and ax.get_title()]
    for ax in views:
        assert sum(len(c.get_paths()) for c in ax.collections) > 5  # the walls, not just the robot
