"""The library of candidate causes: each a physical model extension with a few parameters.

An `Effect` maps a parameter vector x (in file units) onto a (`Robot`, `Calibration`) pair, starting
from a base pair. Mechanical effects change the robot (the Cosserat backend solves them); the two
measurement-side effects change the `Calibration`.

=================  ====  =====================================================================
cause              k     parameters
=================  ====  =====================================================================
curvature          3     pre-curvature kappa_i of each tube (1/m)
stiffness_ratio    1     Poisson's ratio nu; G_i = E_i / (2 (1 + nu)) (torsion vs bending)
bending_stiffness  N-1   stiffness of tube i relative to its file value (E_i and G_i scaled together:
                         wall thickness, heat treatment), i = 2..N; tube 1 is the reference (in free
                         space only stiffness ratios shape the robot)
joint_offset       2N    zero offsets of beta_i (mm) and alpha_i (rad), added to q
gravity            3     gravity vector (m/s^2) with the file's density and E: only rho*g/E matters
tip_force          3     point force at the tip of tube 1 (N), robot frame
registration       6     rotation vector (rad) and translation (mm), robot -> measurement frame
backlash           N     lag of alpha_i (rad) in the direction of its latest motion
sensor_offset      3     tracked point relative to the tip of tube 1, in its tip frame R(l1) (mm)
torsional_windup   N     friction twists the tube behind the plate: a lag of alpha_i growing with
                         -beta_i, windup_i (rad/mm) = friction torque / (G J_i), plus backlash_i
=================  ====  =====================================================================
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from ctrplan.errors import InputError
from ctrplan.measurement import Calibration, per_tube
from ctrplan.robot import Loads, Robot

MAX_GRAVITY = 30.0     # m/s^2 per component
MAX_TIP_FORCE = 0.05   # N per component (50 mN bends tube 1 by tens of mm)

CAUSES = ("curvature", "stiffness_ratio", "bending_stiffness", "joint_offset", "gravity", "tip_force",
          "registration", "sensor_offset", "backlash", "torsional_windup")
MAX_SENSOR_OFFSET_MM = 20.0
STIFFNESS_FACTOR_RANGE = (0.3, 3.0)


@dataclass(frozen=True)
class Param:
    """One fitted parameter: its name, unit and typical magnitude of a lab deviation (for scaling
    the optimisation and the finite-difference steps)."""

    name: str
    unit: str
    scale: float
    lower: float = -np.inf
    upper: float = np.inf


class Effect(ABC):
    """A candidate cause. Subclasses define `params`, `x0` and `apply`."""

    name: str = "effect"
    description: str = ""
    #: "mechanics" (changes the Robot), "joints" (changes the joints the tubes reach) or "frame".
    kind: str = "mechanics"

    @abstractmethod
    def params(self, robot: Robot, calib: Calibration) -> list[Param]:
        """The fitted parameters, in the order of ``x``."""

    @abstractmethod
    def x0(self, robot: Robot, calib: Calibration) -> np.ndarray:
        """Parameter values (len(params),) that reproduce the base model."""

    @abstractmethod
    def apply(self, robot: Robot, calib: Calibration, x: np.ndarray) -> tuple[Robot, Calibration]:
        """The robot and calibration extended with parameters ``x``."""

    def initial_guess(self, robot: Robot, calib: Calibration, predicted_robot_frame: np.ndarray,
                      measured: np.ndarray) -> np.ndarray | None:
        """Optional closed-form start from the base model's robot-frame tips and the measurements
        (both (M, 3) point lists). None: start from `x0`."""
        return None

    def derived(self, robot: Robot, calib: Calibration, x: np.ndarray) -> dict[str, float]:
        """Readable quantities derived from the fitted parameters (for the report)."""
        return {}

    @property
    def causes(self) -> tuple[str, ...]:
        return (self.name,)

    def __repr__(self) -> str:
        return f"<Effect {self.name}>"


class Curvature(Effect):
    name = "curvature"
    description = "pre-curvature of each tube"

    def params(self, robot, calib):
        return [Param(f"kappa{i + 1}_1_per_m", "1/m", max(0.1 * t.curvature_per_mm * 1e3, 0.5))
                for i, t in enumerate(robot.tubes)]

    def x0(self, robot, calib):
        return np.array([t.curvature_per_mm * 1e3 for t in robot.tubes])

    def derived(self, robot, calib, x):
        return {f"kappa{i + 1}_change_pct": 100.0 * (float(v) / (t.curvature_per_mm * 1e3) - 1.0)
                for i, (t, v) in enumerate(zip(robot.tubes, x, strict=True))}

    def apply(self, robot, calib, x):
        tubes = tuple(replace(t, curvature_per_mm=float(v) * 1e-3)
                      for t, v in zip(robot.tubes, x, strict=True))
        return robot.with_changes(tubes=tubes), calib


class StiffnessRatio(Effect):
    name = "stiffness_ratio"
    description = "torsional vs bending stiffness (Poisson's ratio, G = E / (2 (1 + nu)))"

    def params(self, robot, calib):
        # an *effective* ratio: it also absorbs what the isotropic G = E / (2 (1 + nu)) misses in a
        # superelastic tube, so it may leave the isotropic range (-1, 0.5)
        return [Param("poisson_ratio", "1", 0.05, -0.9, 3.0)]

    def x0(self, robot, calib):
        t = robot.tubes[0]
        return np.array([t.youngs_modulus_mpa / (2.0 * t.shear_modulus_mpa) - 1.0])

    def derived(self, robot, calib, x):
        nu0 = self.x0(robot, calib)[0]
        return {"torsional_stiffness_change_pct": 100.0 * ((1.0 + nu0) / (1.0 + float(x[0])) - 1.0)}

    def apply(self, robot, calib, x):
        nu = float(x[0])
        tubes = tuple(replace(t, shear_modulus_mpa=t.youngs_modulus_mpa / (2.0 * (1.0 + nu)))
                      for t in robot.tubes)
        return robot.with_changes(tubes=tubes), calib


class JointOffset(Effect):
    name = "joint_offset"
    description = "zero offsets of the joints (beta mm, alpha rad)"
    kind = "joints"

    def derived(self, robot, calib, x):
        n = len(robot.tubes)
        return {f"alpha{i + 1}_offset_deg": float(np.degrees(x[n + i])) for i in range(n)}

    def params(self, robot, calib):
        n = len(robot.tubes)
        return [Param(f"beta{i + 1}_offset_mm", "mm", 1.0) for i in range(n)] + \
               [Param(f"alpha{i + 1}_offset_rad", "rad", 0.05) for i in range(n)]

    def x0(self, robot, calib):
        return np.asarray(robot.joint_offset, dtype=float)

    def apply(self, robot, calib, x):
        return robot.with_changes(joint_offset=tuple(float(v) for v in x)), calib


class Gravity(Effect):
    name = "gravity"
    description = "distributed weight of the tubes (direction and rho*g/E scale)"

    def params(self, robot, calib):
        # bounded at ~3 g per component: rho*g/E up to 3x its nominal value is generous, and huge loads
        # (what a gravity fit reaches for when it tries to explain a frame offset) are slow to solve
        return [Param(f"gravity_{a}_m_s2", "m/s^2", 5.0, -MAX_GRAVITY, MAX_GRAVITY) for a in "xyz"]

    def x0(self, robot, calib):
        return np.asarray(robot.loads.gravity_m_s2, dtype=float)

    def derived(self, robot, calib, x):
        g = np.asarray(x, dtype=float)
        mag = float(np.linalg.norm(g))
        t = robot.tubes[0]
        out = {"gravity_magnitude_m_s2": mag,
               "rho_g_over_E_per_m": t.density_kg_m3 * mag / (t.youngs_modulus_mpa * 1e6)}
        if mag > 0:
            out["angle_from_insertion_axis_deg"] = float(np.degrees(np.arccos(np.clip(g[2] / mag, -1, 1))))
        return out

    def apply(self, robot, calib, x):
        loads = Loads(gravity_m_s2=tuple(float(v) for v in x), tip_force_n=robot.loads.tip_force_n)
        return robot.with_changes(loads=loads), calib


class TipForce(Effect):
    name = "tip_force"
    description = "constant point force at the tip of tube 1 (e.g. a sensor cable)"

    def params(self, robot, calib):
        return [Param(f"tip_force_{a}_n", "N", 2e-3, -MAX_TIP_FORCE, MAX_TIP_FORCE) for a in "xyz"]

    def x0(self, robot, calib):
        return np.asarray(robot.loads.tip_force_n, dtype=float)

    def derived(self, robot, calib, x):
        return {"tip_force_magnitude_mn": 1e3 * float(np.linalg.norm(x))}

    def apply(self, robot, calib, x):
        loads = Loads(gravity_m_s2=robot.loads.gravity_m_s2, tip_force_n=tuple(float(v) for v in x))
        return robot.with_changes(loads=loads), calib


class Registration(Effect):
    name = "registration"
    description = "rigid transform between the robot frame and the measurement frame"
    kind = "frame"

    def params(self, robot, calib):
        return [Param(f"rotation_{a}_rad", "rad", 0.02) for a in "xyz"] + \
               [Param(f"translation_{a}_mm", "mm", 1.0) for a in "xyz"]

    def x0(self, robot, calib):
        return np.concatenate([calib.rotation_vector_rad, calib.translation_mm]).astype(float)

    def apply(self, robot, calib, x):
        return robot, replace(calib, rotation_vector_rad=tuple(float(v) for v in x[:3]),
                              translation_mm=tuple(float(v) for v in x[3:6]))

    def derived(self, robot, calib, x):
        return {"rotation_deg": float(np.degrees(np.linalg.norm(x[:3]))),
                "translation_mm": float(np.linalg.norm(x[3:6]))}

    def initial_guess(self, robot, calib, predicted_robot_frame, measured):
        R, t = kabsch(predicted_robot_frame, measured)
        return np.concatenate([Rotation.from_matrix(R).as_rotvec(), t])


class Backlash(Effect):
    name = "backlash"
    description = "direction-dependent lag of the rotation joints alpha_i"
    kind = "joints"

    def params(self, robot, calib):
        return [Param(f"backlash{i + 1}_rad", "rad", 0.03, 0.0, 0.5) for i in range(len(robot.tubes))]

    def x0(self, robot, calib):
        return per_tube(calib.backlash_rad, len(robot.tubes))

    def derived(self, robot, calib, x):
        return {f"backlash{i + 1}_deg": float(np.degrees(v)) for i, v in enumerate(x)}

    def apply(self, robot, calib, x):
        return robot, replace(calib, backlash_rad=tuple(float(v) for v in x))


class TorsionalWindup(Effect):
    name = "torsional_windup"
    description = ("friction torque twisting each tube behind the plate: a lag of alpha_i in the "
                   "direction of motion growing with -beta_i (with a constant backlash part)")
    kind = "joints"

    def params(self, robot, calib):
        n = len(robot.tubes)
        return [Param(f"windup{i + 1}_rad_per_mm", "rad/mm", 3e-4, 0.0, 0.02) for i in range(n)] + \
            Backlash().params(robot, calib)

    def x0(self, robot, calib):
        return np.concatenate([per_tube(calib.windup_rad_per_mm, len(robot.tubes)),
                               Backlash().x0(robot, calib)])

    def derived(self, robot, calib, x):
        n = len(robot.tubes)
        return {f"friction_torque{i + 1}_nmm": float(x[i]) * t.torsional_stiffness_nmm2
                for i, t in enumerate(robot.tubes)} | Backlash().derived(robot, calib, x[n:])

    def apply(self, robot, calib, x):
        n = len(robot.tubes)
        return robot, replace(calib, windup_rad_per_mm=tuple(float(v) for v in x[:n]),
                              backlash_rad=tuple(float(v) for v in x[n:]))


class BendingStiffness(Effect):
    name = "bending_stiffness"
    description = "stiffness of each tube relative to tube 1 (E*I and G*J: wall thickness, heat treatment)"

    def _tubes(self, robot: Robot) -> range:
        # only stiffness ratios shape the robot in free space (and a load's rho*g/E is the gravity
        # cause's): tube 1 is the reference
        return range(1, len(robot.tubes))

    def params(self, robot, calib):
        lo, hi = STIFFNESS_FACTOR_RANGE
        return [Param(f"stiffness{i + 1}_rel", "1", 0.1, lo, hi) for i in self._tubes(robot)]

    def x0(self, robot, calib):
        return np.ones(len(self._tubes(robot)))

    def derived(self, robot, calib, x):
        return {f"tube{i + 1}_EI_change_pct": 100.0 * (float(v) - 1.0)
                for i, v in zip(self._tubes(robot), x, strict=True)}

    def apply(self, robot, calib, x):
        tubes = list(robot.tubes)
        for i, v in zip(self._tubes(robot), x, strict=True):
            t = tubes[i]
            tubes[i] = replace(t, youngs_modulus_mpa=t.youngs_modulus_mpa * float(v),
                               shear_modulus_mpa=t.shear_modulus_mpa * float(v))
        return robot.with_changes(tubes=tuple(tubes)), calib


class SensorOffset(Effect):
    name = "sensor_offset"
    description = "tracked point offset from the tip of tube 1, fixed in its tip frame"
    kind = "frame"

    def params(self, robot, calib):
        m = MAX_SENSOR_OFFSET_MM
        return [Param(f"sensor_offset_{a}_mm", "mm", 1.0, -m, m) for a in "xyz"]

    def x0(self, robot, calib):
        return np.asarray(calib.sensor_offset_mm, dtype=float)

    def derived(self, robot, calib, x):
        return {"sensor_offset_mm": float(np.linalg.norm(x))}

    def apply(self, robot, calib, x):
        return robot, replace(calib, sensor_offset_mm=tuple(float(v) for v in x))


class Combined(Effect):
    """Several effects at once (their parameters concatenated, applied in order)."""

    def __init__(self, effects: Sequence[Effect]):
        self.effects = tuple(effects)
        self.name = "+".join(e.name for e in self.effects)
        self.description = "; ".join(e.description for e in self.effects)
        kinds = {e.kind for e in self.effects}
        self.kind = "mechanics" if "mechanics" in kinds else ("joints" if "joints" in kinds else "frame")

    @property
    def causes(self) -> tuple[str, ...]:
        return tuple(c for e in self.effects for c in e.causes)

    def params(self, robot, calib):
        return [p for e in self.effects for p in e.params(robot, calib)]

    def _sizes(self, robot, calib):
        return [len(e.params(robot, calib)) for e in self.effects]

    def x0(self, robot, calib):
        return np.concatenate([e.x0(robot, calib) for e in self.effects])

    def derived(self, robot, calib, x):
        out, i = {}, 0
        for e, n in zip(self.effects, self._sizes(robot, calib), strict=True):
            out.update(e.derived(robot, calib, x[i:i + n]))
            i += n
        return out

    def apply(self, robot, calib, x):
        i = 0
        for e, n in zip(self.effects, self._sizes(robot, calib), strict=True):
            robot, calib = e.apply(robot, calib, x[i:i + n])
            i += n
        return robot, calib


_LIBRARY = {c.name: c for c in (Curvature, StiffnessRatio, BendingStiffness, JointOffset, Gravity,
                                TipForce, Registration, SensorOffset, Backlash, TorsionalWindup)}


def make_effect(name: str) -> Effect:
    """Effect by cause name; ``a+b`` combines."""
    parts = [p.strip() for p in name.split("+") if p.strip()]
    for p in parts:
        if p not in _LIBRARY:
            raise InputError(f"unknown cause {p!r} (known: {', '.join(CAUSES)})")
    if len(parts) == 1:
        return _LIBRARY[parts[0]]()
    return Combined([_LIBRARY[p]() for p in parts])


def kabsch(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares rigid transform (R, t) with ``target ~ R source + t`` for point lists (M, 3)."""
    src = np.asarray(source, dtype=float).reshape(-1, 3)
    dst = np.asarray(target, dtype=float).reshape(-1, 3)
    ok = np.isfinite(src).all(1) & np.isfinite(dst).all(1)
    src, dst = src[ok], dst[ok]
    cs, cd = src.mean(0), dst.mean(0)
    H = (src - cs).T @ (dst - cd)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, cd - R @ cs
