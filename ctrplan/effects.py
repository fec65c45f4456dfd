"""The library of candidate causes: physical extensions of a robot model, each owning its parameters
(unit, plausible range and where that range comes from), where the robot file keeps it, what the data
must show for it to be seen, and how it changes the model.

Every subclass of `Effect` with a ``name`` registers itself in `EFFECTS` (definition order); `CAUSES`
is derived from it, and the command line, the library and the tests use those.

An effect acts on one side of the model (``Effect.side``), in the order a prediction applies them:

* ``joints``    -- reported joints -> the joints the mechanics sees (backlash, windup);
* ``mechanics`` -- tube parameters, transmission lengths, joint offsets, loads (`Robot` fields, solved
  by the Cosserat backend);
* ``tip``       -- the tracked point relative to the solved tip of tube 1 (sensor offset);
* ``frame``     -- robot frame -> tracker frame (registration).

The measurement-side effects (joints, tip, frame: `MeasurementEffect`) live in the robot's
`ctrplan.measurement.Calibration`, under the robot file's ``calibration`` key.

The table of causes (cause, side, parameters) follows, rendered from the registered classes
(`cause_table`). Adding a cause is one `Effect` subclass here: the command line, the library, the
reports and the tests read `EFFECTS` (a mechanics-side cause sets `Robot` fields; a new physical
parameter is also a field of the robot file and of the solver).

"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
from scipy.spatial.transform import Rotation

from ctrplan.errors import InputError

if TYPE_CHECKING:
    from ctrplan.robot import Robot
    from ctrplan.yamlio import KeyPath, YamlDoc

#: Every effect by cause name, in definition order (filled by `Effect.__init_subclass__`).
EFFECTS: dict[str, type[Effect]] = {}
#: The order in which the sides act on a prediction.
SIDES = ("joints", "mechanics", "tip", "frame")

#: Young's modulus of superelastic NiTi, GPa: martensite (lowest) and austenite (highest).
NITI_E_GPA = (28.0, 83.0)
NITI_E_SOURCE = ("superelastic NiTi: E 28-41 GPa (martensite) to 70-83 GPa (austenite), Johnson Matthey "
                 "'Nitinol technical properties'; E of polycrystalline NiTi moves with processing "
                 "(Bucsek, Paranjape & Stebner 2016)")
STANDARD_GRAVITY = 9.81


@dataclass(frozen=True)
class Plausible:
    """The range a real robot can have for a parameter (file units), and where it comes from."""

    low: float
    high: float
    source: str

    def __contains__(self, value: float) -> bool:
        return self.low - 1e-12 <= value <= self.high + 1e-12


@dataclass(frozen=True)
class Param:
    """One fitted parameter: name, unit, the typical size of a lab deviation (scales the optimisation
    and its finite-difference steps), hard bounds the fit keeps to (where the model stops making
    sense) and the plausible range of a real robot (outside it a fit is reported implausible)."""

    name: str
    unit: str
    scale: float
    lower: float = -np.inf
    upper: float = np.inf
    plausible: Plausible | None = None


#: Half-width of a confidence interval in standard deviations (about 95 %).
CONFIDENCE_Z = 2.0
#: Half-width (standard deviations) of the interval that must miss a plausible range for a value to be
#: implausible: 3, so that a true value at the range's edge (a nearly incompressible tube, nu = 0.5) is
#: refused in 0.1 % of fits; with 2 it was refused in 2.3 %, and a wrong cause named instead.
IMPLAUSIBLE_Z = 3.0


@dataclass(frozen=True)
class Check:
    """A quantity of the parameters ``x`` (file units) and the range a real robot can have for it."""

    name: str
    unit: str
    value: Callable[[np.ndarray], float]
    plausible: Plausible


@dataclass(frozen=True)
class Verdict:
    """A check outside its plausible range: its value and standard deviation, and whether the whole
    confidence interval misses the range (``implausible``) or overlaps it (at the edge)."""

    check: Check
    value: float
    std: float
    implausible: bool

    def reason(self) -> str:
        p = self.check.plausible
        std = "" if not self.std else f" +- {self.std:.2g}"
        where = "is outside" if self.implausible else "is at the edge of (its interval overlaps)"
        return f"{self.value:.4g}{std} {self.check.unit} {where} [{p.low:.4g}, {p.high:.4g}]"


def _component(i: int) -> Callable[[np.ndarray], float]:
    return lambda x: float(x[i])


def _norm(x: np.ndarray) -> float:
    return float(np.linalg.norm(x))


def _shifted(f: Callable[[np.ndarray], float], start: int, k: int) -> Callable[[np.ndarray], float]:
    """``f`` of the ``k`` parameters from ``start`` on (an effect inside `Combined`)."""
    return lambda x: f(x[start:start + k])


def _propagated_std(f: Callable[[np.ndarray], float], x: np.ndarray, cov: np.ndarray | None) -> float:
    """Standard deviation of ``f(x)`` for a covariance ``cov`` of ``x`` (linearised; 0 without cov,
    inf when a parameter it depends on is not resolved)."""
    if cov is None:
        return 0.0
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    grad = np.zeros(len(x))
    for i in range(len(x)):
        if not np.isfinite(sd[i]):
            h = 1e-6 * max(abs(x[i]), 1.0)
        elif sd[i] == 0:
            continue
        else:
            h = 1e-3 * sd[i]
        xp = x.copy()
        xp[i] += h
        grad[i] = (f(xp) - f(x)) / h
    used = grad != 0
    if (~np.isfinite(sd[used])).any():
        return float("inf")
    c = np.where(np.isfinite(cov), cov, 0.0)
    return float(np.sqrt(max(grad @ c @ grad, 0.0)))


class Effect(ABC):
    """A candidate cause. Subclasses set ``name``, ``side``, ``key`` and ``description`` and define
    `params`, `values` and `with_values`; `unseen`, `limits`, `implausible`, `derived` and
    `initial_guess` have defaults."""

    name: ClassVar[str] = ""
    side: ClassVar[str] = "mechanics"
    #: Where the robot file keeps the parameters (documentation and messages).
    key: ClassVar[str] = ""
    description: ClassVar[str] = ""

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if cls.name:
            EFFECTS[cls.name] = cls

    @abstractmethod
    def params(self, robot: Robot) -> list[Param]:
        """The fitted parameters, in the order of ``x``."""

    @abstractmethod
    def values(self, robot: Robot) -> np.ndarray:
        """The robot's current parameter values (len(params),), file units."""

    @abstractmethod
    def with_values(self, robot: Robot, x: np.ndarray) -> Robot:
        """``robot`` with this effect's parameters set to ``x``."""

    def unseen(self, q: np.ndarray, direction: np.ndarray, robot: Robot) -> dict[str, str]:
        """Parameters the rows (joints q (R, 2N), directions of motion (R, 2N)) cannot show -> why,
        naming the joint the reason is about. They are held at their base value, not fitted."""
        return {}

    def limits(self, q: np.ndarray, robot: Robot) -> dict[str, tuple[float, float]]:
        """Hard bounds that depend on the rows (e.g. keeping every row physical): name -> (lo, hi)."""
        return {}

    def checks(self, robot: Robot) -> list[Check]:
        """The quantities with a plausible range: every parameter that has one, and (subclasses)
        quantities of several parameters, e.g. the magnitude of a vector. ``robot`` is the base model
        (the ranges refer to its file values)."""
        return [Check(p.name, p.unit, _component(i), p.plausible)
                for i, p in enumerate(self.params(robot)) if p.plausible is not None]

    def plausibility(self, robot: Robot, x: np.ndarray, cov: np.ndarray | None = None,
                     z: float = IMPLAUSIBLE_Z) -> dict[str, Verdict]:
        """Every check outside its plausible range at ``x`` (file units): `Verdict.implausible` when
        its confidence interval (``z`` standard deviations from the covariance ``cov`` of ``x``,
        propagated linearly) misses the range, else at the edge (the range lies within the
        interval). Without ``cov`` the interval is the value itself."""
        x = np.asarray(x, dtype=float)
        out = {}
        for c in self.checks(robot):
            v = float(c.value(x))
            if v in c.plausible:
                continue
            std = _propagated_std(c.value, x, cov)
            out[c.name] = Verdict(c, v, std, implausible=not (v - z * std <= c.plausible.high + 1e-12
                                                              and v + z * std >= c.plausible.low - 1e-12))
        return out

    def implausible(self, robot: Robot, x: np.ndarray, cov: np.ndarray | None = None) -> dict[str, str]:
        """Checks whose confidence interval misses the plausible range -> why (value, interval and
        range; the source is `Check.plausible.source`)."""
        return {k: v.reason() for k, v in self.plausibility(robot, x, cov).items() if v.implausible}

    def derived(self, robot: Robot, x: np.ndarray) -> dict[str, float]:
        """Readable quantities derived from the parameters ``x`` of the base ``robot``."""
        return {}

    def draw(self, robot: Robot, rng: np.random.Generator) -> np.ndarray:
        """Lab-sized values for generated data (`ctrplan.calibration.synthetic`): each parameter 1-3
        typical deviations (``scale``) from the robot's value -- either sign, or upwards where the
        value sits on its lower bound -- inside its hard bounds and plausible range."""
        out = []
        for p, v in zip(self.params(robot), self.values(robot), strict=True):
            step = p.scale * rng.uniform(1.0, 3.0)
            x = v + (step if v <= p.lower else step * rng.choice([-1.0, 1.0]))
            lo, hi = (p.lower, p.upper) if p.plausible is None else \
                (max(p.lower, p.plausible.low), min(p.upper, p.plausible.high))
            out.append(float(np.clip(x, lo, hi)))
        return np.array(out)

    def initial_guess(self, robot: Robot, predicted: np.ndarray, measured: np.ndarray) -> np.ndarray | None:
        """A closed-form start from the base model's robot-frame tips and the measured ones (both
        (M, 3) point lists), or None to start from `values`."""
        return None

    @property
    def causes(self) -> tuple[str, ...]:
        return (self.name,)

    def __repr__(self) -> str:
        return f"<Effect {'+'.join(self.causes)}>"


# ---- mechanics ------------------------------------------------------------------------------------
class Curvature(Effect):
    name = "curvature"
    key = "tubes[i].curvature_1_per_m"
    description = "pre-curvature kappa_i of each tube (1/m)"
    #: Largest bending strain kappa * OD / 2 superelastic NiTi recovers.
    MAX_STRAIN = 0.08
    SOURCE = ("heat-set curvature of nitinol tubes is reproduced within tens of per cent (springback "
              "after shape setting; CTR model calibrations fit it for that reason, e.g. Webster, Romano & "
              "Cowan 2009): file value +- 50 % (+- 1 1/m for a straight tube), and at most 8 % bending "
              "strain kappa * OD / 2 (the strain superelastic NiTi recovers)")

    def params(self, robot):
        out = []
        for i, t in enumerate(robot.tubes):
            k = t.curvature_per_mm * 1e3
            low = max(min(0.5 * k, k - 1.0), 0.0)
            high = min(max(1.5 * k, k + 1.0), self.MAX_STRAIN / t.outer_radius_mm * 1e3)
            out.append(Param(f"kappa{i + 1}_1_per_m", "1/m", max(0.1 * k, 0.5), 0.0, np.inf,
                             Plausible(low, high, self.SOURCE)))
        return out

    def values(self, robot):
        return np.array([t.curvature_per_mm * 1e3 for t in robot.tubes])

    def with_values(self, robot, x):
        return robot.with_changes(tubes=tuple(replace(t, curvature_per_mm=float(v) * 1e-3)
                                              for t, v in zip(robot.tubes, x, strict=True)))

    def unseen(self, q, direction, robot):
        return {f"kappa{i + 1}_1_per_m": f"tube {i + 1} has no curved part"
                for i, t in enumerate(robot.tubes) if t.curved_length_mm <= 0.0}

    def derived(self, robot, x):
        return {f"kappa{i + 1}_change_pct": 100.0 * (float(v) / (t.curvature_per_mm * 1e3) - 1.0)
                for i, (t, v) in enumerate(zip(robot.tubes, x, strict=True)) if t.curvature_per_mm > 0}


class StiffnessRatio(Effect):
    name = "stiffness_ratio"
    key = "tubes[i].shear_modulus_gpa"
    description = "Poisson's ratio nu; G_i = E_i / (2 (1 + nu)) (torsion vs bending)"
    SOURCE = ("isotropic metals have 0 <= nu <= 0.5 (0.5: incompressible); superelastic NiTi "
              "nu = 0.3-0.33 (Johnson Matthey 'Nitinol technical properties'); nu = E / (2 G) - 1 as in "
              "Dupont, Lock, Itkowitz & Butler 2010")

    def params(self, robot):
        # the hard bounds are wider than the plausible range so that a fit can say what it needs
        return [Param("poisson_ratio", "1", 0.05, -0.9, 2.0, Plausible(0.0, 0.5, self.SOURCE))]

    def values(self, robot):
        t = robot.tubes[0]
        return np.array([t.youngs_modulus_mpa / (2.0 * t.shear_modulus_mpa) - 1.0])

    def with_values(self, robot, x):
        nu = float(x[0])
        return robot.with_changes(tubes=tuple(
            replace(t, shear_modulus_mpa=t.youngs_modulus_mpa / (2.0 * (1.0 + nu))) for t in robot.tubes))

    def unseen(self, q, direction, robot):
        if robot.n_tubes == 1:
            return {"poisson_ratio": "a single tube carries no torsion in free space"}
        return {}

    def derived(self, robot, x):
        nu0 = self.values(robot)[0]
        return {"torsional_stiffness_change_pct": 100.0 * ((1.0 + nu0) / (1.0 + float(x[0])) - 1.0)}


class BendingStiffness(Effect):
    name = "bending_stiffness"
    key = "tubes[i].youngs_modulus_gpa, shear_modulus_gpa"
    description = ("E*I and G*J of tube i relative to tube 1, i = 2..N (in free space only stiffness ratios "
                   "shape the robot)")

    def params(self, robot):
        lo, hi = NITI_E_GPA
        plausible = Plausible(lo / hi, hi / lo, f"{NITI_E_SOURCE}: one tube at most {hi:g}/{lo:g} times "
                                                f"stiffer or softer than another")
        return [Param(f"stiffness{i + 1}_rel", "1", 0.1, 0.1, 10.0, plausible)
                for i in range(1, robot.n_tubes)]

    def values(self, robot):
        return np.ones(robot.n_tubes - 1)

    def with_values(self, robot, x):
        tubes = list(robot.tubes)
        for i, v in enumerate(x, start=1):
            tubes[i] = replace(tubes[i], youngs_modulus_mpa=tubes[i].youngs_modulus_mpa * float(v),
                               shear_modulus_mpa=tubes[i].shear_modulus_mpa * float(v))
        return robot.with_changes(tubes=tuple(tubes))

    def derived(self, robot, x):
        return {f"tube{i}_EI_change_pct": 100.0 * (float(v) - 1.0) for i, v in enumerate(x, start=2)}


class Transmission(Effect):
    name = "transmission"
    key = "tubes[i].transmission_length_mm"
    description = ("extra length d_i (mm) over which tube i twists behind the plate: the drive's torsional "
                   "compliance, or a clamp nearer the plate (d_i < 0)")
    SOURCE = ("the straight tube behind the plate twists ('transmissional torsion', Webster, Romano & "
              "Cowan 2009); a drive of gears and collets adds at most the tube's own length of torsional "
              "compliance, a clamp nearer the plate removes at most all of it")

    def params(self, robot):
        return [Param(f"transmission{i + 1}_mm", "mm", 5.0, -1000.0, 1000.0,
                      Plausible(-t.length_mm, t.length_mm, self.SOURCE)) for i, t in enumerate(robot.tubes)]

    def values(self, robot):
        return np.array([t.transmission_length_mm for t in robot.tubes])

    def with_values(self, robot, x):
        return robot.with_changes(tubes=tuple(replace(t, transmission_length_mm=float(v))
                                              for t, v in zip(robot.tubes, x, strict=True)))

    def unseen(self, q, direction, robot):
        if robot.n_tubes == 1:
            return {"transmission1_mm": "a single tube carries no torsion in free space"}
        return {}

    def limits(self, q, robot):
        # every row keeps a twisting length -beta_i + d_i >= 0 behind the plate
        beta = robot.apply_offset(q)[:, :robot.n_tubes]
        return {f"transmission{i + 1}_mm": (float(beta[:, i].max()), np.inf) for i in range(robot.n_tubes)}

    def draw(self, robot, rng):
        return np.abs(super().draw(robot, rng))   # a compliant drive: rows near the plate keep d >= 0

    def derived(self, robot, x):
        # a drive of torsional stiffness k adds d = G J / k of twisting length
        return {f"drive_stiffness{i + 1}_nmm_per_rad": t.torsional_stiffness_nmm2 / float(v)
                for i, (t, v) in enumerate(zip(robot.tubes, x, strict=True)) if v > 0}


class JointOffset(Effect):
    name = "joint_offset"
    key = "joint_offset"
    description = "zero offsets of beta_i (mm) and alpha_i (rad), added to q"
    BETA_SOURCE = ("the zero of a translation (tube tip flush with the front plate) is set by eye or a "
                   "homing switch: a few mm off at most; 10 mm ceiling")
    ALPHA_SOURCE = "the zero of a rotation may be any angle"

    def params(self, robot):
        n = robot.n_tubes
        return [Param(f"beta{i + 1}_offset_mm", "mm", 1.0, -1000.0, 1000.0,
                      Plausible(-10.0, 10.0, self.BETA_SOURCE)) for i in range(n)] + \
               [Param(f"alpha{i + 1}_offset_rad", "rad", 0.05, -2 * math.pi, 2 * math.pi,
                      Plausible(-math.pi, math.pi, self.ALPHA_SOURCE)) for i in range(n)]

    def values(self, robot):
        return np.asarray(robot.joint_offset, dtype=float)

    def with_values(self, robot, x):
        return robot.with_changes(joint_offset=tuple(float(v) for v in x))

    def unseen(self, q, direction, robot):
        names = [p.name for p in self.params(robot)]
        joints = robot.joint_names
        return {names[j]: f"{joints[j]} never moves in the data" for j in range(robot.n_joints)
                if np.ptp(q[:, j]) <= 1e-9}

    def derived(self, robot, x):
        n = robot.n_tubes
        return {f"alpha{i + 1}_offset_deg": float(np.degrees(x[n + i])) for i in range(n)}


class Gravity(Effect):
    name = "gravity"
    key = "loads.gravity_m_s2"
    description = "gravity vector (m/s^2) with the file's density and E: only rho*g/E matters"

    SOURCE = (f"only rho*g/E matters: |g| <= 9.81 m/s^2 x the file's E / the lowest E of NiTi "
              f"({NITI_E_SOURCE})")

    def params(self, robot):
        # hard bounds: huge loads (what a gravity fit reaches for when it tries to explain a frame offset)
        # are slow to solve
        g = self.max_magnitude(robot)
        return [Param(f"gravity_{a}_m_s2", "m/s^2", 5.0, -30.0, 30.0, Plausible(-g, g, self.SOURCE))
                for a in "xyz"]

    def values(self, robot):
        return np.asarray(robot.loads.gravity_m_s2, dtype=float)

    def with_values(self, robot, x):
        return robot.with_changes(loads=replace(robot.loads, gravity_m_s2=tuple(float(v) for v in x)))

    def max_magnitude(self, robot: Robot) -> float:
        """The largest |g| a fit may need (m/s^2): 9.81 x E_file / E_true, E_true >= NiTi martensite."""
        return STANDARD_GRAVITY * robot.tubes[0].youngs_modulus_mpa * 1e-3 / NITI_E_GPA[0]

    def checks(self, robot):
        return super().checks(robot) + [Check("gravity_magnitude_m_s2", "m/s^2", _norm,
                                              Plausible(0.0, self.max_magnitude(robot), self.SOURCE))]

    def draw(self, robot, rng):
        # the robot lies horizontal (insertion axis level within 5 deg), rho*g/E within +-20 %
        phi, tilt = rng.uniform(0, 2 * math.pi), math.radians(rng.uniform(-5, 5))
        return STANDARD_GRAVITY * rng.uniform(0.8, 1.2) * np.array(
            [math.cos(phi) * math.cos(tilt), math.sin(phi) * math.cos(tilt), math.sin(tilt)])

    def derived(self, robot, x):
        g = np.asarray(x, dtype=float)
        mag = float(np.linalg.norm(g))
        t = robot.tubes[0]
        out = {"gravity_magnitude_m_s2": mag,
               "rho_g_over_E_per_m": t.density_kg_m3 * mag / (t.youngs_modulus_mpa * 1e6)}
        if mag > 0:
            out["angle_from_insertion_axis_deg"] = float(np.degrees(np.arccos(np.clip(g[2] / mag, -1, 1))))
        return out


class TipForce(Effect):
    name = "tip_force"
    key = "loads.tip_force_n"
    description = "point force at the tip of tube 1 (N), robot frame"
    MAX_N = 0.02
    SOURCE = "a sensor cable or tether on the tip of a robot in free space pulls a few mN; 20 mN ceiling"

    def params(self, robot):
        plausible = Plausible(-self.MAX_N, self.MAX_N, self.SOURCE)
        return [Param(f"tip_force_{a}_n", "N", 2e-3, -0.05, 0.05, plausible) for a in "xyz"]

    def values(self, robot):
        return np.asarray(robot.loads.tip_force_n, dtype=float)

    def with_values(self, robot, x):
        return robot.with_changes(loads=replace(robot.loads, tip_force_n=tuple(float(v) for v in x)))

    def checks(self, robot):
        return super().checks(robot) + [Check("tip_force_magnitude_n", "N", _norm,
                                              Plausible(0.0, self.MAX_N, self.SOURCE))]

    def derived(self, robot, x):
        return {"tip_force_magnitude_mn": 1e3 * float(np.linalg.norm(x))}


# ---- measurement side: the robot's calibration ---------------------------------------------------
class MeasurementEffect(Effect):
    """An effect of the measurement side (joints, tip or frame): a term of the robot's
    `ctrplan.measurement.Calibration`, kept under ``calibration.<key>`` in the robot file.

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


#: Every cause name, in definition order.
CAUSES = tuple(EFFECTS)


def cause_table(width: int = 100) -> str:
    """The registered causes as a reStructuredText table: cause, side, parameters (``description``)."""
    import textwrap

    name_w, side_w = max(map(len, ("cause", *CAUSES))) + 2, max(map(len, SIDES)) + 2
    rule = f"{'=' * (name_w - 2)}  {'=' * (side_w - 2)}  {'=' * (width - name_w - side_w)}"
    lines = [rule, f"{'cause':<{name_w}}{'side':<{side_w}}parameters (plausible range: see each `Param`)",
             rule]
    for name, cls in EFFECTS.items():
        text = textwrap.wrap(cls.description, width - name_w - side_w)
        lines.append(f"{name:<{name_w}}{cls.side:<{side_w}}{text[0]}")
        lines += [" " * (name_w + side_w) + more for more in text[1:]]
    return "\n".join([*lines, rule, ""])


if __doc__ is not None:  # the module's table of causes (absent under python -OO)
    __doc__ += cause_table()


# ---- several causes at once -----------------------------------------------------------------------
class Combined(Effect):
    """Several effects at once: their parameters concatenated, applied in order."""

    def __init__(self, effects: Sequence[Effect]):
        self.effects = tuple(effects)

    @property
    def causes(self) -> tuple[str, ...]:
        return tuple(c for e in self.effects for c in e.causes)

    def _parts(self, robot: Robot, x: np.ndarray):
        i = 0
        for e in self.effects:
            k = len(e.params(robot))
            yield e, x[i:i + k]
            i += k

    def params(self, robot):
        return [p for e in self.effects for p in e.params(robot)]

    def values(self, robot):
        return np.concatenate([e.values(robot) for e in self.effects])

    def with_values(self, robot, x):
        for e, xe in self._parts(robot, x):
            robot = e.with_values(robot, xe)
        return robot

    def unseen(self, q, direction, robot):
        return {k: v for e in self.effects for k, v in e.unseen(q, direction, robot).items()}

    def limits(self, q, robot):
        return {k: v for e in self.effects for k, v in e.limits(q, robot).items()}

    def checks(self, robot):
        out, i = [], 0
        for e in self.effects:
            k = len(e.params(robot))
            out += [replace(c, value=_shifted(c.value, i, k)) for c in e.checks(robot)]
            i += k
        return out

    def derived(self, robot, x):
        return {k: v for e, xe in self._parts(robot, x) for k, v in e.derived(robot, xe).items()}


def make_effect(name: str) -> Effect:
    """The effect of a cause name; ``a+b`` combines several."""
    parts = [p.strip() for p in name.split("+") if p.strip()]
    for p in parts:
        if p not in EFFECTS:
            raise InputError(f"unknown cause {p!r} (known: {', '.join(CAUSES)})")
    if len(parts) == 1:
        return EFFECTS[parts[0]]()
    return Combined([EFFECTS[p]() for p in parts])


# ---- helpers --------------------------------------------------------------------------------------
def numbers(doc: YamlDoc, keys: KeyPath, value: Any, n: int) -> tuple[float, ...]:
    """A list of ``n`` finite numbers from a robot file, or `InputError` naming the key."""
    ok = isinstance(value, list) and len(value) == n and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)
    if not ok:
        raise doc.error(keys, f"expected a list of {n} finite numbers, got {value!r}")
    return tuple(float(v) for v in value)


def _never_reverses(direction: np.ndarray, n: int) -> list[tuple[int, str]]:
    """Tubes (0-based) whose rotation never reverses its direction of motion, with the reason."""
    out = []
    for i in range(n):
        d = direction[:, n + i]
        if not ((d > 0).any() and (d < 0).any()):
            out.append((i, f"alpha{i + 1} never reverses its direction of motion"))
    return out


def offset_limits(q: np.ndarray, robot: Robot, share: float = 0.5,
                  margin_mm: float = 1e-6) -> dict[str, tuple[float, float]]:
    """Bounds on the beta zero offsets (mm, absolute) under which every row of ``q`` stays physically
    valid (tube order, bases behind the plate, inner tubes reaching furthest; `Robot.check_joints`).
    Each tube may use ``share`` of the slack of a pairwise constraint: 0.5 guarantees validity for
    any offsets in the box, 1.0 is each tube's own limit (check the fitted robot)."""
    n = q.shape[-1] // 2
    base = np.asarray(robot.joint_offset, dtype=float)[:n]
    b = np.asarray(q, dtype=float)[:, :n] + base
    ends = b + robot.lengths_mm
    lo, hi = np.full(n, -np.inf), np.full(n, np.inf)
    for i in range(n - 1):
        gap = max(float((b[:, i + 1] - b[:, i]).min()) - margin_mm, 0.0)      # beta_i <= beta_i+1
        hi[i], lo[i + 1] = min(hi[i], base[i] + share * gap), max(lo[i + 1], base[i + 1] - share * gap)
        gap = max(float((ends[:, i] - ends[:, i + 1]).min()) - margin_mm, 0.0)  # l_i >= l_i+1
        lo[i], hi[i + 1] = max(lo[i], base[i] - share * gap), min(hi[i + 1], base[i + 1] + share * gap)
    hi[n - 1] = min(hi[n - 1], base[n - 1] + max(float(-b[:, n - 1].max()) - margin_mm, 0.0))
    lo[n - 1] = max(lo[n - 1], base[n - 1] - max(float(ends[:, n - 1].min()) - 1e-3, 0.0))
    return {f"beta{i + 1}_offset_mm": (float(lo[i]), float(hi[i])) for i in range(n)}


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
