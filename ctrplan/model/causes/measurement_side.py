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
from ctrplan.model.motion import joint_steps

if TYPE_CHECKING:
    from ctrplan.base.yamlio import KeyPath, YamlDoc
    from ctrplan.model.motion import Motion
    from ctrplan.model.robot import Robot


class MeasurementEffect(Effect):
    """An effect of the measurement side (joints, tip or frame): a term of the robot's
    `ctrplan.model.measurement.Calibration`, kept under ``calibration.<key>`` in the robot file.

    A cause derives from the class of its side, which declares the map it defines: `JointsEffect`
    (reported joints -> the joints the mechanics sees), `TipEffect` (solved tips -> tracked point) or
    `FrameEffect` (robot -> tracker frame)."""

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


class JointsEffect(MeasurementEffect):
    """An effect on the reported joints (`Calibration.joints`)."""

    side = "joints"

    @abstractmethod
    def joints(self, values: np.ndarray, q: np.ndarray, motion: Motion) -> np.ndarray:
        """Joints q (B, 2N) -- the reported ones, or what the terms before this one made of them -- of
        rows with the motion history ``motion`` (of the reported joints) -> the joints the mechanics
        sees (B, 2N)."""


class TipEffect(MeasurementEffect):
    """An effect on the tracked point (`Calibration.tips`)."""

    side = "tip"

    @abstractmethod
    def tips(self, values: np.ndarray, tips_mm: np.ndarray, tip_rotation: np.ndarray) -> np.ndarray:
        """Solved tips (B, T, 3) mm and the tip frame of tube 1 (B, 3, 3) -> tracked tips."""


class FrameEffect(MeasurementEffect):
    """An effect on the tracker frame (`Calibration.to_tracker`, `Calibration.from_tracker`)."""

    side = "frame"

    @abstractmethod
    def frame(self, values: np.ndarray, points_mm: np.ndarray, inverse: bool = False) -> np.ndarray:
        """Robot-frame points (..., 3) -> tracker frame (or back, with ``inverse``)."""

    @abstractmethod
    def frame_rotation(self, values: np.ndarray) -> np.ndarray:
        """The rotation (3, 3) of the frame map (for orientations)."""


class Latency(JointsEffect):
    name = "latency"
    key = "latency_rows"
    description = ("the tracker sees the robot where it was t sample intervals (rows) earlier: the joints "
                   "the mechanics sees are q - t (q - q_previous row)")
    MAX_ROWS = 2.0
    SOURCE = ("the tracker and the joint log run on separate clocks: an electromagnetic tracker delivers a "
              "pose tens of ms after it was taken, a drive reaches a commanded joint a servo period or two "
              "later, a log that writes each command with the pose measured before it is reached is one "
              "sample late: at most 2 sample intervals either way")

    def size(self, n_tubes):
        return 1

    def params(self, robot):
        return [Param("latency_rows", "rows", 0.1, -3.0, 3.0,
                      Plausible(-self.MAX_ROWS, self.MAX_ROWS, self.SOURCE))]

    def unseen(self, q, direction, robot):
        if not (np.abs(direction) > 0).any():
            return {"latency_rows": "no joint moves between rows"}
        return {}

    def joints(self, values, q, motion):
        return np.asarray(q, dtype=float) - float(values[0]) * motion.step

    def draw(self, robot, rng):
        return np.array([rng.uniform(0.3, 1.0)])


class Backlash(JointsEffect):
    name = "backlash"
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

    def joints(self, values, q, motion):
        n = q.shape[-1] // 2
        out = np.array(q, dtype=float, copy=True)
        out[..., n:] -= np.asarray(values) * motion.direction[..., n:]
        return out

    def derived(self, robot, x):
        return {f"backlash{i + 1}_deg": float(np.degrees(v)) for i, v in enumerate(x)}


class Friction(JointsEffect):
    """Coulomb friction in the drives and between the tubes as Maxwell-slip elements (a spring and a
    Coulomb slider each; together a Prandtl-Ishlinskii operator set, the standard model of frictional
    hysteresis): joint j reaches its command minus ``sum_k w_jk phi_k``, with ``phi_k`` the normalised
    play of half-width ``r_k`` behind the joint's travel (`ctrplan.model.motion.play_lag`). After a
    reversal the lag of element k turns from +w_jk to -w_jk over 2 r_k of travel -- the smaller the
    radius the sooner (backlash is the element of radius 0) -- so the lag depends on the direction and
    the history of the motion. Weights >= 0 (a slip element only ever lags)."""

    name = "friction"
    key = "friction"
    description = ("Coulomb friction in the drives and between the tubes (Maxwell-slip elements): after a "
                   "reversal joint j lags by up to sum_k w_jk (rad or mm), each element building up over "
                   "2 r_k of travel (r = 0: an instant flip, backlash)")
    #: Half-widths of the elements: 0 is an instant flip (backlash; a lead screw's for a translation),
    #: the others build up over 2 r of travel.
    RADII_RAD = tuple(math.radians(r) for r in (0.0, 2.0, 6.0, 18.0))
    RADII_MM = (0.0, 0.2, 0.6, 1.8)
    #: the longest lag a rotary drive's own play and compliance add (as `Backlash`), rad
    MAX_DRIVE_LAG_RAD = 0.1
    MAX_TRANSLATION_LAG_MM = 0.5
    ROTATION_SOURCE = ("a rotary drive's play and compliance (gears, belts, collets: at most 0.1 rad) plus "
                       "the tube twisted by friction (nested-tube friction mu ~ 0.1-0.3 on contact forces "
                       "of a few N at the tube radius, Lock & Dupont 2011: at most 5 N mm) over its length "
                       "and transmission: 0.1 rad + 5 N mm x (L_i + d_i) / G J_i")
    TRANSLATION_SOURCE = ("lead-screw backlash of linear stages (0.01-0.2 mm) and the axial compliance of "
                          "drive and tube under seal friction: 0.5 mm ceiling")
    FILE_KEYS = ("radii_rad", "radii_mm", "rotation_lag_rad", "translation_lag_mm")

    def size(self, n_tubes):
        return 2 * n_tubes * len(self.RADII_RAD)

    def _radii(self, joint: int, n_tubes: int) -> tuple[float, ...]:
        return self.RADII_MM if joint < n_tubes else self.RADII_RAD

    def params(self, robot):
        n, out = robot.n_tubes, []
        for j, joint in enumerate(robot.joint_names):
            unit, scale, source = ("mm", 0.02, self.TRANSLATION_SOURCE) if j < n else \
                ("rad", 0.005, self.ROTATION_SOURCE)
            ceiling = self.max_lag(robot, j)
            out += [Param(f"{joint}_slip{k + 1}_{unit}", unit, scale, 0.0, 2.0 * ceiling,
                          Plausible(0.0, ceiling, source)) for k in range(len(self.RADII_RAD))]
        return out

    def max_lag(self, robot: Robot, joint: int) -> float:
        """The largest total lag (mm or rad) joint ``joint`` can have (the plausible ceiling)."""
        n = robot.n_tubes
        if joint < n:
            return self.MAX_TRANSLATION_LAG_MM
        t = robot.tubes[joint - n]
        twist = TorsionalWindup.MAX_TORQUE_NMM * (t.length_mm + max(t.transmission_length_mm, 0.0)) \
            / t.torsional_stiffness_nmm2
        return self.MAX_DRIVE_LAG_RAD + twist

    def checks(self, robot):
        k, n, out = len(self.RADII_RAD), robot.n_tubes, []
        for j, joint in enumerate(robot.joint_names):
            unit, source = ("mm", self.TRANSLATION_SOURCE) if j < n else ("rad", self.ROTATION_SOURCE)
            out.append(Check(f"{joint}_friction_lag_{unit}", unit, _total(j, k),
                             Plausible(0.0, self.max_lag(robot, j), source)))
        return out

    def unseen(self, q, direction, robot):
        """Every element of a joint that never reverses; and the elements after the first that turn
        over within one step of the joint (2 r below its median step): they flip at once, as one."""
        k, n = len(self.RADII_RAD), robot.n_tubes
        names = [p.name for p in self.params(robot)]
        steps = np.abs(joint_steps(q)) if len(q) > 1 else np.zeros((0, 2 * n))
        out = {}
        for j, joint in enumerate(robot.joint_names):
            if not ((direction[:, j] > 0).any() and (direction[:, j] < 0).any()):
                out |= {names[j * k + i]: f"{joint} never reverses its direction of motion" for i in range(k)}
                continue
            moved = steps[:, j][steps[:, j] > 1e-9]
            typical = float(np.median(moved)) if moved.size else 0.0
            unit = "mm" if j < n else "rad"
            out |= {names[j * k + i]: f"{joint} moves {typical:.3g} {unit} a row: its element of radius "
                                      f"{r:.3g} {unit} turns over within a row, as the first one does"
                    for i, r in enumerate(self._radii(j, n)) if i > 0 and 2.0 * r <= typical}
        return out

    def joints(self, values, q, motion):
        n = q.shape[-1] // 2
        w = np.asarray(values, dtype=float).reshape(2 * n, len(self.RADII_RAD))
        out = np.array(q, dtype=float, copy=True)
        for j in np.flatnonzero(w.any(axis=1)):
            out[:, j] -= sum(wk * motion.play(j, r) for wk, r in zip(w[j], self._radii(j, n), strict=True)
                             if wk)
        return out

    def draw(self, robot, rng):
        """Lab-sized friction of the rotations: a total lag of 1-3 deg spread over the elements."""
        n, k = robot.n_tubes, len(self.RADII_RAD)
        w = np.zeros((2 * n, k))
        w[n:] = math.radians(rng.uniform(1.0, 3.0)) * rng.dirichlet(np.ones(k), size=n)
        return w.ravel()

    def write(self, values):
        w = np.asarray(values, dtype=float).reshape(-1, len(self.RADII_RAD))
        n = len(w) // 2
        return {"radii_rad": list(self.RADII_RAD), "radii_mm": list(self.RADII_MM),
                "rotation_lag_rad": w[n:].tolist(), "translation_lag_mm": w[:n].tolist()}

    def read(self, doc, keys, raw, n_tubes):
        k = len(self.RADII_RAD)
        if not isinstance(raw, dict) or set(raw) - set(self.FILE_KEYS):
            raise doc.error(keys, f"expected a mapping with the keys {', '.join(self.FILE_KEYS)}")
        for key, radii in (("radii_rad", self.RADII_RAD), ("radii_mm", self.RADII_MM)):
            if key in raw and (not isinstance(raw[key], list) or len(raw[key]) != k
                               or not np.allclose(numbers(doc, keys + (key,), raw[key], k), radii)):
                raise doc.error(keys + (key,), f"expected the radii of this version, {list(radii)}")
        rows = []
        for key in ("translation_lag_mm", "rotation_lag_rad"):
            value = raw.get(key, [[0.0] * k] * n_tubes)
            if not isinstance(value, list) or len(value) != n_tubes:
                raise doc.error(keys + (key,), f"expected {n_tubes} lists of {k} numbers, one per tube")
            rows += [numbers(doc, keys + (key, i), v, k) for i, v in enumerate(value)]
        flat = tuple(v for row in rows for v in row)
        if any(v < 0 for v in flat):
            raise doc.error(keys, "friction lags are >= 0 (a slip element only ever lags)")
        return flat

    def derived(self, robot, x):
        k, n = len(self.RADII_RAD), robot.n_tubes
        w = np.asarray(x, dtype=float).reshape(-1, k)
        return {(f"{joint}_friction_lag_deg" if j >= n else f"{joint}_friction_lag_mm"):
                float(np.degrees(w[j].sum()) if j >= n else w[j].sum())
                for j, joint in enumerate(robot.joint_names)}


def _total(joint: int, k: int):
    """The total lag of joint ``joint`` (sum of its ``k`` slip weights) of a friction vector."""
    return lambda x: float(np.sum(x[joint * k:(joint + 1) * k]))


class TorsionalWindup(JointsEffect):
    name = "torsional_windup"
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

    def joints(self, values, q, motion):
        n = q.shape[-1] // 2
        out = np.array(q, dtype=float, copy=True)
        out[..., n:] -= np.asarray(values) * -q[..., :n] * motion.direction[..., n:]
        return out

    def derived(self, robot, x):
        return {f"friction_torque{i + 1}_nmm": float(v) * t.torsional_stiffness_nmm2
                for i, (t, v) in enumerate(zip(robot.tubes, x, strict=True))}


class SensorOffset(TipEffect):
    name = "sensor_offset"
    between_sessions = True
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


class Registration(FrameEffect):
    name = "registration"
    between_sessions = True
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
