"""`Calibration`: the measurement-side model extensions that are not mechanics.

Mechanical extensions (curvature, stiffness ratio, bending stiffness, joint offsets, gravity, tip
force) are plain `Robot` parameters solved by the Cosserat backend. Three effects found in measured
data are not mechanics:

* registration -- the rigid transform between the robot frame and the frame the tips were measured
  in: ``p_measured = R(rotation_vector) p_robot + translation``;
* backlash -- a direction-dependent lag of the rotation joints: the tube turns to
  ``alpha_i - backlash_i * d_i``, with ``d_i`` in {-1, 0, +1} the direction of the latest motion of
  alpha_i (from consecutive rows, `motion_direction`);
* torsional windup -- friction torque tau_i on tube i twists the length behind the front plate
  (-beta_i, mm) against the motion: a further lag ``windup_i * (-beta_i) * d_i`` with
  ``windup_i = tau_i / (G J_i)`` (rad/mm);
* sensor offset -- the tracked point sits ``d`` (mm) from the tip of tube 1, fixed in the tip frame
  ``R(l1)`` of the Cosserat state: ``p_tracked = p(l1) + R(l1) d``.

`Calibration.apply` turns a solved `Backbone` into what the extended model predicts the tracker sees
(``ctrplan fk``/``shape`` use it); `Calibration.effective_joints` gives the joints to solve.

It is part of the robot model (`ctrplan.robot.Robot.calibration`); `ctrplan.calibration` fits it to
measured data. In a robot file it is the top-level mapping::

    calibration:
      registration: {rotation_vector_rad: [rx, ry, rz], translation_mm: [tx, ty, tz]}
      backlash_rad: [b1, b2, b3]
      sensor_offset_mm: [dx, dy, dz]
      windup_rad_per_mm: [w1, w2, w3]
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.spatial.transform import Rotation

from ctrplan.errors import InputError
from ctrplan.yamlio import YamlDoc

if TYPE_CHECKING:
    from ctrplan.kinematics.backbone import Backbone

CALIBRATION_KEY = "calibration"


def per_tube(values, n: int) -> np.ndarray:
    """A per-tube calibration vector (any length; missing tubes 0) as n values."""
    out = np.zeros(n)
    m = min(n, len(values))
    out[:m] = np.asarray(values, dtype=float)[:m]
    return out


@dataclass(frozen=True)
class Calibration:
    """Registration (robot frame -> measurement frame), backlash of alpha_1..N, sensor offset.

    Attributes:
        rotation_vector_rad: axis * angle of the registration rotation R (rad).
        translation_mm: registration translation t (mm).
        backlash_rad: lag of alpha_1..N behind the command in the direction of motion (rad).
        sensor_offset_mm: tracked point relative to the tip of tube 1, in the tip frame R(l1) (mm).
        windup_rad_per_mm: torsional windup of alpha_1..N per mm of tube behind the plate (rad/mm).
    """

    rotation_vector_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    translation_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    backlash_rad: tuple[float, ...] = (0.0, 0.0, 0.0)
    sensor_offset_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    windup_rad_per_mm: tuple[float, ...] = (0.0, 0.0, 0.0)

    def refuse(self, robot_name: str, verb: str) -> None:
        """`InputError` for work that models the mechanics only (``verb``: plan, train) when this
        calibration is not the identity -- it would otherwise be ignored silently."""
        if not self.is_identity:
            raise InputError(
                f"robot {robot_name!r}: its calibration section (registration, sensor offset, backlash, "
                f"windup) describes how it is measured and cannot be used to {verb}; delete that section "
                f"from the robot file to {verb} with its mechanics (curvatures, stiffnesses, offsets)")

    @property
    def is_identity(self) -> bool:
        return not any(self.rotation_vector_rad) and not any(self.translation_mm) \
            and not any(self.backlash_rad) and not any(self.sensor_offset_mm) \
            and not any(self.windup_rad_per_mm)

    @property
    def has_registration(self) -> bool:
        return any(self.rotation_vector_rad) or any(self.translation_mm)

    @property
    def rotation(self) -> np.ndarray:
        return Rotation.from_rotvec(np.asarray(self.rotation_vector_rad, dtype=float)).as_matrix()

    @property
    def registration_matrix(self) -> np.ndarray:
        """4x4 homogeneous transform taking robot-frame points (mm) to the measurement frame."""
        T = np.eye(4)
        T[:3, :3] = self.rotation
        T[:3, 3] = self.translation_mm
        return T

    def to_measurement_frame(self, points_mm: np.ndarray) -> np.ndarray:
        """Robot-frame points (..., 3) -> measurement frame."""
        if not self.has_registration:
            return np.asarray(points_mm, dtype=float)
        return np.asarray(points_mm) @ self.rotation.T + np.asarray(self.translation_mm)

    def to_robot_frame(self, points_mm: np.ndarray) -> np.ndarray:
        """Measured points (..., 3) -> robot frame (the inverse of `to_measurement_frame`)."""
        if not self.has_registration:
            return np.asarray(points_mm, dtype=float)
        return (np.asarray(points_mm) - np.asarray(self.translation_mm)) @ self.rotation

    def effective_joints(self, q: np.ndarray, direction: np.ndarray | None = None) -> np.ndarray:
        """Joints the tubes actually reach (B, 2N) for commanded joints q (B, 2N) in acquisition order.

        ``direction`` (B, 2N) is the direction of the latest motion (`motion_direction(q)` if None).
        """
        q = np.asarray(q, dtype=float)
        if not any(self.backlash_rad) and not any(self.windup_rad_per_mm):
            return q
        d = motion_direction(np.atleast_2d(q)) if direction is None else np.asarray(direction)
        n = q.shape[-1] // 2
        lag = per_tube(self.backlash_rad, n) + per_tube(self.windup_rad_per_mm, n) * -q[..., :n]
        out = np.array(q, dtype=float, copy=True)
        out[..., n:] -= lag * d[..., n:]
        return out

    def tracked_tips(self, robot_tips_mm: np.ndarray, tip_rotation: np.ndarray | None) -> np.ndarray:
        """What the tracker sees (B, T, 3), mm, measurement frame, from the solved tube tips (B, T, 3)
        in the robot frame and the tip frame of tube 1 ``tip_rotation`` (B, 3, 3)."""
        tips = np.asarray(robot_tips_mm, dtype=float)
        if any(self.sensor_offset_mm):
            tips = tips.copy()
            tips[:, 0] += np.asarray(tip_rotation) @ np.asarray(self.sensor_offset_mm, dtype=float)
        return self.to_measurement_frame(tips)

    def apply(self, backbone: Backbone) -> Backbone:
        """The extended model's prediction of a solved `Backbone` (solved at `effective_joints`):
        tips with the sensor offset, and positions, orientations and tips in the measurement frame.
        The state's moments, twists and angles are frame-independent and kept."""
        from dataclasses import replace as dc_replace

        if self.is_identity or not (self.has_registration or any(self.sensor_offset_mm)):
            return backbone
        rot = backbone.rotations
        tips = self.tracked_tips(backbone.tips_mm, rot[:, -1])
        state = np.array(backbone.state, copy=True)
        ip = 2 * backbone.n_tubes + 2  # position p, then the orientation quaternion (last 4)
        state[..., ip:ip + 3] = self.to_measurement_frame(state[..., ip:ip + 3])
        if self.has_registration:
            reg = Rotation.from_rotvec(np.asarray(self.rotation_vector_rad, dtype=float))
            q = state[..., -4:].reshape(-1, 4)
            ok = np.isfinite(q).all(1)
            quat = np.full_like(q, np.nan)
            xyzw = (reg * Rotation.from_quat(q[ok][:, [1, 2, 3, 0]])).as_quat()
            quat[ok] = xyzw[:, [3, 0, 1, 2]]
            state[..., -4:] = quat.reshape(state[..., -4:].shape)
        return dc_replace(backbone, state=state, tips_mm=tips)

    # ---- file format ------------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        out = {"registration": {"rotation_vector_rad": [float(v) for v in self.rotation_vector_rad],
                                "translation_mm": [float(v) for v in self.translation_mm]},
               "backlash_rad": [float(v) for v in self.backlash_rad]}
        # absent when unused: older files and fingerprints unchanged
        if any(self.sensor_offset_mm):
            out["sensor_offset_mm"] = [float(v) for v in self.sensor_offset_mm]
        if any(self.windup_rad_per_mm):
            out["windup_rad_per_mm"] = [float(v) for v in self.windup_rad_per_mm]
        return out

    @classmethod
    def from_doc(cls, doc: YamlDoc, keys: tuple = (CALIBRATION_KEY,)) -> Calibration:
        """Validated `Calibration` from the ``calibration`` mapping of a parsed robot file."""
        raw = doc.data.get(keys[0]) if len(keys) == 1 else None
        if raw is None:
            return cls()
        if not isinstance(raw, dict):
            raise doc.error(keys, "expected a mapping with 'registration' and/or 'backlash_rad'")
        for k in raw:
            if k not in ("registration", "backlash_rad", "sensor_offset_mm", "windup_rad_per_mm"):
                raise doc.error(keys + (k,), "unknown key (allowed: backlash_rad, registration, "
                                             "sensor_offset_mm, windup_rad_per_mm)")
        kw: dict[str, tuple] = {}
        reg = raw.get("registration")
        if reg is not None:
            if not isinstance(reg, dict):
                raise doc.error(keys + ("registration",), "expected a mapping with rotation_vector_rad "
                                                          "and translation_mm")
            for k in reg:
                if k not in ("rotation_vector_rad", "translation_mm"):
                    raise doc.error(keys + ("registration", k),
                                    "unknown key (allowed: rotation_vector_rad, translation_mm)")
            for k in ("rotation_vector_rad", "translation_mm"):
                if k in reg:
                    kw[k] = _vector3(doc, keys + ("registration", k), reg[k])
        if "backlash_rad" in raw:
            kw["backlash_rad"] = _vector3(doc, keys + ("backlash_rad",), raw["backlash_rad"])
        if "windup_rad_per_mm" in raw:
            kw["windup_rad_per_mm"] = _vector3(doc, keys + ("windup_rad_per_mm",), raw["windup_rad_per_mm"])
        if "sensor_offset_mm" in raw:
            kw["sensor_offset_mm"] = _vector3(doc, keys + ("sensor_offset_mm",), raw["sensor_offset_mm"])
        return cls(**kw)


def _vector3(doc: YamlDoc, keys: tuple, value: Any) -> tuple[float, float, float]:
    ok = isinstance(value, list) and len(value) == 3 and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)
    if not ok:
        raise doc.error(keys, f"expected a list of 3 finite numbers, got {value!r}")
    return tuple(float(v) for v in value)  # type: ignore[return-value]


def motion_direction(q: np.ndarray, tol: float = 1e-9) -> np.ndarray:
    """Direction of the latest motion of every joint (N, 6) in {-1, 0, +1}, from consecutive rows.

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
