"""plan.png's curved sections (`ctrplan.viz.sections`) against closed forms: the inside of a closed
mesh cut by a plane is its cross-section (area and extent), the cutting surface follows the path in
the hidden axis, an open sheet is outlined and never filled."""

from __future__ import annotations

import math

import numpy as np
import trimesh

from ctrplan.viz.sections import SECTION_STEP_MM, curved_section, guide_heights


def triangles(mesh: trimesh.Trimesh) -> np.ndarray:
    return np.asarray(mesh.vertices)[np.asarray(mesh.faces)]


def straight_guide(x: float) -> np.ndarray:
    """A path along z at x, y = 0."""
    return np.column_stack([np.full(50, x), np.zeros(50), np.linspace(0.0, 100.0, 50)])


def fill_area(section) -> float:
    a0, a1, c0, c1 = section.fills.T
    return float(np.sum((a1 - a0) * (c1 - c0)))


def test_a_sphere_cut_off_centre_fills_its_circle():
    """A sphere of radius 10 at z = 50, cut by the plane x = 6 (a path 6 mm beside its centre): the
    inside is a disc of radius 8 (area 64 pi) spanning y in [-8, 8], z in [42, 58]; the outline lies
    on the sphere."""
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=10.0)
    sphere.apply_translation([0.0, 0.0, 50.0])
    cut = curved_section("ball", triangles(sphere), True, straight_guide(6.0), along=2, across=1, hidden=0,
                         depth_range=(0.0, 100.0), step_mm=0.25)
    assert math.isclose(fill_area(cut), 64 * math.pi, rel_tol=0.02)
    assert np.allclose([cut.fills[:, 0].min(), cut.fills[:, 1].max()], [42.0, 58.0], atol=0.3)
    assert np.allclose([cut.fills[:, 2].min(), cut.fills[:, 3].max()], [-8.0, 8.0], atol=0.1)
    ends = cut.segments.reshape(-1, 2)  # (z, y) in the plane x = 6
    radius = np.linalg.norm(np.column_stack([np.full(len(ends), 6.0), ends[:, 1], ends[:, 0] - 50.0]), axis=1)
    assert np.all(np.abs(radius - 10.0) < 0.05)


def test_the_cut_follows_the_path_in_the_hidden_axis():
    """A wall at x in [8, 12] along all of z; the path runs at x = 0 until z = 50 and at x = 10 after:
    only the second half is cut, and there the wall fills y in [-5, 5] (the box's height)."""
    wall = trimesh.creation.box(extents=[4.0, 10.0, 100.0])
    wall.apply_translation([10.0, 0.0, 50.0])
    guide = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 49.0], [10.0, 0.0, 51.0], [10.0, 0.0, 100.0]])
    cut = curved_section("wall", triangles(wall), True, guide, along=2, across=1, hidden=0,
                         depth_range=(0.0, 100.0), step_mm=1.0)
    assert cut.fills[:, 0].min() >= 49.0 and cut.fills[:, 1].max() <= 100.0 + 1e-9
    assert np.allclose(cut.fills[:, 2:], [-5.0, 5.0])
    assert math.isclose(fill_area(cut), 10.0 * (100.0 - 50.0), rel_tol=0.03)
    assert np.allclose(guide_heights(guide, 2, 0, np.array([-5.0, 25.0, 50.0, 200.0])), [0.0, 0.0, 5.0, 10.0])


def test_an_open_sheet_is_outlined_not_filled():
    """A square sheet in the plane y = 3 (not closed): the plane x = 0 cuts it along the line y = 3,
    z in [40, 60]; no inside."""
    sheet = trimesh.Trimesh([[-5, 3, 40], [5, 3, 40], [5, 3, 60], [-5, 3, 60]], [[0, 1, 2], [0, 2, 3]])
    cut = curved_section("sheet", triangles(sheet), sheet.is_watertight, straight_guide(0.0), along=2,
                         across=1, hidden=0, depth_range=(0.0, 100.0))
    assert not sheet.is_watertight and len(cut.fills) == 0
    ends = cut.segments.reshape(-1, 2)
    assert np.allclose(ends[:, 1], 3.0) and math.isclose(ends[:, 0].min(), 40.0) and \
        math.isclose(ends[:, 0].max(), 60.0)
    assert math.isclose(float(np.sum(np.abs(cut.segments[:, 1, 0] - cut.segments[:, 0, 0]))), 20.0)


def test_a_closed_structure_wider_than_the_picture_is_filled_across_it(tmp_path):
    """A slab (closed, finely meshed) 200 mm tall across a straight path: plan.png's projections clip the
    picture, not the mesh, so every filled column of the slab's cut spans its full height."""
    from matplotlib.collections import PolyCollection

    from ctrplan.scene.loader import load_scene
    from ctrplan.viz.plan_plot import plan_figure
    from tests.paths import SCENES

    slab = trimesh.creation.box(extents=[200.0, 200.0, 5.0]).subdivide().subdivide().subdivide()
    slab.apply_translation([0.0, 0.0, 97.5])
    slab.export(tmp_path / "slab.stl")
    text = (SCENES / "open.yaml").read_text()
    text = text.replace(text[text.index("obstacles:"):text.index("target:")],
                        "obstacles:\n- {name: slab, mesh: slab.stl}\n")
    (tmp_path / "s.yaml").write_text(text)
    scene = load_scene(tmp_path / "s.yaml")
    z = np.linspace(0.0, 180.0, 40)
    fig = plan_figure(scene, np.column_stack([np.zeros(40), np.zeros(40), z])[None])
    fills = [p.vertices for ax in fig.axes if ax.name != "3d" for c in ax.collections
             if isinstance(c, PolyCollection) for p in c.get_paths()]
    assert fills
    for v in fills:
        half = 0.5 * SECTION_STEP_MM  # a depth bin is filled when its centre is inside
        assert v[:, 0].min() >= 95.0 - half and v[:, 0].max() <= 100.0 + half
        assert np.isclose(v[:, 1].min(), -100.0) and np.isclose(v[:, 1].max(), 100.0)
