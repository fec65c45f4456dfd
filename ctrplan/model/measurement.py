"""`Calibration`: the measurement side of a robot model -- how what the robot reports and what the
tracker sees relate to its mechanics.

"Calibration" in ctrplan means two things, kept apart by their names:

* the package `ctrplan.calibration` *calibrates* a robot model from measured tips (``ctrplan
  diagnose``): it extends the mechanics (`Robot` fields) and this measurement side;
* `Robot.calibration` (this class; the robot file's ``calibration`` key) *is* the measurement side
  of one robot: the `ctrplan.model.causes.measurement_side.MeasurementEffect` terms it holds, each with its
  values.

A prediction for measured rows, for any backend, takes three steps:

1. `Calibration.mechanics_joints` -- reported joints (rows in acquisition order, with their motion
   history, `ctrplan.model.motion.Motion`) -> the joints the mechanics sees (latency, backlash,
   friction, torsional windup);
2. the pure mechanics (`Robot.mechanics`, its joint offsets included) solves them;
3. `Calibration.tracked_tips` -- the solved tube tips in the robot frame (and the tip frame of tube 1
   where `needs_tip_rotation`: a sensor offset) -> what the tracker sees (registration).

In a robot file each term is one key of the ``calibration`` mapping (see each effect's ``key``)::

    calibration:
      latency_rows: t
      backlash_rad: [b1, ..., bN]
      friction: {radii: [...], weights: [[...], ...]}      # see `Friction`
      windup_rad_per_mm: [w1, ..., wN]
      sensor_offset_mm: [dx, dy, dz]
      registration: {rotation_vector_rad: [rx, ry, rz], translation_mm: [tx, ty, tz]}
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.spatial.transform import Rotation

from ctrplan.base.errors import InputError
from ctrplan.base.yamlio import YamlDoc
from ctrplan.model.causes.base import EFFECTS, SIDES
from ctrplan.model.causes.measurement_side import MeasurementEffect
from ctrplan.model.motion import Motion

if TYPE_CHECKING:
    from ctrplan.kinematics.backbone import Backbone

CALIBRATION_KEY = "calibration"
#: The measurement-side effects by their robot-file key.
_BY_KEY = {e.key: e() for e in EFFECTS.values() if issubclass(e, MeasurementEffect)}


@dataclass(frozen=True)
class Calibration:
    """The measurement-side terms of a robot: (cause name, values) pairs, in the order their sides
    act (joints, tip, frame), zero terms left out -- the identity has none.

    Build it with `with_term`; read it with `values`.
    """

    terms: tuple[tuple[str, tuple[float, ...]], ...] = ()

    def __post_init__(self) -> None:
        for name, _ in self.terms:
            if not issubclass(EFFECTS.get(name, object), MeasurementEffect):
                raise ValueError(f"{name!r} is not a measurement-side effect")
        order = {name: (SIDES.index(e.side), i) for i, (name, e) in enumerate(EFFECTS.items())}
        object.__setattr__(self, "terms", tuple(sorted(self.terms, key=lambda t: order[t[0]])))

    def values(self, name: str, size: int) -> np.ndarray:
        """The values of term ``name`` (zeros of ``size`` if absent)."""
        found = dict(self.terms).get(name)
        return np.zeros(size) if found is None else np.array(found, dtype=float)

    def with_term(self, name: str, values) -> Calibration:
        """This calibration with term ``name`` set to ``values`` (removed when all zero)."""
        rest = tuple(t for t in self.terms if t[0] != name)
        vals = tuple(float(v) for v in values)
        return Calibration(rest + ((name, vals),) if any(vals) else rest)

    def without(self, side: str) -> Calibration:
        """This calibration without its terms of ``side`` (joints, tip or frame)."""
        return Calibration(tuple((n, v) for n, v in self.terms if EFFECTS[n].side != side))

    @property
    def is_identity(self) -> bool:
        return not self.terms

    def _side(self, side: str):
        for name, vals in self.terms:
            effect = EFFECTS[name]()
            if effect.side == side:
                yield effect, np.array(vals)

    # ---- the maps a prediction applies --------------------------------------------------------------
    def mechanics_joints(self, q: np.ndarray, motion: Motion | None = None) -> np.ndarray:
        """The joints the mechanics sees (B, 2N), mm and rad, for reported joints q (B, 2N) in
        acquisition order. ``motion``: the rows' motion history (`Motion.of(q)` if None -- pass it when
        q is a subset of a longer sequence). The robot's joint offsets are not in it: the backends add
        them."""
        q = np.asarray(q, dtype=float)
        terms = list(self._side("joints"))
        if not terms:
            return q
        m = Motion.of(np.atleast_2d(q)) if motion is None else motion
        out = np.atleast_2d(q)
        for effect, vals in terms:
            out = effect.joints(vals, out, m)
        return out.reshape(q.shape)

    @property
    def needs_tip_rotation(self) -> bool:
        """Whether `tracked_tips` needs the tip frame of tube 1 (a sensor offset)."""
        return any(True for _ in self._side("tip"))

    def tracked_tips(self, robot_tips_mm: np.ndarray, tip_rotation: np.ndarray | None = None) -> np.ndarray:
        """What the tracker sees (B, T, 3), mm, from the solved tube tips (B, T, 3) in the robot frame
        and, where `needs_tip_rotation`, the tip frame R(l1) of tube 1 (B, 3, 3)."""
        tips = np.asarray(robot_tips_mm, dtype=float)
        for effect, vals in self._side("tip"):
            if tip_rotation is None:
                raise ValueError(f"the {effect.name} of this calibration needs the tip rotation of tube 1")
            tips = effect.tips(vals, tips, tip_rotation)
        return self.to_tracker_frame(tips)

    def to_tracker_frame(self, points_mm: np.ndarray) -> np.ndarray:
        """Robot-frame points (..., 3) -> the tracker frame (the frame side only)."""
        p = np.asarray(points_mm, dtype=float)
        for effect, vals in self._side("frame"):
            p = effect.frame(vals, p)
        return p

    def to_robot_frame(self, points_mm: np.ndarray) -> np.ndarray:
        """Tracker-frame points (..., 3) -> the robot frame (the inverse of `to_tracker_frame`)."""
        p = np.asarray(points_mm, dtype=float)
        for effect, vals in reversed(list(self._side("frame"))):
            p = effect.frame(vals, p, inverse=True)
        return p

    def apply(self, backbone: Backbone) -> Backbone:
        """The extended model's prediction of a `Backbone` solved at `mechanics_joints`: tips as the
        tracker sees them, positions and orientations in the tracker frame. The state's moments, twists
        and angles are frame-independent and kept."""
        frames = list(self._side("frame"))
        if not frames and not self.needs_tip_rotation:
            return backbone
        tips = self.tracked_tips(backbone.tips_mm, backbone.rotations[:, -1])
        state = np.array(backbone.state, copy=True)
        ip = 2 * backbone.n_tubes + 2  # position p, then the orientation quaternion (last 4)
        state[..., ip:ip + 3] = self.to_tracker_frame(state[..., ip:ip + 3])
        for effect, vals in frames:
            quat = state[..., -4:].reshape(-1, 4)
            ok = np.isfinite(quat).all(1)
            out = np.full_like(quat, np.nan)
            turn = Rotation.from_matrix(effect.frame_rotation(vals))
            out[ok] = (turn * Rotation.from_quat(quat[ok][:, [1, 2, 3, 0]])).as_quat()[:, [3, 0, 1, 2]]
            state[..., -4:] = out.reshape(state[..., -4:].shape)
        return replace(backbone, state=state, tips_mm=tips)

    def refuse(self, robot_name: str, verb: str) -> None:
        """`InputError` for work that models the mechanics only (``verb``: plan, train) when this
        calibration is not the identity -- it would otherwise be ignored silently."""
        if not self.is_identity:
            names = ", ".join(name.replace("_", " ") for name, _ in self.terms)
            raise InputError(
                f"robot {robot_name!r}: its calibration section ({names}) describes how it is measured and "
                f"cannot be used to {verb}; delete that section from the robot file to {verb} with its "
                f"mechanics (curvatures, stiffnesses, offsets)")

    # ---- the robot file -------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """The ``calibration`` mapping of a robot file: one key per term."""
        return {EFFECTS[name].key: EFFECTS[name]().write(vals) for name, vals in self.terms}

    @classmethod
    def from_doc(cls, doc: YamlDoc, n_tubes: int) -> Calibration:
        """The validated `Calibration` of a parsed robot file of ``n_tubes`` tubes."""
        raw = doc.data.get(CALIBRATION_KEY)
        keys = (CALIBRATION_KEY,)
        if raw is None:
            return cls()
        if not isinstance(raw, dict):
            raise doc.error(keys, f"expected a mapping with some of the keys {', '.join(_BY_KEY)}")
        out = cls()
        for k, value in raw.items():
            effect = _BY_KEY.get(k)
            if effect is None:
                allowed = ", ".join(sorted(_BY_KEY))
                raise doc.error(keys + (k,), f"unknown key (allowed: {allowed})")
            out = out.with_term(effect.name, effect.read(doc, keys + (k,), value, n_tubes))
        return out
