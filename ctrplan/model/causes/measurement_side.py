"""Causes on the measurement side -- reported joints (backlash, windup), the tracked point (sensor
offset) and the tracker frame (registration): terms of a robot's `ctrplan.model.measurement.Calibration`.
"""

from __future__ import annotations

import math
from abc import abstractmethod
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.spatial.transform import Rotation

from ctrplan.model.causes.base import Check, Effect, Param, Plausible, _never_reverses, kabsch, numbers

if TYPE_CHECKING:
    from ctrplan.base.yamlio import KeyPath, YamlDoc
    from ctrplan.model.robot import Robot


class MeasurementEffect(Effect):
    """An effect of the measurement side (joints, tip or frame): a term of the robot's
    `ctrplan.model.measurement.Calibration`, kept under ``calibration.<key>`` in the robot file.

    Subclasses define the map of their side: `joints` (reported joints -> the joints the mechanics
    sees), `tips` (tip side: solved tips -> tracked point) or `frame` (robot -> tracker frame)."""

    @abstractmethod
    def size(self, n_tubes: int) -> int:
        """Number of values for a robot of ``n_tubes`` tubes."""

    def values(self, robot):
        return robot.calibration.values(self.name, self.size(robot.n_tubes))

    def with_values(self, robot, x):
        return robot.with_changes(calibration=robot.calibration.with_term(self.name, x))

    # ---- the robot file -------------------------------------------------------------------------
    def write(self, values: tuple[float, ...]) -> Any:
        """The file form of ``values`` (under ``calibration.<key>``)."""
        return [float(v) for v in values]

    def read(self, doc: YamlDoc, keys: KeyPath, raw: Any, n_tubes: int) -> tuple[float, ...]:
        """Validated values from the file form ``raw`` at ``keys`` of a robot of ``n_tubes`` tubes."""
        return numbers(doc, keys, raw, self.size(n_tubes))

    # ---- the maps of each side ------------------------------------------------------------------
    def joints(self, values: np.ndarray, q: np.ndarray, direction: np.ndarray) -> np.ndarray:
        """Joints side: reported joints q (B, 2N) in acquisition order, their directions of motion
        (B, 2N) -> the joints the mechanics sees (B, 2N)."""
        raise NotImplementedError

    def tips(self, values: np.ndarray, tips_mm: np.ndarray, tip_rotation: np.ndarray) -> np.ndarray:
        """Tip side: solved tips (B, T, 3) mm and the tip frame of tube 1 (B, 3, 3) -> tracked tips."""
        raise NotImplementedError

    def frame(self, values: np.ndarray, points_mm: np.ndarray, inverse: bool = False) -> np.ndarray:
        """Frame side: robot-frame points (..., 3) -> tracker frame (or back, with ``inverse``)."""
        raise NotImplementedError

    def frame_rotation(self, values: np.ndarray) -> np.ndarray:
        """Frame side: the rotation (3, 3) of the frame map (for orientations)."""
        raise NotImplementedError


class Backlash(MeasurementEffect):
    name = "backlash"
    side = "joints"
    key = "backlash_rad"
    description = "lag of alpha_i (rad) in the direction of its latest motion"
    SOURCE = ("gear, belt and collet transmissions of rotary stages: a fraction of a degree to a few "
              "degrees; 0.1 rad (5.7 deg) ceiling")

    def size(self, n_tubes):
        return n_tubes

    def params(self, robot):
        return [Param(f"backlash{i + 1}_rad", "rad", 0.03, 0.0, 0.5, Plausible(0.0, 0.1, self.SOURCE))
                for i in range(robot.n_tubes)]

    def unseen(self, q, direction, robot):
        return {f"backlash{i + 1}_rad": reason for i, reason in _never_reverses(direction, robot.n_tubes)}

    def joints(self, values, q, direction):
        n = q.shape[-1] // 2
        out = np.array(q, dtype=float, copy=True)
        out[..., n:] -= np.asarray(values) * direction[..., n:]
        return out

    def derived(self, robot, x):
        return {f"backlash{i + 1}_deg": float(np.degrees(v)) for i, v in enumerate(x)}


class TorsionalWindup(MeasurementEffect):
    name = "torsional_windup"
    side = "joints"
    key = "windup_rad_per_mm"
    description = ("friction twists tube i behind the plate: a lag of alpha_i growing with -beta_i, windup_i"
                   " (rad/mm) = friction torque / (G J_i)")
    MAX_TORQUE_NMM = 5.0
    SOURCE = ("friction between nested tubes (mu ~ 0.1-0.3, Lock & Dupont 2011) and seals on a lever of "
              "the tube radius: at most a few N mm; friction torque ceiling 5 N mm")

    def size(self, n_tubes):
        return n_tubes

    def params(self, robot):
        out = []
        for i, t in enumerate(robot.tubes):
            high = self.MAX_TORQUE_NMM / t.torsional_stiffness_nmm2
            out.append(Param(f"windup{i + 1}_rad_per_mm", "rad/mm", 0.01 * high, 0.0, 4.0 * high,
                             Plausible(0.0, high, f"{self.SOURCE}, i.e. {high:.3g} rad/mm for tube {i + 1}")))
        return out

    def unseen(self, q, direction, robot):
        n = robot.n_tubes
        why: dict[int, list[str]] = {
            i: [f"beta{i + 1} never moves, so a windup of tube {i + 1} is a constant lag of alpha{i + 1}: "
                f"backlash"] for i in range(n) if np.ptp(q[:, i]) <= 1e-9}
        for i, reason in _never_reverses(direction, n):
            why.setdefault(i, []).append(reason)
        return {f"windup{i + 1}_rad_per_mm": "; ".join(reasons) for i, reasons in sorted(why.items())}

    def joints(self, values, q, direction):
        n = q.shape[-1] // 2
        out = np.array(q, dtype=float, copy=True)
        out[..., n:] -= np.asarray(values) * -q[..., :n] * direction[..., n:]
        return out

    def derived(self, robot, x):
        return {f"friction_torque{i + 1}_nmm": float(v) * t.torsional_stiffness_nmm2
                for i, (t, v) in enumerate(zip(robot.tubes, x, strict=True))}


class SensorOffset(MeasurementEffect):
    name = "sensor_offset"
    side = "tip"
    key = "sensor_offset_mm"
    description = "tracked point relative to the tip of tube 1, in its tip frame R(l1) (mm)"
    #: A coil sensor (NDI Aurora: 0.3-0.8 mm diameter, 8-13 mm long) inside or on the tip of tube 1.
    SENSOR_DIAMETER_MM, MAX_ALONG_MM = 1.0, 15.0
    SOURCE = ("a coil sensor (NDI Aurora: 0.3-0.8 mm diameter, 8-13 mm long) inside or on the tip of "
              "tube 1: to the side at most the tube radius plus 1 mm, along the tip at most 15 mm")

    def size(self, n_tubes):
        return 3

    def side_max(self, robot: Robot) -> float:
        """The farthest the tracked point can sit to the side of the tip of tube 1, mm."""
        return robot.tubes[0].outer_radius_mm + self.SENSOR_DIAMETER_MM

    def params(self, robot):
        side, along = self.side_max(robot), self.MAX_ALONG_MM
        return [Param(f"sensor_offset_{a}_mm", "mm", 1.0, -20.0, 20.0, Plausible(-r, r, self.SOURCE))
                for a, r in zip("xyz", (side, side, along), strict=True)]

    def checks(self, robot):
        side = Check("sensor_offset_side_mm", "mm", lambda x: float(np.hypot(x[0], x[1])),
                     Plausible(0.0, self.side_max(robot), self.SOURCE))
        return super().checks(robot) + [side]

    def draw(self, robot, rng):
        side = rng.normal(size=2)
        return np.r_[side / np.linalg.norm(side) * rng.uniform(0.0, 0.4), rng.uniform(2.0, 6.0)]

    def tips(self, values, tips_mm, tip_rotation):
        out = np.array(tips_mm, dtype=float, copy=True)
        out[:, 0] += np.asarray(tip_rotation) @ np.asarray(values, dtype=float)
        return out

    def derived(self, robot, x):
        return {"sensor_offset_mm": float(np.linalg.norm(x)),
                "sensor_offset_side_mm": float(np.hypot(x[0], x[1]))}


class Registration(MeasurementEffect):
    name = "registration"
    side = "frame"
    key = "registration"
    description = "rotation vector (rad) and translation (mm), robot -> tracker frame"
    KEYS = ("rotation_vector_rad", "translation_mm")
    SOURCE = ("the tracker frame may have any orientation; it lies within the tracking volume (NDI Aurora "
              "planar field generator: a 500 mm cube)")

    def size(self, n_tubes):
        return 6

    def params(self, robot):
        return [Param(f"rotation_{a}_rad", "rad", 0.02, plausible=Plausible(-math.pi, math.pi, self.SOURCE))
                for a in "xyz"] + \
               [Param(f"translation_{a}_mm", "mm", 1.0, plausible=Plausible(-500.0, 500.0, self.SOURCE))
                for a in "xyz"]

    def write(self, values):
        return {k: [float(v) for v in values[3 * i:3 * i + 3]] for i, k in enumerate(self.KEYS)}

    def read(self, doc, keys, raw, n_tubes):
        if not isinstance(raw, dict):
            raise doc.error(keys, f"expected a mapping with {' and/or '.join(self.KEYS)}")
        for k in raw:
            if k not in self.KEYS:
                raise doc.error(keys + (k,), f"unknown key (allowed: {', '.join(self.KEYS)})")
        return tuple(v for k in self.KEYS
                     for v in (numbers(doc, keys + (k,), raw[k], 3) if k in raw else (0.0,) * 3))

    def frame_rotation(self, values):
        return Rotation.from_rotvec(np.asarray(values[:3], dtype=float)).as_matrix()

    def frame(self, values, points_mm, inverse=False):
        R, t = self.frame_rotation(values), np.asarray(values[3:6], dtype=float)
        p = np.asarray(points_mm, dtype=float)
        return (p - t) @ R if inverse else p @ R.T + t

    def initial_guess(self, robot, predicted, measured):
        R, t = kabsch(predicted, measured)
        return np.concatenate([Rotation.from_matrix(R).as_rotvec(), t])

    def derived(self, robot, x):
        return {"rotation_deg": float(np.degrees(np.linalg.norm(x[:3]))),
                "translation_mm": float(np.linalg.norm(x[3:6]))}
