"""`Calibration`: the measurement side of a robot model -- how what the robot reports and what the
tracker sees relate to its mechanics.

"Calibration" in ctrplan means two things, kept apart by their names:

* the package `ctrplan.calibration` *calibrates* a robot model from measured tips (``ctrplan
  diagnose``): it extends the mechanics (`Robot` fields) and this measurement side;
* `Robot.calibration` (this class; the robot file's ``calibration`` key) *is* the measurement side
  of one robot: the `ctrplan.model.causes.measurement_side.MeasurementEffect` terms it holds, each with its
  values.

A prediction for measured rows, for any backend, takes three steps:

1. `Calibration.mechanics_joints` -- reported joints (rows in acquisition order, with their direction
   of motion, `motion_direction`) -> the joints the mechanics sees (backlash, torsional windup);
2. the pure mechanics (`Robot.mechanics`, its joint offsets included) solves them;
3. `Calibration.tracked_tips` -- the solved tube tips in the robot frame (and the tip frame of tube 1
   where `needs_tip_rotation`: a sensor offset) -> what the tracker sees (registration).

In a robot file each term is one key of the ``calibration`` mapping (see each effect's ``key``)::

    calibration:
      backlash_rad: [b1, ..., bN]
      windup_rad_per_mm: [w1, ..., wN]
      sensor_offset_mm: [dx, dy, dz]
      registration: {rotation_vector_rad: [rx, ry, rz], translation_mm: [tx, ty, tz]}
      lag_correction: {radii_rad: [r1, ..., rK], weights_rad: [[w11, ..., w1K], ..., [wN1, ..., wNK]]}

``lag_correction`` is not a cause of `ctrplan diagnose` but learned from the shots by `ctrplan train
--measured` (`LagCorrection`): the lag of the rotation joints after a reversal, which backlash (an
instant flip) does not describe.
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

if TYPE_CHECKING:
    from ctrplan.kinematics.backbone import Backbone

CALIBRATION_KEY = "calibration"
LAG_KEY = "lag_correction"
#: The measurement-side effects by their robot-file key.
_BY_KEY = {e.key: e() for e in EFFECTS.values() if issubclass(e, MeasurementEffect)}


@dataclass(frozen=True)
class Calibration:
    """The measurement-side terms of a robot: (cause name, values) pairs, in the order their sides
    act (joints, tip, frame), zero terms left out -- the identity has none.

    Build it with `with_term`; read it with `values`.
    """

    terms: tuple[tuple[str, tuple[float, ...]], ...] = ()
    lag: LagCorrection | None = None    # learned by `ctrplan train --measured`, applied after the terms

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
        return Calibration(rest + ((name, vals),) if any(vals) else rest, self.lag)

    def with_lag(self, lag: LagCorrection | None) -> Calibration:
        """This calibration with the learned lag correction ``lag`` (None: without one)."""
        return Calibration(self.terms, lag)

    @property
    def is_identity(self) -> bool:
        return not self.terms and self.lag is None

    def _side(self, side: str):
        for name, vals in self.terms:
            effect = EFFECTS[name]()
            if effect.side == side:
                yield effect, np.array(vals)

    # ---- the maps a prediction applies --------------------------------------------------------------
    def mechanics_joints(self, q: np.ndarray, direction: np.ndarray | None = None) -> np.ndarray:
        """The joints the mechanics sees (B, 2N), mm and rad, for reported joints q (B, 2N) in
        acquisition order. ``direction`` (B, 2N): each row's direction of motion (`motion_direction(q)`
        if None -- pass it when q is a subset of a longer sequence). The robot's joint offsets are not
        in it: the backends add them."""
        q = np.asarray(q, dtype=float)
        terms = list(self._side("joints"))
        if not terms and self.lag is None:
            return q
        d = motion_direction(np.atleast_2d(q)).reshape(q.shape) if direction is None \
            else np.asarray(direction)
        out = q
        for effect, vals in terms:
            out = effect.joints(vals, out, d)
        return out if self.lag is None else self.lag.joints(q, d, out)

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
            names = ", ".join([name.replace("_", " ") for name, _ in self.terms]
                              + (["learned lag correction"] if self.lag is not None else []))
            raise InputError(
                f"robot {robot_name!r}: its calibration section ({names}) describes how it is measured and "
                f"cannot be used to {verb}; delete that section from the robot file to {verb} with its "
                f"mechanics (curvatures, stiffnesses, offsets)")

    # ---- the robot file -------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """The ``calibration`` mapping of a robot file: one key per term."""
        out = {EFFECTS[name].key: EFFECTS[name]().write(vals) for name, vals in self.terms}
        return out if self.lag is None else {**out, LAG_KEY: self.lag.to_dict()}

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
            if k == LAG_KEY:
                out = out.with_lag(LagCorrection.from_doc(doc, keys + (k,), value, n_tubes))
                continue
            effect = _BY_KEY.get(k)
            if effect is None:
                allowed = ", ".join(sorted([*_BY_KEY, LAG_KEY]))
                raise doc.error(keys + (k,), f"unknown key (allowed: {allowed})")
            out = out.with_term(effect.name, effect.read(doc, keys + (k,), value, n_tubes))
        return out


def motion_direction(q: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """Direction of the latest motion of every joint (R, 2N) in {-1, 0, +1}, from consecutive rows.

    A joint that did not move keeps the direction of its last move (a backlash gap stays taken up on
    the side it was last driven); before its first move the direction is 0.
    """
    q = np.asarray(q, dtype=float)
    d = np.zeros_like(q)
    step = np.diff(q, axis=0)
    cur = np.zeros(q.shape[1])
    for r in range(1, len(q)):
        s = step[r - 1]
        moved = np.abs(s) > tol
        cur = np.where(moved, np.sign(s), cur)
        d[r] = cur
    return d


def play_features(x: np.ndarray, radii_rad, direction: np.ndarray) -> np.ndarray:
    """Normalised lags (R, C, K) of play (backlash) operators of half-widths ``radii_rad`` (K,) behind
    the commanded angles x (R, C) in acquisition order: the operator's output follows x only when x is
    more than r away (y_k = clip(y_(k-1), x_k - r, x_k + r), y_0 = x_0: no lag before the first move)
    and the feature is (x - y) / r, in [-1, 1]; r = 0 gives ``direction`` (R, C), the direction of
    motion. These are the inputs of a Prandtl-Ishlinskii hysteresis model."""
    x = np.asarray(x, dtype=float)
    r = np.asarray(radii_rad, dtype=float)
    out = np.empty(x.shape + r.shape)
    y = np.repeat(x[:1, :, None], r.size, axis=-1) if len(x) else None
    for k in range(len(x)):
        y = np.clip(y, x[k, :, None] - r, x[k, :, None] + r)
        out[k] = (x[k, :, None] - y) / np.where(r > 0, r, 1.0)
    out[..., r == 0] = np.asarray(direction, dtype=float)[..., None]
    return out


@dataclass(frozen=True)
class LagCorrection:
    """A learned direction-dependent lag of the rotation joints (a Prandtl-Ishlinskii model, the
    standard model of actuator hysteresis): alpha_i reaches ``alpha_i - sum_k w_ik phi_ik``, where
    phi_ik are the `play_features` of the commanded alpha_i (radius 0: the direction of motion, i.e.
    backlash; larger radii: a lag that builds up over that much travel after a reversal). Rad.

    Learned from measured shots by `ctrplan train --measured` (`ctrplan.training.lag`); its inputs
    depend on the rows' order, so rows given together are one sequence (the first rows of a sequence
    have no history: lag 0 until each joint has moved)."""

    radii_rad: tuple[float, ...]
    weights_rad: tuple[tuple[float, ...], ...]     # (N, K): one row per rotation joint

    def lag_rad(self, q: np.ndarray, direction: np.ndarray) -> np.ndarray:
        """The lag (R, N) rad of each rotation joint for reported joints q (R, 2N) in acquisition
        order with their ``direction`` of motion (R, 2N)."""
        n = q.shape[-1] // 2
        phi = play_features(q[:, n:], self.radii_rad, direction[:, n:])
        return np.einsum("rik,ik->ri", phi, np.asarray(self.weights_rad))

    def joints(self, q: np.ndarray, direction: np.ndarray, mechanics_q: np.ndarray) -> np.ndarray:
        """``mechanics_q`` (R, 2N) with the lag of the commanded sequence q (R, 2N) subtracted from the
        rotations."""
        q2 = np.atleast_2d(q)
        out = np.array(np.atleast_2d(mechanics_q), dtype=float, copy=True)
        n = q2.shape[-1] // 2
        out[:, n:] -= self.lag_rad(q2, np.atleast_2d(direction).reshape(q2.shape))
        return out.reshape(np.shape(mechanics_q))

    def to_dict(self) -> dict[str, Any]:
        return {"radii_rad": list(self.radii_rad), "weights_rad": [list(w) for w in self.weights_rad]}

    @classmethod
    def from_doc(cls, doc: YamlDoc, keys: tuple, value: Any, n_tubes: int) -> LagCorrection:
        """The correction of a robot file's ``lag_correction`` mapping (validated)."""
        if not isinstance(value, dict) or set(value) != {"radii_rad", "weights_rad"}:
            raise doc.error(keys, "expected a mapping with the keys radii_rad and weights_rad")
        radii, weights = value["radii_rad"], value["weights_rad"]
        try:
            r = np.array(radii, dtype=float)
            w = np.array(weights, dtype=float)
        except (TypeError, ValueError):
            raise doc.error(keys, "radii_rad and weights_rad must be numbers") from None
        if r.ndim != 1 or not r.size or not np.isfinite(r).all() or (r < 0).any():
            raise doc.error(keys + ("radii_rad",), "expected a list of finite numbers >= 0 (rad)")
        if w.shape != (n_tubes, r.size) or not np.isfinite(w).all():
            raise doc.error(keys + ("weights_rad",), f"expected {n_tubes} lists of {r.size} finite "
                                                     f"numbers (rad), one per tube")
        return cls(tuple(r.tolist()), tuple(tuple(row) for row in w.tolist()))
