"""Display meshes (`ctrplan.viz.display_mesh`): a fine sphere comes down to the triangle budget and
stays on its radius (closed form), a small mesh stored with three vertices per triangle (as an STL
reads) is drawn as it is with its vertices shared."""

from __future__ import annotations

import numpy as np
import trimesh

from ctrplan.scene.objects import Obstacle
from ctrplan.viz.display_mesh import display_mesh

RADIUS_MM = 10.0


def test_a_fine_sphere_is_decimated_to_the_budget_and_keeps_its_radius():
    fine = trimesh.creation.icosphere(subdivisions=5, radius=RADIUS_MM)  # 20,480 triangles
    o = Obstacle("ball", "mesh", vertices=np.asarray(fine.vertices), faces=np.asarray(fine.faces))
    vertices, faces = display_mesh(o, 2000)
    assert 1500 <= len(faces) <= 2000
    r = np.linalg.norm(vertices, axis=1)
    # quadric decimation keeps the vertices near the surface: within 0.1 mm of 10 mm (a chord of the
    # coarse sphere's triangles lies inside it by r (1 - cos(edge / 2r)), ~0.05 mm at 2,000 triangles)
    assert np.all(np.abs(r - RADIUS_MM) < 0.1)
    used = np.unique(faces)
    assert used.min() >= 0 and used.max() < len(vertices)
    area = trimesh.Trimesh(vertices, faces).area
    assert abs(area - 4 * np.pi * RADIUS_MM**2) < 0.02 * 4 * np.pi * RADIUS_MM**2


def test_a_small_mesh_with_a_vertex_per_corner_is_drawn_whole_with_shared_vertices():
    box = trimesh.creation.box(extents=(2.0, 3.0, 4.0))
    corners = np.asarray(box.vertices)[np.asarray(box.faces)].reshape(-1, 3)  # 36 vertices, as an STL
    o = Obstacle("box", "mesh", vertices=corners, faces=np.arange(36).reshape(12, 3))
    vertices, faces = display_mesh(o)
    assert len(faces) == 12 and len(vertices) == 8
    drawn = {tuple(sorted(map(tuple, np.round(vertices[f], 9)))) for f in faces}
    given = {tuple(sorted(map(tuple, np.round(corners[3 * k:3 * k + 3], 9)))) for k in range(12)}
    assert drawn == given
