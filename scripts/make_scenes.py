#!/usr/bin/env python
"""Generate the planning scenes under ``scenes/`` (meshes + YAML). Deterministic; re-run to rebuild.

    python scripts/make_scenes.py            # write scenes/*.yaml and scenes/meshes/**
    python scripts/make_scenes.py --check    # also verify each problem (start valid, the straight
                                             # joint-space line collides, RRTConnect finds a path)

skullbase.yaml -- endonasal, transsphenoidal approach through the right nostril. Scene frame: origin at
the anterior nasal spine, x towards the patient's left, y superior, z posterior (depth), mm. The airway
is one lofted tunnel from the nostril to the pituitary fossa, split into named anatomical surfaces
(the robot is inside it, so every wall counts). Dimensions (docs/design.md §4; where the planning corridor is
wider than the resting anatomy the reason is given):

- nostril/vestibule, then the nasal valve at z = 9..14: a slit 30 mm tall and 6 mm wide (resting
  valve 0.54 +- 0.13 cm^2 and a few mm wide; 6 mm is the valve held open by a nasal speculum, as in
  microscopic transsphenoidal surgery);
- nasal cavity z = 14..46: 44 mm tall between the septum (x = -1) and the lateral wall, 10 mm wide at
  the meatus levels; the inferior and middle turbinates bulge to leave a 6 mm common meatus
  (turbinates lateralised; deeper cross-sections in the model ~3 cm^2 vs 1.0-1.4 cm^2 at rest);
- posterior septectomy z = 46..62 (both sides join), sphenoid opening 16 x 14 mm at z = 62 (anterior
  sphenoid wall 62 mm behind the nasal spine; opening ~15 mm), sphenoid sinus 13.6 mm deep;
- sellar wall at z = 75.6 with a 10 x 7 mm opening (sella ~10 x 6 mm; anterior sellar wall 76 mm),
  pituitary fossa behind it; the target is the right half of the pituitary (the gland is 12 W x 9 AP
  x 6 H mm);
- internal carotid arteries (5 mm diameter) bulging into the sinus with a 16 mm gap (13-22 mm), optic
  chiasm and nerves above the sella.

The robot base (front plate) sits ~105 mm in front of the face in the sagittal plane of the right
airway, placed by `fit_base_pose` so that a planar configuration threads the airway with the tip in
the target. The start is retracted with the tip in the nasal cavity and the innermost tube's curved
end pointing up; reaching the sella needs that tube turned by half a turn, which the nasal slit does
not allow: the straight joint-space line collides, the planner must turn it in the sphenoid sinus.
The resting-anatomy variant (``STRICT``: 5 mm valve and meatus, 15 x 13 mm sphenoid opening, 10 x 6 mm
sella, carotids 15 mm apart) is written as skullbase_strict.yaml: a harder benchmark (RRTConnect with
the PINN solved 15 of 20 seeds within 10 s when it was generated, against 20 of 20 on skullbase).

skullbase_approach.yaml -- skullbase with an approach direction: the tip must reach the target within
20 deg of the sellar wall's normal (+z, posterior), as a surgeon would approach the sella (``APPROACH``;
the goal configurations of skullbase point 18-24 deg below it, so about half of them qualify).

skullbase_design.yaml -- the design task of `ctrplan design` on skullbase.yaml: six targets of
transsphenoidal surgery (both halves of the pituitary, the tuberculum sellae, the clivus, both medial
cavernous-sinus walls), each placed in the free space from the anatomy above and given its clinical
reason; the nominal robot as the base design, its curvatures and innermost curved length varied, tube
sizes from a stock catalogue (``design_task``).

open.yaml -- open workspace with one sphere and one box between the retracted start and the target.
pipe.yaml -- a curved pipe (12 mm bore, 70 mm long) the robot has to thread to a target at its closed end.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
import trimesh

from ctrplan.base.yamlio import dump_yaml

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "scenes"
MESHES = SCENES / "meshes"

# ---- cross-sections ---------------------------------------------------------------------------------
# Every cross-section has the same four sides (so consecutive ones loft without twisting):
# floor (medial -> lateral), lateral wall (bottom -> top), roof (lateral -> medial),
# medial wall (top -> bottom). The right nasal cavity is at x < 0, so "medial" is +x.
N_SIDE = {"floor": 6, "lateral": 18, "roof": 6, "medial": 18}
SIDES = ("floor", "lateral", "roof", "medial")
K = sum(N_SIDE.values())


def _side_index() -> np.ndarray:
    out = []
    for i, s in enumerate(SIDES):
        out += [i] * N_SIDE[s]
    return np.array(out)


SIDE_OF_VERTEX = _side_index()


def superellipse_section(cx: float, cy: float, a: float, b: float, n: float = 2.0) -> np.ndarray:
    """(K, 2) points of a superellipse, sides mapped to angle quadrants (clockwise from the
    medial-bottom corner at -45 deg)."""
    pts = []
    starts = {"floor": -0.25 * math.pi, "lateral": -0.75 * math.pi, "roof": -1.25 * math.pi,
              "medial": -1.75 * math.pi}
    for s in SIDES:
        m = N_SIDE[s]
        th = starts[s] - 0.5 * math.pi * np.arange(m) / m
        c, si = np.cos(th), np.sin(th)
        x = cx + a * np.sign(c) * np.abs(c) ** (2.0 / n)
        y = cy + b * np.sign(si) * np.abs(si) ** (2.0 / n)
        pts.append(np.stack([x, y], 1))
    return np.concatenate(pts)


def cavity_section(x_medial: float, y0: float, y1: float, width, ) -> np.ndarray:
    """(K, 2) nasal-cavity section: medial wall at x_medial, lateral wall at x_medial - width(y)."""
    pts = []
    # floor: medial -> lateral
    m = N_SIDE["floor"]
    xl0 = x_medial - width(y0)
    for t in np.arange(m) / m:
        pts.append((x_medial + t * (xl0 - x_medial), y0))
    m = N_SIDE["lateral"]
    for t in np.arange(m) / m:
        y = y0 + t * (y1 - y0)
        pts.append((x_medial - width(y), y))
    m = N_SIDE["roof"]
    xl1 = x_medial - width(y1)
    for t in np.arange(m) / m:
        pts.append((xl1 + t * (x_medial - xl1), y1))
    m = N_SIDE["medial"]
    for t in np.arange(m) / m:
        pts.append((x_medial, y1 + t * (y0 - y1)))
    return np.array(pts, dtype=float)


def _bump(y, centre, sigma, depth):
    return depth * np.exp(-(((y - centre) / sigma) ** 2))


#: Sphenoid sinus (z = 62 .. SELLAR_WALL_Z - 0.1): superellipse centred at y = SINUS_Y, half-width 15,
#: half-height SINUS_HALF_HEIGHT; the sellar wall at SELLAR_WALL_Z; the pituitary fossa behind it,
#: centred at y = FOSSA_Y, half-width FOSSA_HALF_WIDTH, half-height 4.2, back wall at FOSSA_END_Z (mm).
SINUS_Y, SINUS_HALF_HEIGHT = 18.0, 13.0
SELLAR_WALL_Z = 75.6
FOSSA_Y, FOSSA_HALF_WIDTH, FOSSA_END_Z = 22.0, 7.0, 85.5


def skullbase_stations(p: dict) -> list[tuple[float, np.ndarray, str]]:
    """Stations (z, section (K, 2), label) from the nostril to the back of the pituitary fossa.

    The right airway lies lateral of the septum (medial wall at x = -1); the vestibule and the
    posterior cavity are centred on the approach line x = p["corridor_x"].
    """
    w_meatus, w_turb = p["cavity_width"], p["meatus_width"]
    depth = w_meatus - w_turb
    xc = p["corridor_x"]

    def width(y):
        return w_meatus - _bump(y, 9.0, 3.5, depth) - _bump(y, 24.0, 3.0, depth)

    # the label of a station names the surface between the previous station and this one
    vw = p["valve_width"]
    st = [
        (0.0, superellipse_section(xc, 9.0, 5.0, 7.0, 2.2), "vestibule"),
        (6.0, superellipse_section(-1.0 - vw / 2, 13.0, vw / 2, 11.0, 2.5), "vestibule"),
        (9.0, superellipse_section(-1.0 - vw / 2, 17.0, vw / 2, 15.0, 3.0), "valve"),
        (14.0, superellipse_section(-1.0 - vw / 2, 17.0, vw / 2, 15.0, 3.0), "valve"),
    ]
    for z in np.arange(18.0, p["septum_end"] + 0.1, 4.0):
        st.append((float(z), cavity_section(-1.0, 0.0, 44.0, width), "cavity"))
    sw, sh = p["sphenoid_width"], p["sphenoid_height"]
    st += [
        (56.0, superellipse_section(0.0, 18.0, p["posterior_width"] / 2, p["posterior_height"] / 2, 3.0),
         "septectomy"),
        (61.9, superellipse_section(0.0, 18.0, sw / 2, sh / 2, 3.0), "septectomy"),
        (62.0, superellipse_section(0.0, SINUS_Y, 15.0, SINUS_HALF_HEIGHT, 4.0), "sphenoid_face"),
        (SELLAR_WALL_Z - 0.1, superellipse_section(0.0, SINUS_Y, 15.0, SINUS_HALF_HEIGHT, 4.0), "sinus"),
        (SELLAR_WALL_Z, superellipse_section(0.0, FOSSA_Y, p["sella_width"] / 2, p["sella_height"] / 2, 3.0),
         "sellar_wall"),
        (SELLAR_WALL_Z + 1.0, superellipse_section(0.0, FOSSA_Y, FOSSA_HALF_WIDTH, 4.2, 2.5), "fossa"),
        (FOSSA_END_Z, superellipse_section(0.0, FOSSA_Y, FOSSA_HALF_WIDTH, 4.2, 2.5), "fossa"),
    ]
    return st


def _part_name(segment: str, side: str, y_mid: float) -> str:
    if segment in ("vestibule", "valve"):
        return "nasal_vestibule_and_valve"
    if segment == "cavity":
        if side == "medial":
            return "nasal_septum"
        if side == "floor":
            return "nasal_floor"
        if side == "roof":
            return "nasal_roof"
        if 3.0 <= y_mid <= 15.0:
            return "inferior_turbinate"
        if 19.0 <= y_mid <= 29.0:
            return "middle_turbinate"
        return "lateral_nasal_wall"
    if segment == "septectomy":
        return "posterior_nasal_cavity"
    if segment == "sphenoid_face":
        return "sphenoid_face"
    if segment == "sinus":
        return "sphenoid_sinus"
    if segment == "sellar_wall":
        return "sellar_wall"
    return "sella_turcica"


def loft_tunnel(stations, face_half: float = 110.0) -> dict[str, trimesh.Trimesh]:
    """The airway surface as named meshes: the face (an annulus around the nostril), the lofted
    tunnel, and the cap behind the fossa (dorsum sellae)."""
    z0, s0, _ = stations[0]
    outer = superellipse_section(float(s0[:, 0].mean()), float(s0[:, 1].mean()), face_half, face_half, 12.0)
    rings = [np.column_stack([outer, np.full(K, z0)])]
    rings += [np.column_stack([sec, np.full(K, z)]) for z, sec, _ in stations]
    segs = ["face"] + [lab for _, _, lab in stations[1:]]
    V = np.concatenate(rings)
    faces: dict[str, list] = {}
    for j in range(len(rings) - 1):
        a, b = j * K, (j + 1) * K
        for k in range(K):
            k2 = (k + 1) % K
            tri = [[a + k, b + k2, a + k2], [a + k, b + k, b + k2]]
            if segs[j] == "face":
                name = "face"
            else:
                side = SIDES[SIDE_OF_VERTEX[k]]
                y_mid = 0.25 * (V[a + k, 1] + V[a + k2, 1] + V[b + k, 1] + V[b + k2, 1])
                name = _part_name(segs[j], side, y_mid)
            faces.setdefault(name, []).extend(tri)
    # cap (back wall of the fossa)
    c = len(V)
    V = np.vstack([V, np.append(stations[-1][1].mean(axis=0), stations[-1][0])])
    b = (len(rings) - 1) * K
    faces.setdefault("sella_turcica", []).extend([[b + k, b + (k + 1) % K, c] for k in range(K)])
    out = {}
    for name, f in faces.items():
        m = trimesh.Trimesh(V, np.array(f), process=False)
        m.remove_unreferenced_vertices()
        out[name] = m
    return out


def tube_along(points: np.ndarray, radius: float, sections: int = 16) -> trimesh.Trimesh:
    """A closed tube of ``radius`` swept along a polyline (M, 3)."""
    pts = np.asarray(points, dtype=float)
    t = np.gradient(pts, axis=0)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    ref = np.array([1.0, 0.0, 0.0]) if abs(t[0, 0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    n = np.cross(t[0], ref)
    n /= np.linalg.norm(n)
    verts = []
    for i in range(len(pts)):  # parallel transport of the normal
        n = n - np.dot(n, t[i]) * t[i]
        n /= np.linalg.norm(n)
        bvec = np.cross(t[i], n)
        ang = 2 * np.pi * np.arange(sections) / sections
        ring = pts[i] + radius * (np.cos(ang)[:, None] * n + np.sin(ang)[:, None] * bvec)
        verts.append(ring)
    V = np.concatenate(verts + [pts[:1], pts[-1:]])
    F = []
    for i in range(len(pts) - 1):
        a, b = i * sections, (i + 1) * sections
        for k in range(sections):
            k2 = (k + 1) % sections
            F += [[a + k, a + k2, b + k2], [a + k, b + k2, b + k]]
    c0, c1 = len(V) - 2, len(V) - 1
    last = (len(pts) - 1) * sections
    F += [[c0, (k + 1) % sections, k] for k in range(sections)]
    F += [[c1, last + k, last + (k + 1) % sections] for k in range(sections)]
    return trimesh.Trimesh(V, np.array(F), process=False)


def smooth_curve(ctrl: np.ndarray, n: int = 24) -> np.ndarray:
    """Catmull-Rom through control points (M, 3) -> (≈n*(M-1), 3)."""
    P = np.vstack([ctrl[0], ctrl, ctrl[-1]])
    out = []
    for i in range(1, len(P) - 2):
        p0, p1, p2, p3 = P[i - 1], P[i], P[i + 1], P[i + 2]
        for t in np.linspace(0, 1, n, endpoint=False):
            t2, t3 = t * t, t * t * t
            out.append(0.5 * ((2 * p1) + (-p0 + p2) * t + (2 * p0 - 5 * p1 + 4 * p2 - p3) * t2
                              + (-p0 + 3 * p1 - 3 * p2 + p3) * t3))
    out.append(ctrl[-1])
    return np.array(out)


def carotid(side: float, half_gap: float) -> trimesh.Trimesh:
    """Internal carotid artery (5 mm diameter): paraclival segment rising behind the sinus, anterior
    genu bulging into the sinus' lateral wall, then up and back (siphon)."""
    r = 2.5
    x = side * (half_gap + r)
    ctrl = np.array([[x, -6.0, 82.0], [x, 8.0, 79.0], [x, 16.0, 74.0], [x, 24.0, 71.0], [x, 31.0, 75.0],
                     [x * 0.9, 34.0, 82.0]])
    return tube_along(smooth_curve(ctrl, 6), r, 12)


def optic_apparatus() -> trimesh.Trimesh:
    """Optic chiasm (flattened ellipsoid above the sella) and both optic nerves towards the canals."""
    ch = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    ch.apply_scale([7.0, 1.8, 4.0])
    ch.apply_translation([0.0, 31.5, 81.0])
    parts = [ch]
    for s in (-1.0, 1.0):
        ctrl = np.array([[s * 4.0, 31.5, 79.0], [s * 8.0, 31.8, 72.0], [s * 11.0, 32.0, 64.0]])
        parts.append(tube_along(smooth_curve(ctrl, 8), 1.6, 12))
    return trimesh.util.concatenate(parts)


#: Planning corridor of skullbase.yaml (see the module docstring), mm.
SKULLBASE = {"valve_width": 6.0, "cavity_width": 10.0, "meatus_width": 6.0, "sphenoid_width": 16.0,
             "sphenoid_height": 14.0, "posterior_width": 24.0, "posterior_height": 24.0,
             "sella_width": 10.0, "sella_height": 7.0, "corridor_x": -4.0, "septum_end": 46.0,
             "ica_gap": 16.0}
#: Resting-anatomy widths (skullbase_strict.yaml): narrower valve and meatus, 15 mm sphenoid opening,
#: 10 x 6 mm sella, 15 mm between the carotids.
STRICT = {**SKULLBASE, "valve_width": 5.0, "cavity_width": 9.0, "meatus_width": 5.0,
          "sphenoid_width": 15.0, "sphenoid_height": 13.0, "posterior_width": 22.0,
          "sella_width": 10.0, "sella_height": 6.0, "corridor_x": -3.5, "ica_gap": 15.0}
#: Pituitary (gland centre) and the target region: an ellipsoid in its right half.
PITUITARY = np.array([0.0, 22.0, 81.0])
TARGET = {"center": [-2.5, 22.0, 81.0], "semi_axes_mm": [3.5, 2.5, 3.5]}
AIM = np.array([-3.0, 22.0, 81.0])  # where the fitted configuration puts the tip
VALVE_Z = 11.0


#: Approach to the sella (skullbase_approach.yaml): within 20 deg of the sellar wall's normal.
APPROACH = {"direction": [0.0, 0.0, 1.0], "angle_tolerance_deg": 20.0}


def approach_variant(scene: dict) -> dict:
    """skullbase with the approach direction `APPROACH` on its target (same meshes)."""
    return {**scene, "name": "skullbase_approach",
            "description": scene["description"] + " The tip must approach the sella within "
                           f"{APPROACH['angle_tolerance_deg']:g} deg of the sellar wall's normal.",
            "target": {**scene["target"], **APPROACH}}


#: Stock nitinol tube sizes of the design task (inner/outer diameter, mm): the three of the paper's
#: robot and three in between or beyond.
CATALOGUE = ((0.40, 0.50), (0.55, 0.70), (0.70, 0.90), (0.95, 1.20), (1.20, 1.50), (1.55, 1.90))


def design_task(p: dict) -> dict:
    """skullbase_design.yaml: which tube set reaches the targets of transsphenoidal surgery through
    skullbase.yaml. Every target lies in the free space of the scene, placed from its anatomy."""
    sella_top = FOSSA_Y + p["sella_height"] / 2  # upper edge of the sellar opening
    in_front = SELLAR_WALL_Z - 2.0  # 2 mm in front of the sellar wall, in the sinus
    wall_x = FOSSA_HALF_WIDTH - 1.5  # 1.5 mm inside the fossa's side walls
    mirror = [-TARGET["center"][0], *TARGET["center"][1:]]
    wall_z = float(PITUITARY[2]) - 0.5
    targets = [
        {"name": "pituitary_right", "ellipsoid": dict(TARGET),
         "reason": "right half of the gland, on the side of the approach nostril: a microadenoma seen there "
                   "is resected here"},
        {"name": "pituitary_left", "ellipsoid": {**TARGET, "center": mirror},
         "reason": "left half of the gland: a contralateral microadenoma; the tip must cross the midline "
                   "behind the 10 mm sellar opening"},
        {"name": "tuberculum_sellae", "point": [0.0, sella_top + 2.5, in_front], "tolerance_mm": 1.5,
         "reason": "the bony ridge above the sella, opened in the extended approach to suprasellar "
                   "tumours (tuberculum sellae meningioma), just below the optic chiasm"},
        {"name": "clivus", "point": [0.0, SINUS_Y - SINUS_HALF_HEIGHT + 4.0, in_front], "tolerance_mm": 2.0,
         "reason": "clival recess of the posterior sinus wall below the sella: biopsy of a clival chordoma "
                   "or chondrosarcoma"},
        {"name": "cavernous_wall_right", "point": [-wall_x, FOSSA_Y, wall_z], "tolerance_mm": 1.5,
         "reason": "right medial wall of the cavernous sinus (the fossa's side wall, the carotid beyond "
                   "it): functioning adenomas invade it, and resecting it raises remission"},
        {"name": "cavernous_wall_left", "point": [wall_x, FOSSA_Y, wall_z], "tolerance_mm": 1.5,
         "reason": "left medial wall of the cavernous sinus, contralateral to the approach: the tip must "
                   "bend across the fossa"},
    ]
    return {
        "scene": "skullbase.yaml",
        "targets": targets,
        "robot": "nominal",
        "vary": {1: {"curvature_1_per_m": [0.0, 80.0], "curved_length_mm": [20.0, 90.0]},
                 2: {"curvature_1_per_m": [0.0, 30.0]},
                 3: {"curvature_1_per_m": [0.0, 15.0]}},
        "catalogue": [{"inner_diameter_mm": i, "outer_diameter_mm": o} for i, o in CATALOGUE],
        "constraints": {"max_strain": 0.06, "snap_free": True},
        "objectives": ["targets_reached", "min_clearance_mm", "-max_strain"],
        "budget": {"trials": 200, "plan_time_s": 8.0},
    }


def write_mesh(mesh: trimesh.Trimesh, path: Path) -> str:
    path.parent.mkdir(parents=True, exist_ok=True)
    mesh.export(path, file_type="stl")  # binary STL
    return path.relative_to(SCENES).as_posix()


def skullbase_meshes(p: dict) -> dict[str, trimesh.Trimesh]:
    parts = loft_tunnel(skullbase_stations(p))
    parts["right_internal_carotid"] = carotid(-1.0, p["ica_gap"] / 2)
    parts["left_internal_carotid"] = carotid(1.0, p["ica_gap"] / 2)
    parts["optic_chiasm"] = optic_apparatus()
    return parts


def _rz(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def fit_base_pose(p: dict, backend, base_depth: float = -105.0, roll: float = -0.5 * math.pi):
    """Place the robot base so that a planar configuration threads the airway.

    Candidates: planar configurations (relative tube angles 0 or pi) over a grid of translations.
    Each backbone is laid into the vertical plane through the valve centre and `AIM`, tip on
    `AIM`, tilted by -40..40 deg with the base ~`base_depth` mm in front of the face; the fit keeps
    the one whose backbone stays furthest inside the airway's vertical extent. ``roll`` is added to
    every tube angle (and taken out of the base rotation) so the angles lie inside (-pi, pi).

    Returns (goal box coordinates (6,), base pose 4x4).
    """
    robot = backend.robot
    st = skullbase_stations(p)
    zs = np.array([z for z, _, _ in st])
    ylo = np.array([sec[:, 1].min() for _, sec, _ in st])
    yhi = np.array([sec[:, 1].max() for _, sec, _ in st])
    rows = []
    pi = math.pi
    for rel in ((0.0, 0.0), (pi, 0.0), (0.0, pi), (pi, pi)):
        for b3 in (0.0, -5.0, -10.0):
            for d32 in range(0, 56, 5):
                for d21 in (0.0, 5.0, 10.0, 15.0):
                    rows.append([b3, d32, d21, 0.0, rel[0], rel[1]])
    X = np.array(rows)
    bb = backend.forward(robot.domain.from_box(X), points=120, check=False)
    best = None
    for k in range(len(X)):
        P = bb.positions_mm[k]  # planar: x = 0, bending along robot y
        z, w = P[:, 2], P[:, 1]
        for flip in (1.0, -1.0):
            for th in np.radians(np.arange(-40.0, 40.01, 1.0)):
                c, s_ = math.cos(th), math.sin(th)
                Z = c * z - s_ * flip * w
                Y = s_ * z + c * flip * w
                Z, Y = Z - Z[-1] + AIM[2], Y - Y[-1] + AIM[1]
                if abs(Z[0] - base_depth) > 10.0:
                    continue
                inside = (Z >= 0) & (zs[-1] >= Z)
                lo = np.interp(Z[inside], zs, ylo)
                hi = np.interp(Z[inside], zs, yhi)
                margin = float(np.minimum(Y[inside] - lo, hi - Y[inside]).min())
                if best is None or margin > best[0]:
                    best = (margin, k, flip, th)
    _, k, flip, th = best
    goal = X[k].copy()
    tip = bb.tip_mm[k]
    xv = -1.0 - p["valve_width"] / 2
    h = np.array([AIM[0] - xv, 0.0, AIM[2] - VALVE_Z])
    h /= np.linalg.norm(h)
    ey = np.array([0.0, 1.0, 0.0])
    c, s_ = math.cos(th), math.sin(th)
    rz = c * h + s_ * ey
    ry = flip * (-s_ * h + c * ey)
    R = np.column_stack([np.cross(ry, rz), ry, rz])
    T = np.eye(4)
    T[:3, :3] = R @ _rz(-roll)
    T[:3, 3] = AIM - R @ tip
    goal[3:] = goal[3:] + roll
    goal[3:] = (goal[3:] + pi) % (2 * pi) - pi
    return goal, T


def _yaml_q(q: np.ndarray) -> list[float]:
    """Joints rounded for YAML, angles kept strictly inside (-pi, pi) so rounding stays in range."""
    q = np.asarray(q, dtype=float).copy()
    q[3:] = np.clip(q[3:], -math.pi + 1e-5, math.pi - 1e-5)
    return [round(float(v), 6) for v in q]


def _yaml_pose(T: np.ndarray) -> dict:
    return {"position": [round(float(v), 4) for v in T[:3, 3]],
            "rotation": {"matrix": [[round(float(v), 9) for v in row] for row in T[:3, :3]]}}


def skullbase_scene(p: dict, name: str, description: str, backend) -> dict:
    parts = skullbase_meshes(p)
    obstacles = [{"name": n, "mesh": write_mesh(m, MESHES / name / f"{n}.stl")} for n, m in parts.items()]
    goal, T = fit_base_pose(p, backend)
    start = goal.copy()
    start[1:3] = (55.0, 15.0)  # tubes 1 and 2 retracted
    start[3] = (start[3] + 2 * math.pi) % (2 * math.pi) - math.pi  # tube 1 turned by half a turn
    q_start = backend.robot.domain.from_box(start)
    return {
        "name": name,
        "description": description,
        "robot": "nominal",
        "base_pose": _yaml_pose(T),
        "anatomy": {"x": "left", "y": "superior", "z": "posterior"},
        "obstacles": obstacles,
        "target": {"ellipsoid": dict(TARGET)},
        "start": _yaml_q(q_start),
        "planner": {"planner": "corridor", "time_limit_s": 10.0, "margin_mm": 0.2, "points": 40,
                    "resolution_mm": 1.0, "mm_per_rad": 40.0, "range_mm": 10.0},
    }


def open_scene() -> dict:
    """Open workspace, base at the origin: a sphere and a box between start and target."""
    return {
        "name": "open",
        "description": "Open workspace: the robot swings from its retracted start around a sphere and "
                       "a box to a target point. Primitives only.",
        "robot": "nominal",
        "base_pose": {"position": [0.0, 0.0, 0.0]},
        "obstacles": [
            {"name": "ball", "sphere": {"center": [43.0, -47.0, 150.0], "radius": 7.0}},
            {"name": "block", "box": {"center": [-25.0, -30.0, 150.0], "size": [20.0, 20.0, 20.0],
                                      "rotation": {"rpy_deg": [0.0, 0.0, 30.0]}}},
        ],
        "target": {"point": [37.2, -27.2, 181.6], "tolerance_mm": 3.0},
        "start": [-80.0, -65.0, -10.0, 0.0, 0.0, 0.0],
        "planner": {"time_limit_s": 10.0, "points": 30},
    }


PIPE_RADIUS = 6.0
PIPE_LENGTH = 70.0


def pipe_scene(backend) -> dict:
    """A curved pipe (12 mm bore, closed at the far end) laid along the distal 70 mm of a planar
    configuration's backbone, target near its end; the start is the most retracted configuration
    with the goal's tube angles that fits inside: the robot advances through the bend."""
    from ctrplan.collision.checker import RobotCollisionChecker
    from ctrplan.collision.world import CollisionWorld
    from ctrplan.scene.objects import Obstacle

    robot = backend.robot
    goal = np.array([-5.0, 10.0, 5.0, 0.0, 0.5 * math.pi, -0.5 * math.pi])
    bb = backend.forward(robot.domain.from_box(goal), points=80, check=False)
    P, s = bb.positions_mm[0], bb.s_mm[0]
    seg = P[s >= s[-1] - PIPE_LENGTH]
    end = seg[-1] + 4.0 * (seg[-1] - seg[-2]) / np.linalg.norm(seg[-1] - seg[-2])
    pipe = tube_along(np.vstack([seg, end]), PIPE_RADIUS, 24)
    V, F = np.asarray(pipe.vertices), np.asarray(pipe.faces)
    F = F[~np.any(len(V) - 2 == F, axis=1)]  # open the proximal end (drop its cap)
    pipe = trimesh.Trimesh(V, F, process=False)
    pipe.remove_unreferenced_vertices()
    world = CollisionWorld([Obstacle("pipe", "mesh", vertices=np.asarray(pipe.vertices),
                                     faces=np.asarray(pipe.faces))])
    checker = RobotCollisionChecker(world, np.eye(4), 40, 0.2)
    start = None  # the most retracted configuration with the goal's tube angles that fits
    for d32 in range(55, -1, -5):
        for d21 in (15.0, 10.0, 5.0, 0.0):
            x = goal.copy()
            x[1:3] = (d32, d21)
            b = backend.forward(robot.domain.from_box(x), points=40, check=False)
            if b.converged[0] and checker.is_free(b.positions_mm[0], b.radius_mm[0]):
                start = x
                break
        if start is not None:
            break
    return {
        "name": "pipe",
        "description": "A narrow curved pipe (12 mm bore, 70 mm long, closed at the far end); the "
                       "robot starts inside, retracted as far as the pipe allows, and advances through "
                       "the bend to the target near the end.",
        "robot": "nominal",
        "base_pose": {"position": [0.0, 0.0, 0.0]},
        "obstacles": [{"name": "pipe", "mesh": write_mesh(pipe, MESHES / "pipe" / "pipe.stl")}],
        "target": {"point": [round(float(v), 3) for v in bb.tip_mm[0]], "tolerance_mm": 2.0},
        "start": _yaml_q(robot.domain.from_box(start)),
        "planner": {"time_limit_s": 10.0, "range_mm": 10.0},
    }


def check_scene(path: Path, seeds: int = 3, time_limit: float = 10.0) -> None:  # pragma: no cover
    """Start valid, straight line start -> found goal collides, and RRTConnect solves it."""
    from ompl import util as ou

    from ctrplan.kinematics import CosseratBackend
    from ctrplan.planning import ConfigurationChecker, PlanningModel, plan
    from ctrplan.scene.loader import load_scene

    ou.setLogLevel(ou.LOG_ERROR)
    scene = load_scene(path)
    checker = ConfigurationChecker(PlanningModel.of(scene, CosseratBackend(scene.robot)))
    print(f"{path.name}: start valid: {checker.is_valid(scene.start)}, "
          f"start tip {np.round(checker.tip(scene.start), 1)}")
    for seed in range(seeds):
        res = plan(scene, "cosserat", seed=seed, time_limit_s=time_limit)
        line = ""
        if res.solved:
            dense = checker.space.densify(np.stack([scene.start, res.path[-1]]), 1.0)
            line = f", straight line start->goal valid at {checker.check(dense).mean():.0%} of states"
        v = res.validated
        print(f"  seed {seed}: solved={res.solved} in {res.planning_time_s:.1f} s{line}"
              + (f", clearance {v.min_clearance_mm:.2f} mm" if v else "") + f" ({res.message})")


def main() -> None:  # pragma: no cover - script
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    ap.add_argument("--check", action="store_true", help="verify the problems by planning")
    args = ap.parse_args()
    from ctrplan.kinematics import CosseratBackend
    from ctrplan.model.robot import Robot

    backend = CosseratBackend(Robot.nominal())
    desc = ("Endonasal transsphenoidal approach through the right nostril to the pituitary "
            "(generated by scripts/make_scenes.py; see its docstring for the dimensions). Scene "
            "frame: origin at the anterior nasal spine, x left, y superior, z posterior, mm.")
    scenes = {
        "skullbase": skullbase_scene(SKULLBASE, "skullbase", desc, backend),
        "skullbase_strict": skullbase_scene(STRICT, "skullbase_strict",
                                            desc + " Resting-anatomy widths: a harder benchmark.",
                                            backend),
        "open": open_scene(),
        "pipe": pipe_scene(backend),
    }
    scenes["skullbase_approach"] = approach_variant(scenes["skullbase"])
    header = "# Generated by scripts/make_scenes.py -- edit the generator, not this file.\n"
    for name, d in scenes.items():
        path = SCENES / f"{name}.yaml"
        path.write_text(header + dump_yaml(d))
        print(f"wrote {path.relative_to(ROOT)}")
    path = SCENES / "skullbase_design.yaml"
    note = "# The design task of `ctrplan design` (docs/design.md §5); targets in the scene frame, mm.\n"
    path.write_text(header + note + dump_yaml(design_task(SKULLBASE)))
    print(f"wrote {path.relative_to(ROOT)}")
    if args.check:
        for name in scenes:
            check_scene(SCENES / f"{name}.yaml")


if __name__ == "__main__":
    main()
