"""Meshes for looking at, not for checking: a structure's surface with shared vertices, decimated to a
triangle budget, for what draws the anatomy (the `ctrplan serve` page and plan.html).

Collision checking, clearances and the page's click-to-place keep the full meshes; only what is drawn
is coarser. A surface from a label volume keeps up to 20,000 triangles (`ctrplan.scene.segmentation`)
and arrives with three vertices of its own per triangle (STL); drawn, it is merged (shared vertices)
and, above `DISPLAY_FACES` triangles, decimated by quadric error (fast_simplification, through
trimesh) -- a smooth organ keeps its shape to a fraction of a millimetre. The budget is what a
browser drawing in software affords: the 16 structures of a skull base from labels (220,000
triangles) took 200 ms a frame at 4,000 a structure and 130-150 ms at 2,000 (1,000: 120-130 ms;
the anatomy hidden: 50 ms; headless Chromium, SwiftShader, 1024 x 640, this 2-core machine at load
8-10), and plan.html shrank from 12.4 MB to about 1 MB. Primitives (spheres, boxes, cylinders,
capsules) and small meshes are under the budget and drawn as they are.
"""

from __future__ import annotations

import numpy as np

from ctrplan.scene.objects import Obstacle

#: Triangles at most per drawn structure.
DISPLAY_FACES = 2000


def display_mesh(obstacle: Obstacle, max_faces: int = DISPLAY_FACES) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) float64 (mm, scene frame) and faces (F, 3) int64 of ``obstacle``'s surface to
    draw: vertices shared, at most ``max_faces`` triangles (quadric decimation above it; a mesh the
    decimation cannot bring under the budget is thinned to every k-th face instead)."""
    import trimesh

    m = obstacle.to_trimesh()
    m = trimesh.Trimesh(np.asarray(m.vertices, dtype=float), np.asarray(m.faces, dtype=np.int64),
                        process=True)  # merges the duplicated vertices of an STL
    if len(m.faces) > max_faces:
        m = m.simplify_quadric_decimation(face_count=max_faces)
    faces = np.asarray(m.faces, dtype=np.int64)
    if len(faces) > max_faces:
        faces = faces[:: int(np.ceil(len(faces) / max_faces))]
    return np.asarray(m.vertices, dtype=float), faces
