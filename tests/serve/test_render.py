"""What the page computes apart from the browser, checked against closed forms: where a click meets a
surface, where a point lands on the screen, the clearance colours."""

from __future__ import annotations

import math

import numpy as np
import trimesh

from ctrplan.serve.render import clearance_rgb, ray_hit, screen_point
from ctrplan.viz.style import CLEARANCE_CAP_MM


def test_a_click_ray_meets_the_nearest_face_of_a_box():
    box = trimesh.creation.box(extents=[4.0, 6.0, 8.0])  # centred: faces at x = +-2, y = +-3, z = +-4
    hit = ray_hit(np.asarray(box.vertices), np.asarray(box.faces), np.array([10.0, 0.5, -1.0]),
                  np.array([-2.0, 0.0, 0.0]))
    np.testing.assert_allclose(hit, [2.0, 0.5, -1.0], atol=1e-12)
    assert ray_hit(np.asarray(box.vertices), np.asarray(box.faces), np.array([10.0, 5.0, 0.0]),
                   np.array([-1.0, 0.0, 0.0])) is None  # passes above the box


def test_screen_points_of_a_perspective_camera():
    """The point looked at lands in the middle; a point off the axis by tan(fov/2) of its depth lands
    on the top edge; +x of a camera looking along -z from +z is to the right."""
    pos, look, fov = np.array([0.0, 0.0, 100.0]), np.zeros(3), math.radians(60.0)
    assert screen_point(pos, look, fov, 800, 600, look) == (400.0, 300.0)
    x, y = screen_point(pos, look, fov, 800, 600, [0.0, 100.0 * math.tan(fov / 2), 0.0])
    assert abs(x - 400.0) < 1e-9 and abs(y) < 1e-9
    assert screen_point(pos, look, fov, 800, 600, [10.0, 0.0, 0.0])[0] > 400.0


def test_clearance_colours_run_from_red_to_green():
    rgb = clearance_rgb(np.array([0.0, CLEARANCE_CAP_MM, 10.0 * CLEARANCE_CAP_MM, np.nan]))
    assert tuple(rgb[0]) == (0xD7, 0x19, 0x1C) and tuple(rgb[1]) == (0x1A, 0x96, 0x41)
    assert tuple(rgb[2]) == tuple(rgb[1]) and tuple(rgb[3]) == tuple(rgb[0])  # capped; NaN as contact
