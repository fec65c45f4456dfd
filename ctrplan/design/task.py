"""Design task files (`ctrplan design TASK.yaml`, docs/design.md §5): which tube set to build for a procedure.

A task is YAML in mm and 1/m; paths are relative to the task file::

    scene: skullbase.yaml                # anatomy, base pose, start, planner defaults (its target is
                                         #   ignored)
    targets:                             # named scene targets: point + tolerance_mm, or ellipsoid;
      - {name: sella, ellipsoid: {center: [-2.5, 22.0, 81.0], semi_axes_mm: [3.5, 2.5, 3.5]},
         reason: "..."}                  #   optional direction + angle_tolerance_deg, reason
      - {name: clivus, point: [0.0, 9.0, 73.5], tolerance_mm: 2.0}
    robot: nominal                       # the base design (built-in name or robot file; default: the
                                         #   scene's); its joint domain (the actuator strokes) is kept
    vary:                                # tube index (1 = innermost) -> field -> [min, max]
      1: {curvature_1_per_m: [0.0, 60.0], curved_length_mm: [20.0, 120.0]}
      2: {curvature_1_per_m: [0.0, 30.0]}
    catalogue:                           # optional stock tube sizes; each tube takes one of them,
      - {inner_diameter_mm: 0.4, outer_diameter_mm: 0.5}   #   nested (tube i fits in tube i + 1)
    constraints: {max_strain: 0.08, snap_free: true}
    objectives: [targets_reached, -max_strain]   # maximise the first, then the rest (Pareto);
                                                 #   "-" minimises
    budget: {trials: 60, plan_time_s: 5.0}   # optional plan_states: the work budget of each target's
                                             #   search (states; default: what plan_time_s buys with
                                             #   the exact model on the reference machine)

Every error names the file, the key and the line (`ctrplan.base.yamlio`).
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
import re
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path
from typing import Any

from ctrplan.base.errors import InputError
from ctrplan.base.yamlio import YamlDoc, load_yaml
from ctrplan.design.objectives import OBJECTIVES, Objective
from ctrplan.model.robot import BUILTIN_ROBOTS, MAX_PRECURVE_STRAIN, TUBE_LIMITS, Robot
from ctrplan.scene.loader import load_scene, target_from_yaml
from ctrplan.scene.objects import Scene, TargetRegion

#: Robot-file tube fields a task may vary (file units: 1/m, mm).
VARY_FIELDS = ("curvature_1_per_m", "curved_length_mm", "straight_length_mm")
DEFAULT_OBJECTIVES = ("targets_reached", "-max_strain")
_TOP_KEYS = {"scene", "targets", "robot", "vary", "catalogue", "constraints", "objectives", "budget"}
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")


@dataclass(frozen=True)
class NamedTarget:
    """A target of the procedure: its name (also a folder name), region (scene frame) and why it
    matters clinically."""

    name: str
    region: TargetRegion
    reason: str = ""


@dataclass(frozen=True)
class Vary:
    """One design parameter: ``field`` (a robot-file key, file units) of tube ``tube`` (1 =
    innermost) in ``[low, high]``."""

    tube: int
    field: str
    low: float
    high: float

    @property
    def name(self) -> str:
        """The parameter's name in the study, e.g. ``tube1.curvature_1_per_m``."""
        return f"tube{self.tube}.{self.field}"


@dataclass(frozen=True)
class StockSize:
    """A tube size one can buy (mm)."""

    inner_diameter_mm: float
    outer_diameter_mm: float

    @property
    def label(self) -> str:
        return f"{self.inner_diameter_mm:g}/{self.outer_diameter_mm:g}"


@dataclass(frozen=True)
class DesignTask:
    """A validated design task (see the module docstring). ``scene`` carries the base robot and the
    scene's start; ``max_strain`` is a fraction; ``plan_time_s`` the planning time per target (its
    wall-clock guard is `GUARD_FACTOR` times it) and ``plan_states`` its work budget (None: what
    ``plan_time_s`` buys with the exact model on the reference machine; see
    `ctrplan.planning.budget`)."""

    path: Path
    scene: Scene
    targets: tuple[NamedTarget, ...]
    vary: tuple[Vary, ...]
    catalogue: tuple[StockSize, ...]
    max_strain: float
    snap_free: bool
    objectives: tuple[Objective, ...]
    trials: int
    plan_time_s: float
    digest: str
    plan_states: int | None = None

    @property
    def name(self) -> str:
        return self.path.stem

    @property
    def robot(self) -> Robot:
        """The base design."""
        return self.scene.robot

    @cached_property
    def diameter_sets(self) -> tuple[tuple[StockSize, ...], ...]:
        """Every way to give each tube a catalogue size so that tube i fits inside tube i + 1
        (innermost first); empty without a catalogue."""
        n = self.robot.n_tubes
        return tuple(c for c in itertools.combinations(self.catalogue, n)
                     if all(a.outer_diameter_mm <= b.inner_diameter_mm for a, b in itertools.pairwise(c)))


def load_task(path: str | Path) -> DesignTask:
    """Load and validate a design task file; `InputError` naming the key and line otherwise."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path}: is a directory, expected a design task YAML file")
    doc = load_yaml(path)
    d = doc.data
    for k in d:
        if k not in _TOP_KEYS:
            raise doc.error((k,), f"unknown key (allowed: {', '.join(sorted(_TOP_KEYS))})")
    for k in ("scene", "targets"):
        if k not in d:
            raise doc.error((), f"missing required key {k!r}")
    scene = load_scene(_file(doc, ("scene",), d["scene"], "a scene file"))
    if "robot" in d:
        scene = _with_robot(doc, scene, d["robot"])
    targets = _targets(doc, d["targets"])
    vary = _vary(doc, d.get("vary") or {}, scene.robot)
    catalogue = _catalogue(doc, d.get("catalogue") or [])
    constraints = _mapping(doc, ("constraints",), d.get("constraints") or {}, {"max_strain", "snap_free"})
    max_strain = _number(doc, ("constraints", "max_strain"),
                         constraints.get("max_strain", MAX_PRECURVE_STRAIN))
    if not 0 < max_strain <= MAX_PRECURVE_STRAIN:
        raise doc.error(("constraints", "max_strain"), f"must be in (0, {MAX_PRECURVE_STRAIN:g}] (no tube "
                                                       f"survives more), got {max_strain:g}")
    snap_free = constraints.get("snap_free", True)
    if not isinstance(snap_free, bool):
        raise doc.error(("constraints", "snap_free"), f"expected true or false, got {snap_free!r}")
    budget = _mapping(doc, ("budget",), d.get("budget") or {}, {"trials", "plan_time_s", "plan_states"})
    trials = budget.get("trials", 60)
    if isinstance(trials, bool) or not isinstance(trials, int) or trials < 1:
        raise doc.error(("budget", "trials"), f"expected an integer >= 1, got {trials!r}")
    plan_time = _number(doc, ("budget", "plan_time_s"),
                        budget.get("plan_time_s", scene.settings.time_limit_s))
    if plan_time <= 0:
        raise doc.error(("budget", "plan_time_s"), f"must be > 0, got {plan_time:g}")
    plan_states = budget.get("plan_states")
    if plan_states is not None and (isinstance(plan_states, bool) or not isinstance(plan_states, int)
                                    or plan_states < 1):
        raise doc.error(("budget", "plan_states"), f"expected an integer >= 1 (states), got {plan_states!r}")
    task = DesignTask(path=path, scene=scene, targets=targets, vary=vary, catalogue=catalogue,
                      max_strain=max_strain, snap_free=snap_free,
                      objectives=_objectives(doc, d.get("objectives", list(DEFAULT_OBJECTIVES))),
                      trials=int(trials), plan_time_s=plan_time, digest=_digest(doc, scene),
                      plan_states=plan_states)
    if catalogue and not task.diameter_sets:
        raise doc.error(("catalogue",), f"no {scene.robot.n_tubes} sizes of the catalogue nest (each "
                                        f"tube's outer diameter <= the next tube's inner diameter)")
    return task


# ---- parts ---------------------------------------------------------------------------------------
def _number(doc: YamlDoc, keys: tuple, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise doc.error(keys, f"expected a finite number, got {value!r}")
    return float(value)


def _mapping(doc: YamlDoc, keys: tuple, value: Any, allowed: set[str]) -> dict:
    if not isinstance(value, dict):
        raise doc.error(keys, f"expected a mapping, got {value!r}")
    for k in value:
        if k not in allowed:
            raise doc.error(keys + (k,), f"unknown key (allowed: {', '.join(sorted(allowed))})")
    return value


def _file(doc: YamlDoc, keys: tuple, value: Any, what: str) -> Path:
    """A file named relative to the task file."""
    if not isinstance(value, str) or not value:
        raise doc.error(keys, f"expected {what}, got {value!r}")
    p = Path(value)
    p = p if p.is_absolute() else doc.path.parent / p
    if not p.is_file():
        raise doc.error(keys, f"no such file: {p}")
    return p


def _with_robot(doc: YamlDoc, scene: Scene, spec: Any) -> Scene:
    """The scene with the task's base robot; its start must suit it."""
    source = spec if spec in BUILTIN_ROBOTS else _file(doc, ("robot",), spec, "a built-in robot name or a "
                                                                               "robot file")
    try:
        robot = Robot.load(source)
    except InputError as exc:
        raise doc.error(("robot",), str(exc)) from None
    try:
        robot.check_joints(scene.start, where="the scene's start")
    except InputError as exc:
        raise doc.error(("robot",), str(exc)) from None
    return replace(scene, robot=robot)


def _targets(doc: YamlDoc, raw: Any) -> tuple[NamedTarget, ...]:
    if not isinstance(raw, list) or not raw:
        raise doc.error(("targets",), "expected a non-empty list of named targets")
    out: list[NamedTarget] = []
    for i, item in enumerate(raw):
        keys = ("targets", i)
        if not isinstance(item, dict):
            raise doc.error(keys, f"expected a mapping with name and a region, got {item!r}")
        name = item.get("name")
        if not isinstance(name, str) or not _NAME.match(name):
            raise doc.error(keys + ("name",), f"expected a name of letters, digits, '_', '-', '.' (it "
                                              f"names a folder), got {name!r}")
        if any(t.name == name for t in out):
            raise doc.error(keys + ("name",), f"duplicate target name {name!r}")
        reason = item.get("reason", "")
        if not isinstance(reason, str):
            raise doc.error(keys + ("reason",), f"expected a string, got {reason!r}")
        region = target_from_yaml(doc, {k: v for k, v in item.items() if k not in ("name", "reason")}, keys)
        out.append(NamedTarget(name, region, reason.strip()))
    return tuple(out)


def _vary(doc: YamlDoc, raw: Any, robot: Robot) -> tuple[Vary, ...]:
    if not isinstance(raw, dict):
        raise doc.error(("vary",), f"expected a mapping of tube index -> field -> [min, max], got {raw!r}")
    out = []
    for key, fields in raw.items():
        keys = ("vary", str(key))
        tube = int(key) if isinstance(key, int) or (isinstance(key, str) and key.isdigit()) else None
        if tube is None or not 1 <= tube <= robot.n_tubes:
            raise doc.error(keys, f"expected a tube index 1..{robot.n_tubes} (1 = innermost), got {key!r}")
        fields = _mapping(doc, keys, fields, set(VARY_FIELDS))
        for field, value in fields.items():
            k = keys + (field,)
            if not isinstance(value, list) or len(value) != 2:
                raise doc.error(k, f"expected a range [min, max], got {value!r}")
            lo, hi = (_number(doc, k + (j,), v) for j, v in enumerate(value))
            if lo > hi:
                raise doc.error(k, f"min {lo:g} exceeds max {hi:g}")
            low, high, why = TUBE_LIMITS[field]
            if lo < low or hi > high:
                raise doc.error(k, f"[{lo:g}, {hi:g}] leaves the physical range [{low:g}, {high:g}] ({why})")
            out.append(Vary(tube, field, lo, hi))
    return tuple(sorted(out, key=lambda v: (v.tube, VARY_FIELDS.index(v.field))))


def _catalogue(doc: YamlDoc, raw: Any) -> tuple[StockSize, ...]:
    if not isinstance(raw, list):
        raise doc.error(("catalogue",), f"expected a list of stock sizes, got {raw!r}")
    sizes = []
    allowed = {"inner_diameter_mm", "outer_diameter_mm"}
    for i, item in enumerate(raw):
        keys = ("catalogue", i)
        item = _mapping(doc, keys, item, allowed)
        values = {}
        for k in sorted(allowed):
            if k not in item:
                raise doc.error(keys, f"missing required key {k!r}")
            values[k] = _number(doc, keys + (k,), item[k])
            low, high, why = TUBE_LIMITS[k]
            if not low <= values[k] <= high:
                raise doc.error(keys + (k,), f"{values[k]:g} is outside the physical range [{low:g}, "
                                             f"{high:g}] ({why})")
        if values["inner_diameter_mm"] >= values["outer_diameter_mm"]:
            raise doc.error(keys, "inner diameter must be < outer diameter")
        size = StockSize(**values)
        if size in sizes:
            raise doc.error(keys, f"duplicate size {size.label} mm")
        sizes.append(size)
    return tuple(sorted(sizes, key=lambda s: (s.outer_diameter_mm, s.inner_diameter_mm)))


def _objectives(doc: YamlDoc, raw: Any) -> tuple[Objective, ...]:
    keys = ("objectives",)
    if not isinstance(raw, list) or not raw:
        raise doc.error(keys, "expected a list of objectives, targets_reached first")
    out: list[Objective] = []
    for i, item in enumerate(raw):
        name = item.removeprefix("-") if isinstance(item, str) else None
        if name not in OBJECTIVES:
            raise doc.error(keys + (i,), f"unknown objective {item!r} (choose from "
                                         f"{', '.join(OBJECTIVES)}; '-' in front minimises)")
        if any(o.name == name for o in out):
            raise doc.error(keys + (i,), f"objective {name!r} given twice")
        out.append(Objective(name, not item.startswith("-")))
    if out[0] != Objective("targets_reached"):
        raise doc.error(keys, "the first objective must be targets_reached (maximised)")
    return tuple(out)


def _digest(doc: YamlDoc, scene: Scene) -> str:
    """What decides a design's evaluation: the task (its trial budget aside), the scene file and the
    base robot. A study continues only under the same digest."""
    data = {k: v for k, v in doc.data.items() if k != "budget"}
    budget = doc.data.get("budget") or {}
    data["plan_time_s"] = budget.get("plan_time_s")
    if "plan_states" in budget:
        data["plan_states"] = budget["plan_states"]
    text = json.dumps(_str_keys(data), sort_keys=True) + (scene.path.read_text() if scene.path else "")
    return hashlib.sha256((text + scene.robot.fingerprint).encode()).hexdigest()


def _str_keys(x: Any) -> Any:
    """``x`` with every mapping key a string (YAML allows ``1:`` next to ``"2":``)."""
    if isinstance(x, dict):
        return {str(k): _str_keys(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_str_keys(v) for v in x]
    return x
