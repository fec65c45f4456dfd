"""What the `ctrplan serve` page draws and writes for an answer, computed apart from viser: line
segments of a backbone and of the tip path coloured by clearance (plan.html's colour scale), the
first camera, and the result panel's text.

The colour along the path is the collision world's distance-grid bound of each state's clearance (a
lower bound, computed in one compiled call; exact to the grid's resolution, a few tenths of a mm);
the numbers in the panel are the exact model's distances to each structure (`structure_clearances`).
"""

from __future__ import annotations

import numpy as np

from ctrplan.collision.world import CollisionWorld
from ctrplan.viz.style import CLEARANCE_CAP_MM, CLEARANCE_STOPS

#: Structures listed in the result panel (the nearest ones; all below their margin in any case).
LISTED = 5


def hex_rgb(colour: str) -> tuple[int, int, int]:
    return tuple(int(colour[i:i + 2], 16) for i in (1, 3, 5))


def clearance_rgb(clearance_mm: np.ndarray) -> np.ndarray:
    """RGB (..., 3) uint8 of clearances (mm) on plan.html's scale (red at contact to green at
    `CLEARANCE_CAP_MM` and beyond)."""
    f = np.clip(np.nan_to_num(np.asarray(clearance_mm, dtype=float), nan=0.0) / CLEARANCE_CAP_MM, 0.0, 1.0)
    stops = np.array([s for s, _ in CLEARANCE_STOPS])
    colours = np.array([hex_rgb(c) for _, c in CLEARANCE_STOPS], dtype=float)
    return np.stack([np.interp(f, stops, colours[:, k]) for k in range(3)], axis=-1).round().astype(np.uint8)


def state_clearances(world: CollisionWorld, backbones_scene: np.ndarray, radius_mm: np.ndarray,
                     margin_mm: float = 0.0) -> np.ndarray:
    """Per state (K,) and per capsule (K, N-1): a lower bound of the distance (mm) from the robot's
    surface to the nearest structure less its margin, from the world's distance grid (capped at the
    grid's band; 0 in contact)."""
    pts = np.asarray(backbones_scene, dtype=float)
    r = np.maximum(radius_mm[:, 1:], radius_mm[:, :-1]) + margin_mm
    if world.grid is None:
        per = np.full(r.shape, CLEARANCE_CAP_MM)
    else:
        per = np.maximum(world.grid.segment_lower_bounds(pts) - r, 0.0)
    per = np.where(np.isfinite(per), per, 0.0)
    return per.min(axis=1), per


def segments(points: np.ndarray) -> np.ndarray:
    """Line segments (N-1, 2, 3) of a polyline (N, 3)."""
    p = np.asarray(points, dtype=float)
    return np.stack([p[:-1], p[1:]], axis=1)


def segment_colours(rgb: np.ndarray) -> np.ndarray:
    """Per-segment colours (M, 3) as viser's per-point colours (M, 2, 3)."""
    return np.repeat(np.asarray(rgb, dtype=np.uint8)[:, None, :], 2, axis=1)


def first_camera(start_tip: np.ndarray, target: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera position and look-at point (mm): across the corridor from the start's tip to the
    target, a little from above and from the front, far enough to see both (and at least 100 mm
    away)."""
    d = target - start_tip
    length = max(float(np.linalg.norm(d)), 1e-9)
    d = d / length
    side = np.cross(d, up)
    side = side / (np.linalg.norm(side) or 1.0)
    look = start_tip + 0.6 * (target - start_tip)
    distance = max(100.0, 1.15 * length)
    view = 0.85 * side + 0.35 * up - 0.4 * d
    return look + distance * view / np.linalg.norm(view), look


def result_markdown(doc: dict, planner: str, moved: dict[str, np.ndarray] | None = None) -> str:
    """The result panel: plan number, verdict, times, the exact check, the path, the structures that
    moved (name -> shift from the scene file, mm) and the nearest structures."""
    t = doc["target_mm"]
    lines = [f"**plan #{doc['number']}** ({planner}) &middot; target ({t[0]:.1f}, {t[1]:.1f}, {t[2]:.1f}) "
             f"mm, tolerance {doc['tolerance_mm']:g} mm", ""]
    verdict = "solved" if doc["solved"] else "no path"
    lines.append(f"**{verdict}** &middot; query {1e3 * doc['query_time_s']:.1f} ms, exact validation "
                 f"{1e3 * doc['validation_time_s']:.0f} ms")
    v = doc.get("validated")
    if not doc["solved"]:
        lines += ["", f"why: {doc['message']}"]
    if v is not None:
        tip = v["tip_mm"]
        lines += ["", f"exact model: {'collision-free' if v['collision_free'] else 'COLLIDES'}, tip "
                      f"{'in' if v['tip_in_target'] else 'OUTSIDE'} the target, {v['states']} states checked",
                  "", f"path: {len(doc['path'])} waypoints, exact tip at ({tip[0]:.2f}, {tip[1]:.2f}, "
                      f"{tip[2]:.2f}) mm"]
    shifted = [f"{name} by ({t[0]:.1f}, {t[1]:.1f}, {t[2]:.1f}) mm" for name, t in (moved or {}).items()
               if np.any(t != 0)]
    if shifted:
        lines += ["", "tissue moved: " + ", ".join(shifted)]
    listed = [c for i, c in enumerate(doc.get("structures", [])) if i < LISTED or c["below_margin"]]
    if doc["solved"] and not listed:
        lines += ["", "*measuring the clearance to each structure ...*"]
    if listed:
        lines += ["", "| nearest structures | clearance | needs |", "|---|---|---|"]
        for c in listed:
            clear = "-" if c["clearance_mm"] is None else f"{c['clearance_mm']:.2f} mm"
            flag = " **below**" if c["below_margin"] else ""
            lines.append(f"| {c['name']} | {clear}{flag} | {c['required_mm']:g} mm |")
    return "\n".join(lines)


def legend_html(names_colours: list[tuple[str, str]], target_colour: str) -> str:
    """The structures' names in their colours (as plan.html's legend), and the target's."""
    items = [f'<div><span style="display:inline-block;width:10px;height:10px;margin-right:6px;'
             f'background:{c};border:1px solid #0003"></span>{n}</div>' for n, c in names_colours]
    items.append(f'<div><span style="display:inline-block;width:10px;height:10px;margin-right:6px;'
                 f'background:{target_colour};border:1px solid #0003"></span><b>target</b></div>')
    return '<div style="font-size:12px;line-height:1.4">' + "".join(items) + "</div>"


def ray_hit(vertices: np.ndarray, faces: np.ndarray, origin: np.ndarray, direction: np.ndarray
            ) -> np.ndarray | None:
    """The first point (3,) where the ray hits the triangles, or None (Moeller-Trumbore, vectorised)."""
    v0, v1, v2 = (vertices[faces[:, k]] for k in range(3))
    e1, e2 = v1 - v0, v2 - v0
    d = np.asarray(direction, dtype=float) / max(float(np.linalg.norm(direction)), 1e-300)
    p = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, p)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = origin - v0
    u = np.einsum("ij,ij->i", s, p) * inv
    qv = np.cross(s, e1)
    w = (qv @ d) * inv
    t = np.einsum("ij,ij->i", e2, qv) * inv
    hit = ok & (u >= 0) & (w >= 0) & (u + w <= 1) & (t > 0)
    if not hit.any():
        return None
    return origin + float(np.min(t[hit])) * d


def screen_point(position: np.ndarray, look_at: np.ndarray, fov_rad: float, width: int, height: int,
                 p: np.ndarray) -> tuple[float, float]:
    """Pixel (x right, y down) of scene point ``p`` (mm) in a ``width`` x ``height`` view from a
    perspective camera at ``position`` looking at ``look_at`` with vertical field of view ``fov_rad``
    and +y up (the page's camera: for tests and benchmarks that drive the page)."""
    pos = np.asarray(position, dtype=float)
    fw = np.asarray(look_at, dtype=float) - pos
    fw /= np.linalg.norm(fw)
    rt = np.cross(fw, [0.0, 1.0, 0.0])
    rt /= np.linalg.norm(rt)
    up = np.cross(rt, fw)
    v = np.asarray(p, dtype=float) - pos
    z, t = float(v @ fw), float(np.tan(fov_rad / 2))
    x = (1 + float(v @ rt) / (z * t * width / height)) / 2 * width
    return x, (1 - float(v @ up) / (z * t)) / 2 * height


def drag_arrow(page, camera, size: tuple[int, int], centre: np.ndarray, arrow_mm: np.ndarray, start: float,
               end: float, pause_ms: int = 25) -> None:
    """Drag the page's gizmo arrow ``arrow_mm`` (3,) (its axis times its length, mm) at ``centre``
    from ``start`` to ``end`` of its length, in ten steps: ``page`` is a Playwright page of the app,
    ``camera`` a viser camera handle of its client (for the tests and benchmarks that drive the page)."""
    x0, y0 = screen_point(camera.position, camera.look_at, camera.fov, *size, centre + start * arrow_mm)
    x1, y1 = screen_point(camera.position, camera.look_at, camera.fov, *size, centre + end * arrow_mm)
    page.mouse.move(x0 - 4, y0)  # onto the arrow from beside it: it lights up, then takes the press
    page.mouse.move(x0, y0)
    page.mouse.down()
    for k in range(1, 11):
        page.mouse.move(x0 + (x1 - x0) * k / 10, y0 + (y1 - y0) * k / 10)
        page.wait_for_timeout(pause_ms)
    page.mouse.up()
