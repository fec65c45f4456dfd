"""Scene files: robot, robot base pose, obstacles, target region, start configuration, settings.

A scene is a YAML file in mm (scene frame). Everything is validated on load and every error names the
file, the key and the line (`ctrplan.base.yamlio`). Layout::

    name: skullbase                       # optional
    description: ...                      # optional
    robot: nominal                        # built-in name or robot YAML file (relative to the scene)
    base_pose:                            # robot frame (front plate, z = insertion) in the scene frame
      position: [x, y, z]                 # mm
      rotation: {rpy_deg: [r, p, y]}      # or {matrix: 3x3} | {quaternion_wxyz: [...]} |
                                          #    {axis_angle_deg: {axis: [...], angle: a}} |
                                          #    {z_axis: [...], y_axis: [...]} (y projected)
    obstacles:
      - {name: septum, mesh: meshes/septum.stl}             # STL/OBJ/PLY, path relative to the scene;
                                                           # optional position/rotation/scale; a file
                                                           # that declares its frame (SPACE=LPS, as 3D
                                                           # Slicer writes) is converted to the
                                                           # scene's `anatomy` frame
      - {name: ball, sphere: {center: [...], radius: r}}
      - {name: wall, box: {center: [...], size: [a, b, c], rotation: {...}}}
      - {name: rod, cylinder: {center: [...], radius: r, length: l, axis: [...]}}
      - {name: pin, capsule: {center: [...], radius: r, length: l, axis: [...]}}
      - {name: carotid, mesh: meshes/ica.stl, margin_mm: 2.0}  # any obstacle: its own no-go margin
                                          # (mm, default 0), on top of planner.margin_mm: the robot
                                          # must keep this much more clearance from it
    anatomy: {x: left, y: superior, z: posterior}   # optional: the patient direction of each scene
                                          # axis (left/right, anterior/posterior, superior/inferior),
                                          # shown as orientation cues in plan.png and plan.html
    target:                               # tip must end inside this region (scene frame)
      point: [x, y, z]                    # with
      tolerance_mm: 2.0
      # or: ellipsoid: {center: [...], semi_axes_mm: [a, b, c], rotation: {...}}
      direction: [dx, dy, dz]             # optional approach: the tip's tangent (scene frame) ...
      angle_tolerance_deg: 20             # ... within this angle of direction (give both)
    start: [beta1, beta2, beta3, alpha1, alpha2, alpha3]    # mm, rad; inside the snap-free domain
    joint_limits:                         # optional: narrow the planning box (box coordinates)
      alpha1_deg: [-60, 60]               # keys: beta3_mm, beta3_minus_beta2_mm, beta2_minus_beta1_mm,
                                          #       alpha1_deg, alpha2_deg, alpha3_deg
    planner:                              # defaults, all optional (see `PlannerSettings`)
      planner: corridor                   # one of ctrplan.planning.planners.PLANNERS
      time_limit_s: 10
      seed: null
      margin_mm: 0.2                      # added to the capsule radii (planning and validation)
      surrogate_margin_mm: null           # extra while planning with the PINN (null: the model
                                          #   card's calibrated error bound by arc-length region
      surrogate_coverage: 0.8             #   at this coverage: 0.5 | 0.8 | 0.9 | 0.95 | 0.99)
      points: 40                          # backbone points (capsules + 1)
      resolution_mm: 1.0                  # edge checking step in the planning metric
      mm_per_rad: 40.0                    # metric weight of rotations
      range_mm: null                      # tree planners' step (null: OMPL's default)
      simplify: true
      goal_samples: 8                     # IK seeds per goal batch / 3
      repair: true                        # re-plan stretches that fail exact validation

A target further from the base than the robot can ever reach is bad input (the loader says so);
a start in collision is reported by the planner, naming the obstacles. Cylinders and capsules are
given by their centre, radius, length (of the straight part for capsules) and either an ``axis``
direction or a ``rotation`` (local z = axis).

Over 500 lines because it is the scene file format: every key with its check, default and error
message in one place, so that a new key touches one file.
"""

from __future__ import annotations

import copy
import math
import os
from dataclasses import fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from ctrplan.base.errors import InputError
from ctrplan.base.yamlio import YamlDoc, load_yaml
from ctrplan.model.robot import JointDomain, Robot
from ctrplan.scene.geometry import ANATOMY_PAIRS, frame_from_z, make_pose, rpy_matrix
from ctrplan.scene.objects import Obstacle, PlannerSettings, Scene, TargetRegion
from ctrplan.scene.orientation import anatomy_code, code_matrix, declared_space

PRIMITIVES = ("sphere", "box", "cylinder", "capsule")

MESH_SUFFIXES = (".stl", ".obj", ".ply")

# ---- loading ---------------------------------------------------------------------------------------
_TOP_KEYS = {"name", "description", "robot", "base_pose", "obstacles", "target", "start", "planner",
             "joint_limits", "anatomy"}
def joint_limit_keys(domain: JointDomain) -> tuple[str, ...]:
    """Keys of a scene's ``joint_limits`` (box coordinates; translations in mm, rotations in deg):
    the robot file's domain keys with ``alphaI_deg`` for the rotations."""
    return tuple(k.replace("_rad", "_deg") for k in domain.keys)




def _num(doc: YamlDoc, keys: tuple, value: Any, *, positive: bool = False,
         nonneg: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise doc.error(keys, f"expected a finite number, got {value!r}")
    if positive and value <= 0:
        raise doc.error(keys, f"must be > 0, got {value!r}")
    if nonneg and value < 0:
        raise doc.error(keys, f"must be >= 0, got {value!r}")
    return float(value)


def _vec(doc: YamlDoc, keys: tuple, value: Any, n: int) -> np.ndarray:
    if not isinstance(value, list) or len(value) != n:
        raise doc.error(keys, f"expected a list of {n} numbers, got {value!r}")
    return np.array([_num(doc, keys + (i,), v) for i, v in enumerate(value)])


def _mapping(doc: YamlDoc, keys: tuple, value: Any, allowed: set[str],
             required: tuple[str, ...] = ()) -> dict:
    if not isinstance(value, dict):
        raise doc.error(keys, f"expected a mapping, got {value!r}")
    for k in value:
        if k not in allowed:
            raise doc.error(keys + (k,), f"unknown key (allowed: {', '.join(sorted(allowed))})")
    for k in required:
        if k not in value:
            raise doc.error(keys, f"missing required key {k!r}")
    return value


def _direction(doc: YamlDoc, keys: tuple, value: Any) -> np.ndarray:
    v = _vec(doc, keys, value, 3)
    n = np.linalg.norm(v)
    if n < 1e-12:
        raise doc.error(keys, "direction must not be the zero vector")
    return v / n


def _rotation(doc: YamlDoc, keys: tuple, value: Any) -> np.ndarray:
    spec = _mapping(doc, keys, value, {"rpy_deg", "matrix", "quaternion_wxyz", "axis_angle_deg",
                                       "z_axis", "y_axis"})
    forms = [k for k in ("rpy_deg", "matrix", "quaternion_wxyz", "axis_angle_deg", "z_axis") if k in spec]
    if len(forms) != 1:
        raise doc.error(keys, "give exactly one of rpy_deg, matrix, quaternion_wxyz, axis_angle_deg, "
                              "z_axis (+ optional y_axis)")
    form = forms[0]
    if "y_axis" in spec and form != "z_axis":
        raise doc.error(keys + ("y_axis",), "y_axis is only allowed together with z_axis")
    k = keys + (form,)
    if form == "rpy_deg":
        r, p, y = np.radians(_vec(doc, k, spec[form], 3))
        return rpy_matrix(r, p, y)
    if form == "matrix":
        raw = spec[form]
        if not isinstance(raw, list) or len(raw) != 3:
            raise doc.error(k, "expected a 3x3 matrix (list of 3 rows)")
        R = np.stack([_vec(doc, k + (i,), row, 3) for i, row in enumerate(raw)])
        if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise doc.error(k, "not a rotation matrix (must be orthonormal with determinant +1)")
        return R
    if form == "quaternion_wxyz":
        qv = _vec(doc, k, spec[form], 4)
        n = np.linalg.norm(qv)
        if n < 1e-12:
            raise doc.error(k, "quaternion must not be zero")
        w, x, y, z = qv / n
        return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                         [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                         [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    if form == "axis_angle_deg":
        aa = _mapping(doc, k, spec[form], {"axis", "angle"}, ("axis", "angle"))
        axis = _direction(doc, k + ("axis",), aa["axis"])
        ang = math.radians(_num(doc, k + ("angle",), aa["angle"]))
        K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        return np.eye(3) + math.sin(ang) * K + (1 - math.cos(ang)) * K @ K
    z = _direction(doc, k, spec["z_axis"])
    y = None
    if "y_axis" in spec:
        y = _direction(doc, keys + ("y_axis",), spec["y_axis"])
        if abs(np.dot(y, z)) > 0.999:
            raise doc.error(keys + ("y_axis",), "y_axis must not be parallel to z_axis")
    return frame_from_z(z, y)


def _pose(doc: YamlDoc, keys: tuple, value: Any) -> np.ndarray:
    spec = _mapping(doc, keys, value, {"position", "rotation", "matrix"})
    if "matrix" in spec:
        if len(spec) != 1:
            raise doc.error(keys, "give either matrix (4x4) or position/rotation, not both")
        raw = spec["matrix"]
        if not isinstance(raw, list) or len(raw) != 4:
            raise doc.error(keys + ("matrix",), "expected a 4x4 matrix (list of 4 rows)")
        T = np.stack([_vec(doc, keys + ("matrix", i), row, 4) for i, row in enumerate(raw)])
        R = T[:3, :3]
        if not np.allclose(T[3], [0, 0, 0, 1]) or not np.allclose(R.T @ R, np.eye(3), atol=1e-6) \
                or np.linalg.det(R) < 0:
            raise doc.error(keys + ("matrix",), "not a rigid transform (rotation must be orthonormal, "
                                                "last row 0 0 0 1)")
        return T
    if "position" not in spec:
        raise doc.error(keys, "missing required key 'position'")
    pos = _vec(doc, keys + ("position",), spec["position"], 3)
    R = _rotation(doc, keys + ("rotation",), spec["rotation"]) if "rotation" in spec else np.eye(3)
    return make_pose(R, pos)


def _load_mesh(doc: YamlDoc, keys: tuple, rel: Any, frame: str | None):
    """Vertices (scene frame: converted from the frame the file declares, `declared_space`, to
    ``frame``, the scene's anatomy code, when both are known), faces, the file and its declared
    frame."""
    import trimesh

    if not isinstance(rel, str) or not rel:
        raise doc.error(keys, f"expected a mesh file name, got {rel!r}")
    path = Path(rel)
    if not path.is_absolute():
        path = doc.path.parent / path
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise doc.error(keys, f"unsupported mesh format {path.suffix!r} (use STL, OBJ or PLY)")
    if not path.is_file():
        raise doc.error(keys, f"mesh file not found: {path}")
    try:
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types on corrupt files
        raise doc.error(keys, f"cannot read mesh {path} ({exc})") from None
    faces = np.asarray(getattr(mesh, "faces", np.zeros((0, 3))), dtype=np.int64)
    verts = np.asarray(getattr(mesh, "vertices", np.zeros((0, 3))), dtype=float)
    if faces.ndim != 2 or faces.shape[0] == 0 or faces.shape[1] != 3:
        raise doc.error(keys, f"mesh {path} has no triangles")
    if not np.all(np.isfinite(verts)):
        raise doc.error(keys, f"mesh {path} has non-finite vertices")
    space = declared_space(path)
    if space is not None and frame is not None:
        verts = verts @ code_matrix(space, frame).T
        if np.linalg.det(code_matrix(space, frame)) < 0:  # a reflection turns the faces inside out
            faces = faces[:, ::-1]
    return verts, faces, str(path), space


def _obstacle(doc: YamlDoc, keys: tuple, raw: Any, index: int, frame: str | None) -> Obstacle:
    allowed = {"name", "mesh", "position", "rotation", "scale", "margin_mm"} | set(PRIMITIVES)
    raw = _mapping(doc, keys, raw, allowed)
    return replace(_obstacle_shape(doc, keys, raw, index, frame), margin_mm=_num(
        doc, keys + ("margin_mm",), raw["margin_mm"], nonneg=True) if "margin_mm" in raw else 0.0)


def _obstacle_shape(doc: YamlDoc, keys: tuple, raw: dict, index: int, frame: str | None) -> Obstacle:
    kinds = [k for k in ("mesh", *PRIMITIVES) if k in raw]
    if len(kinds) != 1:
        raise doc.error(keys, f"give exactly one of mesh, {', '.join(PRIMITIVES)}")
    kind = kinds[0]
    name = raw.get("name", f"obstacle{index}")
    if not isinstance(name, str) or not name:
        raise doc.error(keys + ("name",), f"expected a non-empty string, got {name!r}")
    if kind == "mesh":
        verts, faces, src, space = _load_mesh(doc, keys + ("mesh",), raw["mesh"], frame)
        scale = _num(doc, keys + ("scale",), raw["scale"], positive=True) if "scale" in raw else 1.0
        pos = _vec(doc, keys + ("position",), raw["position"], 3) if "position" in raw else np.zeros(3)
        R = _rotation(doc, keys + ("rotation",), raw["rotation"]) if "rotation" in raw else np.eye(3)
        verts = (verts * scale) @ R.T + pos
        return Obstacle(name=name, kind="mesh", vertices=verts, faces=faces, source=src, space=space)
    for k in ("position", "rotation", "scale"):
        if k in raw:
            raise doc.error(keys + (k,), f"{k!r} belongs inside the {kind} mapping (or use a mesh)")
    k = keys + (kind,)
    if kind == "sphere":
        spec = _mapping(doc, k, raw[kind], {"center", "radius"}, ("center", "radius"))
        c = _vec(doc, k + ("center",), spec["center"], 3)
        r = _num(doc, k + ("radius",), spec["radius"], positive=True)
        return Obstacle(name=name, kind=kind, pose=make_pose(np.eye(3), c), radius=r)
    if kind == "box":
        spec = _mapping(doc, k, raw[kind], {"center", "size", "rotation"}, ("center", "size"))
        c = _vec(doc, k + ("center",), spec["center"], 3)
        size = _vec(doc, k + ("size",), spec["size"], 3)
        if np.any(size <= 0):
            raise doc.error(k + ("size",), f"all sizes must be > 0, got {size.tolist()}")
        R = _rotation(doc, k + ("rotation",), spec["rotation"]) if "rotation" in spec else np.eye(3)
        return Obstacle(name=name, kind=kind, pose=make_pose(R, c), size=tuple(size.tolist()))
    spec = _mapping(doc, k, raw[kind], {"center", "radius", "length", "axis", "rotation"},
                    ("center", "radius", "length"))
    c = _vec(doc, k + ("center",), spec["center"], 3)
    r = _num(doc, k + ("radius",), spec["radius"], positive=True)
    length = _num(doc, k + ("length",), spec["length"], nonneg=kind == "capsule",
                  positive=kind == "cylinder")
    if "axis" in spec and "rotation" in spec:
        raise doc.error(k, "give either axis or rotation, not both")
    if "rotation" in spec:
        R = _rotation(doc, k + ("rotation",), spec["rotation"])
    else:
        axis = _direction(doc, k + ("axis",), spec["axis"]) if "axis" in spec else np.array([0, 0, 1.0])
        R = frame_from_z(axis)
    return Obstacle(name=name, kind=kind, pose=make_pose(R, c), radius=r, length=length)


def target_from_yaml(doc: YamlDoc, raw: Any, keys: tuple = ("target",)) -> TargetRegion:
    """The target region of the mapping ``raw`` found at ``keys`` of ``doc`` (the scene's
    ``target`` by default; see the module docstring); errors name the key and line."""
    spec = _mapping(doc, keys, raw, {"point", "tolerance_mm", "ellipsoid", "direction",
                                     "angle_tolerance_deg"})
    region = _target_region(doc, keys, {k: v for k, v in spec.items()
                                        if k not in ("direction", "angle_tolerance_deg")})
    if ("direction" in spec) != ("angle_tolerance_deg" in spec):
        raise doc.error(keys, "give direction and angle_tolerance_deg together")
    if "direction" not in spec:
        return region
    tol = _num(doc, keys + ("angle_tolerance_deg",), spec["angle_tolerance_deg"], positive=True)
    if tol >= 180:
        raise doc.error(keys + ("angle_tolerance_deg",), f"must be < 180, got {tol:g}")
    return replace(region, direction=_direction(doc, keys + ("direction",), spec["direction"]),
                   angle_tolerance_rad=math.radians(tol))


def _target_region(doc: YamlDoc, keys: tuple, spec: dict) -> TargetRegion:
    if "ellipsoid" in spec:
        if len(spec) != 1:
            raise doc.error(keys, "give either point + tolerance_mm or ellipsoid")
        k = keys + ("ellipsoid",)
        e = _mapping(doc, k, spec["ellipsoid"], {"center", "semi_axes_mm", "rotation"},
                     ("center", "semi_axes_mm"))
        c = _vec(doc, k + ("center",), e["center"], 3)
        ax = _vec(doc, k + ("semi_axes_mm",), e["semi_axes_mm"], 3)
        if np.any(ax <= 0):
            raise doc.error(k + ("semi_axes_mm",), f"semi-axes must be > 0, got {ax.tolist()}")
        R = _rotation(doc, k + ("rotation",), e["rotation"]) if "rotation" in e else np.eye(3)
        return TargetRegion(c, ax, R, "ellipsoid")
    if "point" not in spec:
        raise doc.error(keys, "missing required key 'point' (or give an ellipsoid)")
    if "tolerance_mm" not in spec:
        raise doc.error(keys, "missing required key 'tolerance_mm'")
    c = _vec(doc, keys + ("point",), spec["point"], 3)
    tol = _num(doc, keys + ("tolerance_mm",), spec["tolerance_mm"], positive=True)
    return TargetRegion.sphere(c, tol)


def _settings(doc: YamlDoc, raw: Any) -> PlannerSettings:
    keys = ("planner",)
    names = {f.name for f in fields(PlannerSettings)}
    spec = _mapping(doc, keys, raw, names)
    kw: dict[str, Any] = {}
    for name, value in spec.items():
        k = keys + (name,)
        if name == "planner":
            if not isinstance(value, str):
                raise doc.error(k, f"expected a planner name, got {value!r}")
            kw[name] = value
        elif name in ("simplify", "repair"):
            if not isinstance(value, bool):
                raise doc.error(k, f"expected true or false, got {value!r}")
            kw[name] = value
        elif name in ("seed", "points", "goal_samples", "max_states"):
            if value is None and name in ("seed", "max_states"):
                kw[name] = None
                continue
            if isinstance(value, bool) or not isinstance(value, int):
                raise doc.error(k, f"expected an integer, got {value!r}")
            lo = {"seed": 0, "points": 3, "goal_samples": 1, "max_states": 1}[name]
            if value < lo:
                raise doc.error(k, f"must be >= {lo}, got {value!r}")
            kw[name] = int(value)
        elif name == "range_mm":
            kw[name] = None if value is None else _num(doc, k, value, positive=True)
        elif name == "surrogate_margin_mm":
            kw[name] = None if value is None else _num(doc, k, value, nonneg=True)
        elif name == "margin_mm":
            kw[name] = _num(doc, k, value, nonneg=True)
        elif name == "surrogate_coverage":
            kw[name] = _num(doc, k, value, positive=True)
            if kw[name] >= 1:
                raise doc.error(k, f"must be below 1, got {value!r}")
        else:
            kw[name] = _num(doc, k, value, positive=True)
    return PlannerSettings(**kw)




def _anatomy(doc: YamlDoc, raw: Any) -> dict[str, str]:
    spec = _mapping(doc, ("anatomy",), raw, {"x", "y", "z"}, ("x", "y", "z"))
    terms = [t for pair in ANATOMY_PAIRS for t in pair]
    for axis, value in spec.items():
        if value not in terms:
            raise doc.error(("anatomy", axis), f"expected one of {', '.join(terms)}, got {value!r}")
    used = [next(i for i, pair in enumerate(ANATOMY_PAIRS) if spec[a] in pair) for a in "xyz"]
    if len(set(used)) != 3:
        raise doc.error(("anatomy",), "each axis needs its own pair of directions (left/right, "
                                      "anterior/posterior, superior/inferior)")
    return {a: spec[a] for a in "xyz"}


def _joint_limits(doc: YamlDoc, raw: Any, robot: Robot) -> tuple[np.ndarray, np.ndarray]:
    keys = ("joint_limits",)
    names = joint_limit_keys(robot.domain)
    spec = _mapping(doc, keys, raw, set(names))
    lo, hi = robot.domain.box_lower.copy(), robot.domain.box_upper.copy()
    for i, name in enumerate(names):
        if name not in spec:
            continue
        a, b = _vec(doc, keys + (name,), spec[name], 2)
        if name.endswith("_deg"):
            a, b = math.radians(a), math.radians(b)
        if a > b:
            raise doc.error(keys + (name,), f"lower limit must not exceed the upper limit, got {spec[name]}")
        tol = 1e-9
        if a < lo[i] - tol or b > hi[i] + tol:
            unit = "deg" if name.endswith("_deg") else "mm"
            f = math.degrees if name.endswith("_deg") else float
            raise doc.error(keys + (name,), f"must lie inside the robot's snap-free domain "
                                            f"[{f(lo[i]):g}, {f(hi[i]):g}] {unit}")
        lo[i], hi[i] = max(a, lo[i]), min(b, hi[i])
    return lo, hi


def scene_from_yaml(doc: YamlDoc, *, check_start: bool = True, robot: Robot | None = None) -> Scene:
    """Build a validated `Scene` from a parsed YAML document (errors name key and line). With
    ``check_start=False`` a start outside the joint domain (or the scene's joint limits) is kept, for
    `ctrplan.planning.scene_check` to report and repair. ``robot`` replaces the scene's ``robot:``
    (``plan --robot``)."""
    d = doc.data
    for k in d:
        if k not in _TOP_KEYS:
            raise doc.error((k,), f"unknown key (allowed: {', '.join(sorted(_TOP_KEYS))})")
    for k in ("robot", "base_pose", "target", "start"):
        if k not in d:
            raise doc.error((), f"missing required key {k!r}")

    robot = robot or _robot(doc, d["robot"])

    base_pose = _pose(doc, ("base_pose",), d["base_pose"])
    anatomy = _anatomy(doc, d["anatomy"]) if "anatomy" in d else None
    frame = None if anatomy is None else anatomy_code(anatomy)

    raw_obs = d.get("obstacles", [])
    if raw_obs is None:
        raw_obs = []
    if not isinstance(raw_obs, list):
        raise doc.error(("obstacles",), "expected a list of obstacles")
    obstacles = tuple(_obstacle(doc, ("obstacles", i), o, i, frame) for i, o in enumerate(raw_obs))
    seen: dict[str, int] = {}
    for i, o in enumerate(obstacles):
        if o.name in seen:
            raise doc.error(("obstacles", i, "name"), f"duplicate obstacle name {o.name!r} "
                                                      f"(also obstacles[{seen[o.name]}])")
        seen[o.name] = i

    target = target_from_yaml(doc, d["target"])
    reach = float(robot.lengths_mm[0] + robot.domain.box_upper[0])  # l1 at full extension
    gap = float(np.linalg.norm(target.center - base_pose[:3, 3]) - np.max(target.semi_axes))
    if gap > reach:
        raise doc.error(("target",), f"out of reach: the target region is {gap:.1f} mm from the robot "
                                     f"base, but the robot is at most {reach:.1f} mm long")
    start = _vec(doc, ("start",), d["start"], robot.n_joints)
    if check_start:
        try:
            robot.check_joints(start, where="start")
        except InputError as exc:
            raise doc.error(("start",), str(exc).removeprefix("start: ").removeprefix("row 0: ")) from None
    settings = _settings(doc, d["planner"]) if "planner" in d else PlannerSettings()
    limits = None
    if "joint_limits" in d:
        limits = _joint_limits(doc, d["joint_limits"], robot)
        box = robot.domain.to_box(start)
        out = np.flatnonzero((box < limits[0] - 1e-9) | (box > limits[1] + 1e-9))
        if out.size and check_start:
            i = int(out[0])
            names = joint_limit_keys(robot.domain)
            raise doc.error(("start",), f"outside the scene's joint_limits: {names[i]}")

    name = d.get("name", doc.path.stem)
    desc = d.get("description", "")
    if not isinstance(name, str):
        raise doc.error(("name",), f"expected a string, got {name!r}")
    if not isinstance(desc, str):
        raise doc.error(("description",), f"expected a string, got {desc!r}")
    return Scene(name=name, robot=robot, base_pose=base_pose, obstacles=obstacles, target=target,
                 start=start, settings=settings, description=desc.strip(), path=doc.path,
                 joint_limits=limits, anatomy=anatomy,
                 key_lines={".".join(map(str, k)): line for k, line in doc.lines.items() if k})


def _robot(doc: YamlDoc, spec: Any) -> Robot:
    """The robot a scene's ``robot:`` names: built-in, or a file relative to the scene."""
    if not isinstance(spec, str) or not spec:
        raise doc.error(("robot",), f"expected a built-in robot name or a robot file, got {spec!r}")
    from ctrplan.model.robot import BUILTIN_ROBOTS

    if spec not in BUILTIN_ROBOTS:
        rpath = Path(spec)
        if not rpath.is_absolute():
            rpath = doc.path.parent / rpath
        if not rpath.is_file():
            raise doc.error(("robot",), f"not a built-in robot ({', '.join(BUILTIN_ROBOTS)}) and no "
                                        f"such file: {rpath}")
        spec = rpath
    try:
        return Robot.load(spec)
    except InputError as exc:
        raise doc.error(("robot",), str(exc)) from None


def load_scene(path: str | Path, *, check_start: bool = True, robot: Robot | None = None) -> Scene:
    """Load and validate a scene file (see the module docstring for the format; ``check_start`` and
    ``robot`` as in `scene_from_yaml`)."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path}: is a directory, expected a scene YAML file")
    return scene_from_yaml(load_yaml(path), check_start=check_start, robot=robot)


def relocated(doc: YamlDoc, out: Path) -> dict[str, Any]:
    """The scene file ``doc``'s mapping as a file at ``out`` must say it: the robot file and mesh
    paths, relative to ``doc``, made relative to ``out`` (absolute where no relative path exists)."""
    from ctrplan.model.robot import BUILTIN_ROBOTS

    def moved(rel: str) -> str:
        if Path(rel).is_absolute():
            return rel
        target = (doc.path.parent / rel).resolve()
        try:
            return os.path.relpath(target, out.parent.resolve())
        except ValueError:  # another drive (Windows)
            return str(target)

    data = copy.deepcopy(doc.data)
    if isinstance(data.get("robot"), str) and data["robot"] not in BUILTIN_ROBOTS:
        data["robot"] = moved(data["robot"])
    for obstacle in data.get("obstacles") or []:
        if isinstance(obstacle, dict) and isinstance(obstacle.get("mesh"), str):
            obstacle["mesh"] = moved(obstacle["mesh"])
    return data
