"""The robot model: tube parameters, loads, the snap-free joint domain, validation and sampling.

Everything here is immutable physical description (Pinocchio's *model*); solver workspaces and warm
starts live with the kinematics backends. Units at this interface: mm, rad, N, kg/m^3, m/s^2.

Joint vector, everywhere: ``q = [beta1, beta2, beta3, alpha1, alpha2, alpha3]`` (mm, rad); tube 1 is
the innermost (longest) tube. Tube i occupies arc length ``[beta_i, beta_i + L_i]``; ``s = 0`` is the
front plate.

Over 500 lines because it is the robot and its file format together: every physical parameter with its
YAML key, plausibility limit and error message, so that a new parameter touches one file.
"""

from __future__ import annotations

import hashlib
import json
import math
import warnings
from dataclasses import dataclass, field, fields, replace
from functools import cached_property
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from ctrplan.base.dataio import Table, atomic_write, joint_names, plain, read_table
from ctrplan.base.errors import DomainError, InputError
from ctrplan.base.yamlio import YamlDoc, load_yaml
from ctrplan.model.actuators import ACTUATORS_KEY, Actuator, actuators_from_yaml
from ctrplan.model.measurement import CALIBRATION_KEY, Calibration
from ctrplan.model.sessions import SESSION_COLUMN, SESSIONS_KEY, SessionValues

BUILTIN_ROBOTS = ("nominal",)


@dataclass(frozen=True)
class Tube:
    """One pre-curved nitinol tube. Lengths in mm, curvature in 1/mm, moduli in N/mm^2 (MPa).

    ``transmission_length_mm`` is the length over which the tube twists behind the plate beyond
    ``-beta`` (0: the model's tube starts where its rotation is imposed; > 0: a compliant drive;
    < 0: clamped nearer the plate). The Cosserat backend solves it; the PINN does not model it.
    """

    inner_diameter_mm: float
    outer_diameter_mm: float
    straight_length_mm: float
    curved_length_mm: float
    curvature_per_mm: float
    youngs_modulus_mpa: float = 50e3
    shear_modulus_mpa: float = 19.23e3
    density_kg_m3: float = 6450.0
    transmission_length_mm: float = 0.0

    @property
    def length_mm(self) -> float:
        return self.straight_length_mm + self.curved_length_mm

    @property
    def outer_radius_mm(self) -> float:
        return 0.5 * self.outer_diameter_mm

    @property
    def area_mm2(self) -> float:
        return math.pi / 4 * (self.outer_diameter_mm**2 - self.inner_diameter_mm**2)

    @property
    def second_moment_mm4(self) -> float:
        return math.pi / 64 * (self.outer_diameter_mm**4 - self.inner_diameter_mm**4)

    @property
    def bending_stiffness_nmm2(self) -> float:
        """E*I in N*mm^2."""
        return self.youngs_modulus_mpa * self.second_moment_mm4

    @property
    def torsional_stiffness_nmm2(self) -> float:
        """G*J in N*mm^2 (J = 2 I for a circular tube)."""
        return self.shear_modulus_mpa * 2.0 * self.second_moment_mm4


@dataclass(frozen=True)
class Loads:
    """External loads: gravity (m/s^2, robot frame) on tube material in front of the plate, a point
    force (N, robot frame) at the tip of tube 1, and a follower force (N) at that tip fixed in its tip
    frame (x, y: across the tube, y in the plane tube 1's curvature bends it; z: along its tangent,
    distal) -- a lead or tether pulling on the tip, which turns with it."""

    gravity_m_s2: tuple[float, float, float] = (0.0, 0.0, 0.0)
    tip_force_n: tuple[float, float, float] = (0.0, 0.0, 0.0)
    tip_follower_force_n: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def is_free(self) -> bool:
        return not any(self.gravity_m_s2) and not any(self.tip_force_n) and not self.has_follower

    @property
    def has_follower(self) -> bool:
        """A follower force at the tip: the force in the robot frame depends on the solved tip frame."""
        return any(self.tip_follower_force_n)

    @property
    def axisymmetric(self) -> bool:
        """Loads along z only (or none) in the robot frame: rotating every tube by the same angle then
        rotates the whole robot about z, a symmetry the PINN's equivariant encoding builds in. A follower
        force turns with the tip, so it keeps the symmetry."""
        return not any(self.gravity_m_s2[:2]) and not any(self.tip_force_n[:2])


@dataclass(frozen=True)
class JointLimits:
    """Actuation limits for timed trajectories (robot file ``limits:``): speed and acceleration of
    every translation (mm/s, mm/s^2) and rotation (rad/s, rad/s^2). The defaults are those of a
    bench-top CTR actuation unit, slow enough for a surgeon to follow."""

    speed_mm_per_s: float = 10.0
    speed_rad_per_s: float = 1.0
    acceleration_mm_per_s2: float = 50.0
    acceleration_rad_per_s2: float = 5.0

    def per_joint(self, n_tubes: int) -> tuple[np.ndarray, np.ndarray]:
        """Speed and acceleration limits (2N,) in joint order (betas, then alphas)."""
        speed = np.r_[np.full(n_tubes, self.speed_mm_per_s), np.full(n_tubes, self.speed_rad_per_s)]
        accel = np.r_[np.full(n_tubes, self.acceleration_mm_per_s2),
                      np.full(n_tubes, self.acceleration_rad_per_s2)]
        return speed, accel


def _refs(n_tubes: int, relative_to: tuple[int, ...] = ()) -> tuple[int, ...]:
    return tuple(relative_to) or (-1,) * n_tubes


def box_names(n_tubes: int, relative_to: tuple[int, ...] = ()) -> tuple[str, ...]:
    """Box coordinates ``(betaN, betaN - betaN-1, …, beta2 - beta1, alpha1 … alphaN)``; with
    ``relative_to`` (per tube, 0-based, -1: none) a tube's rotation coordinate is ``alphaJ - alphaI``."""
    refs = _refs(n_tubes, relative_to)
    return ((f"beta{n_tubes}",) + tuple(f"beta{i + 1} - beta{i}" for i in range(n_tubes - 1, 0, -1))
            + tuple(f"alpha{j + 1}" if r < 0 else f"alpha{j + 1} - alpha{r + 1}" for j, r in enumerate(refs)))


def box_keys(n_tubes: int, relative_to: tuple[int, ...] = ()) -> tuple[str, ...]:
    """Robot-file keys of the box coordinates (mm, rad): ``beta3_mm``, ``beta3_minus_beta2_mm``, …,
    then one ``alphaJ_rad`` per tube (a shared ``alpha_rad`` sets them all), or ``alphaJ_minus_alphaI_rad``
    for a relative rotation (`box_names`)."""
    return tuple(name.replace(" - ", "_minus_") + ("_mm" if name.startswith("beta") else "_rad")
                 for name in box_names(n_tubes, relative_to))


def _box_matrix(n_tubes: int, relative_to: tuple[int, ...] = ()) -> np.ndarray:
    """The linear map box = M q for N tubes (2N, 2N): lower triangular with a unit diagonal in the
    rotations (a coordinate is alpha_J or alpha_J - alpha_I, I < J), so always invertible."""
    n = n_tubes
    M = np.zeros((2 * n, 2 * n))
    M[0, n - 1] = 1.0
    for r, i in enumerate(range(n - 1, 0, -1), start=1):  # beta_{i+1} - beta_i
        M[r, i] = 1.0
        M[r, i - 1] = -1.0
    M[n:, n:] = np.eye(n)
    for j, ref in enumerate(_refs(n, relative_to)):
        if ref >= 0:
            M[n + j, n + ref] = -1.0
    return M


#: One turn (rad): a rotation interval at least this wide wraps (`JointDomain.wraps`).
TURN = 2.0 * math.pi

#: Joint names of a three-tube robot (the CSV header of three-tube files).
JOINT_NAMES = joint_names(3)

#: The paper's snap-free box for the three-tube Table I robot (Remark in III-B), mm and rad.
PAPER_BOX = ((-10.0, 0.0), (0.0, 55.0), (0.0, 15.0)) + ((-math.pi, math.pi),) * 3


@dataclass(frozen=True)
class JointDomain:
    """The actuation domain: a box in ``(betaN, betaN - betaN-1, …, beta2 - beta1, alpha1 … alphaN)``;
    with ``relative_to`` (per tube, 0-based index I < J of another tube, -1 none) tube J's rotation
    coordinate is ``alphaJ - alphaI`` instead: a limit on a relative rotation (the part of the
    domain where the robot does not snap) is then a box too, sampled exactly.

    ``bounds`` are (lower, upper) per box coordinate (mm, rad), 2N of them; a zero-width interval is a
    fixed joint. ``box_lower``/``box_upper`` are the corners (2N,). The default is the paper's box for
    its three-tube robot. A rotation whose interval spans a full turn wraps (`wraps`): any value is
    inside, as the same angle one or more turns on; a narrower one is an actuator's limit, compared
    as it stands.
    """

    bounds: tuple[tuple[float, float], ...] = PAPER_BOX
    relative_to: tuple[int, ...] = ()

    @property
    def n_tubes(self) -> int:
        return len(self.bounds) // 2

    @cached_property
    def names(self) -> tuple[str, ...]:
        """The box coordinates' names (`box_names`)."""
        return box_names(self.n_tubes, self.relative_to)

    @cached_property
    def keys(self) -> tuple[str, ...]:
        """The box coordinates' robot-file keys (`box_keys`)."""
        return box_keys(self.n_tubes, self.relative_to)

    @cached_property
    def box_lower(self) -> np.ndarray:
        return np.array([b[0] for b in self.bounds])

    @cached_property
    def box_upper(self) -> np.ndarray:
        return np.array([b[1] for b in self.bounds])

    @cached_property
    def wraps(self) -> np.ndarray:
        """Which box coordinates are rotations whose interval spans a full turn (2N,) bool."""
        rotation = np.arange(len(self.bounds)) >= self.n_tubes
        return rotation & (self.box_upper - self.box_lower >= TURN * (1.0 - 1e-12))

    @cached_property
    def fixed(self) -> np.ndarray:
        """Which box coordinates are fixed (zero-width interval), (2N,) bool."""
        return self.box_upper - self.box_lower <= 0.0

    @cached_property
    def box_from_joints(self) -> np.ndarray:
        """M (2N, 2N) with box = M q."""
        return _box_matrix(self.n_tubes, self.relative_to)

    @cached_property
    def joints_from_box(self) -> np.ndarray:
        """M^-1 (2N, 2N) with q = M^-1 box."""
        return np.linalg.inv(self.box_from_joints)

    def to_box(self, q: np.ndarray) -> np.ndarray:
        """Joints (..., 2N) -> box coordinates (..., 2N)."""
        return np.asarray(q, dtype=float) @ self.box_from_joints.T

    def from_box(self, x: np.ndarray) -> np.ndarray:
        """Box coordinates (..., 2N) -> joints (..., 2N)."""
        return np.asarray(x, dtype=float) @ self.joints_from_box.T

    def sample(self, n: int, rng: np.random.Generator | int | None = None) -> np.ndarray:
        """``n`` joint vectors (n, 2N) drawn uniformly in the box coordinates."""
        rng = np.random.default_rng(rng)
        x = rng.uniform(self.box_lower, self.box_upper, size=(n, len(self.bounds)))
        return self.from_box(x)

    def violations(self, q: np.ndarray, tol: float = 1e-9) -> list[tuple[int, str]]:
        """``(row, message)`` for the first violated inequality of every offending row of q (..., 2N)."""
        box = self.to_box(np.atleast_2d(q))
        lo = self.box_lower[self.wraps]
        box[:, self.wraps] = lo + np.mod(box[:, self.wraps] - lo, TURN)
        lo, hi = self.box_lower - tol, self.box_upper + tol
        bad = (box < lo) | (box > hi)
        names = self.names
        out = []
        for r in np.flatnonzero(bad.any(axis=1)):
            c = int(np.argmax(bad[r]))
            out.append((int(r), f"{self.box_lower[c]:g} <= {names[c]} <= {self.box_upper[c]:g} violated "
                                f"({names[c]} = {box[r, c]:.6g})"))
        return out

    def impossible(self, lengths_mm: np.ndarray) -> tuple[int, str] | None:
        """The first box coordinate whose interval holds physically impossible configurations of
        tubes of ``lengths_mm`` (N,), as ``(index, message naming the limit)``; None if every
        configuration of the box is possible (so `sample` never draws an impossible one).

        Possible: tube N's base behind the plate and its tip in front of it,
        ``-L_N < beta_N <= 0``, and no tube reaching past an inner one,
        ``beta_{i+1} - beta_i <= L_i - L_{i+1}`` (tube order, ``>= 0``, is checked on loading)."""
        n, L = self.n_tubes, np.asarray(lengths_mm, dtype=float)
        names = box_names(n)
        lo, hi = self.bounds[0]
        if hi > 0.0:
            return 0, (f"{names[0]} up to {hi:g} mm puts tube {n}'s base in front of the plate: "
                       f"need {names[0]} <= 0")
        if lo <= -L[n - 1]:
            return 0, (f"{names[0]} down to {lo:g} mm pulls tube {n} behind the plate: need {names[0]} > "
                       f"-L{n} = {-L[n - 1]:g} mm")
        for c in range(1, n):
            i = n - c  # coordinate c is beta_{i+1} - beta_i (tubes 1-based)
            limit = L[i - 1] - L[i]
            if self.bounds[c][1] > limit + 1e-9:
                return c, (f"{names[c]} up to {self.bounds[c][1]:g} mm puts tube {i + 1}'s tip past tube "
                           f"{i}'s: need {names[c]} <= L{i} - L{i + 1} = {limit:g} mm")
        return None

    def to_dict(self) -> dict[str, list[float]]:
        """File form: one key per box coordinate; the alphas share ``alpha_rad`` when equal (and
        absolute)."""
        keys = self.keys
        n = self.n_tubes
        out = {k: list(b) for k, b in zip(keys[:n], self.bounds[:n], strict=True)}
        alphas = self.bounds[n:]
        if all(a == alphas[0] for a in alphas) and all(r < 0 for r in _refs(n, self.relative_to)):
            out["alpha_rad"] = list(alphas[0])
        else:
            out.update({k: list(b) for k, b in zip(keys[n:], alphas, strict=True)})
        return out


@dataclass(frozen=True)
class Robot:
    """Immutable description of a CTR of N = 1…4 tubes: tubes (1 = innermost), loads, joint domain.

    Joints ``q = [beta_1 … beta_N, alpha_1 … alpha_N]`` (mm, rad). ``joint_offset`` (2N,) is added to
    every commanded q by the backends (zero offsets of beta in mm and alpha in rad: mechanics).
    ``calibration`` is the measurement side (`ctrplan.model.measurement.Calibration`: backlash, windup,
    sensor offset, registration); backends never apply it -- backbones stay in the robot frame -- but
    measured-data tools and `fk`/`shape` on ordered rows do. `mechanics` is the robot without it.
    """

    tubes: tuple[Tube, ...]
    domain: JointDomain = field(default_factory=JointDomain)
    loads: Loads = field(default_factory=Loads)
    joint_offset: tuple[float, ...] = ()
    calibration: Calibration = field(default_factory=Calibration)
    name: str = "custom"
    limits: JointLimits = field(default_factory=JointLimits)
    sessions: SessionValues = field(default_factory=SessionValues)
    actuators: tuple[Actuator, ...] = ()

    def __post_init__(self) -> None:
        n = len(self.tubes)
        if not self.joint_offset:
            object.__setattr__(self, "joint_offset", (0.0,) * (2 * n))
        if not 1 <= n <= MAX_TUBES:
            raise InputError(f"robot: expected 1 to {MAX_TUBES} tubes, got {n}")
        if self.domain.n_tubes != n:
            raise InputError(f"robot: the joint domain is for {self.domain.n_tubes} tubes, the robot has {n}")
        if len(self.joint_offset) != 2 * n:
            raise InputError(f"robot: joint_offset needs {2 * n} values, got {len(self.joint_offset)}")
        bad = self.domain.impossible(self.lengths_mm)
        if bad is not None:
            raise InputError(f"robot {self.name}: domain: {bad[1]}")

    # ---- construction -------------------------------------------------------------------------
    @classmethod
    def nominal(cls) -> Robot:
        """The paper's Table I robot (built in)."""
        return cls.load("nominal")

    @classmethod
    def load(cls, spec: str | Path | None = None) -> Robot:
        """Load a built-in robot by name (`BUILTIN_ROBOTS`) or a robot YAML file; None -> nominal."""
        if spec is None or str(spec) in BUILTIN_ROBOTS:
            name = "nominal" if spec is None else str(spec)
            with resources.as_file(resources.files("ctrplan.data") / f"{name}.yaml") as p:
                return robot_from_yaml(load_yaml(p))
        return robot_from_yaml(load_yaml(spec))

    def with_changes(self, **changes: Any) -> Robot:
        return replace(self, **changes)

    @property
    def mechanics(self) -> Robot:
        """The pure mechanics: this robot without its measurement-side calibration (what a backend
        solves and a PINN is trained on; joint offsets, loads and tube parameters kept) and without the
        values that differ between measurement sessions (its shared values)."""
        if self.calibration.is_identity and not self.sessions:
            return self
        return replace(self, calibration=Calibration(), sessions=SessionValues())

    def for_session(self, session: str) -> Robot:
        """The robot of measurement session ``session`` (`ctrplan.model.sessions`): the shared robot
        with the values that differ in that session (the shared robot for a session it does not name)."""
        return self.sessions.apply(self, session) if self.sessions else self

    def save(self, path: str | Path, comment: str = "") -> None:
        """Write the robot file (`to_dict`, atomic); ``comment`` lines go on top as YAML comments."""
        import yaml

        text = yaml.safe_dump(plain(self.to_dict()), sort_keys=False, default_flow_style=None, width=100)
        head = "".join(f"# {ln}\n" if ln else "#\n" for ln in comment.splitlines())
        with atomic_write(path) as fh:
            fh.write(head + text)

    # ---- derived ------------------------------------------------------------------------------
    @property
    def n_tubes(self) -> int:
        return len(self.tubes)

    @property
    def n_joints(self) -> int:
        """2N: N translations, then N rotations."""
        return 2 * len(self.tubes)

    @property
    def n_states(self) -> int:
        """Length of the Cosserat state, 2N + 9 (`ctrplan.kinematics.backbone.state_names`)."""
        return 2 * len(self.tubes) + 9

    @property
    def joint_names(self) -> tuple[str, ...]:
        return joint_names(len(self.tubes))

    @cached_property
    def lengths_mm(self) -> np.ndarray:
        return np.array([t.length_mm for t in self.tubes])

    @cached_property
    def outer_radii_mm(self) -> np.ndarray:
        return np.array([t.outer_radius_mm for t in self.tubes])

    def tube_ends_mm(self, q: np.ndarray) -> np.ndarray:
        """Distal ends ``l_i = beta_i + L_i`` (..., N) for joints (..., 2N) (offsets applied)."""
        q = self.apply_offset(q)
        return q[..., :self.n_tubes] + self.lengths_mm

    def apply_offset(self, q: np.ndarray) -> np.ndarray:
        return np.asarray(q, dtype=float) + np.asarray(self.joint_offset)

    def to_dict(self) -> dict[str, Any]:
        """Plain, JSON/YAML-ready description in file units (the format `Robot.load` reads)."""
        # a key at its default is left out when the default is 0: older files and fingerprints unchanged
        tubes = [{key: getattr(t, attr) / scale for key, (attr, scale) in _TUBE_KEYS.items()
                  if key not in _OPTIONAL_TUBE_KEYS or getattr(t, attr)} for t in self.tubes]
        out = {
            "name": self.name,
            "tubes": tubes,
            "domain": self.domain.to_dict(),
            "loads": {"gravity_m_s2": list(self.loads.gravity_m_s2),
                      "tip_force_n": list(self.loads.tip_force_n),
                      **({"tip_follower_force_n": list(self.loads.tip_follower_force_n)}
                         if self.loads.has_follower else {})},   # absent when 0: fingerprints unchanged
            "joint_offset": list(self.joint_offset),
        }
        if not self.calibration.is_identity:  # absent when unused: fingerprints stay stable
            out[CALIBRATION_KEY] = self.calibration.to_dict()
        if self.sessions:
            out[SESSIONS_KEY] = self.sessions.to_dict(self)
        if self.limits != JointLimits():
            out["limits"] = dict(vars(self.limits))
        if self.actuators:
            names = self.joint_names
            out[ACTUATORS_KEY] = {names[a.joint]: a.to_dict(names) for a in self.actuators}
        return out

    @cached_property
    def fingerprint(self) -> str:
        """SHA-256 of every parameter that changes the mechanics or the domain (not the name, not the
        measurement-side calibration: a PINN or a stability certificate of the mechanics holds for
        every way of measuring it).

        Numbers enter at 12 significant digits, so a robot survives a round trip through its file.
        """
        d = self.mechanics.to_dict()
        d.pop("name")
        d.pop("limits", None)  # how fast it is driven is not mechanics
        d.pop(ACTUATORS_KEY, None)  # nor in which units
        text = json.dumps(_rounded(d), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()

    # ---- joints ---------------------------------------------------------------------------------
    def check_joints(self, q: np.ndarray, *, allow_outside_domain: bool = False,
                     where: str = "q", row_offset: int = 0) -> np.ndarray:
        """Validate joints (2N,) or (B, 2N); return them as a float array of the same shape.

        Non-finite values and physically impossible configurations (tube order, a tube base in
        front of the plate, an outer tube reaching past an inner one) raise `InputError`. Leaving the
        domain raises `DomainError`, or only warns with ``allow_outside_domain``.
        ``where``/``row_offset`` name the source in messages (e.g. a file and its first data row).
        """
        n, nj = self.n_tubes, self.n_joints
        names = self.joint_names
        arr = np.asarray(q, dtype=float)
        if arr.shape[-1:] != (nj,) or arr.ndim not in (1, 2):
            raise InputError(f"{where}: expected joints of shape ({nj},) or (N, {nj}) "
                             f"({','.join(names)}), got {arr.shape}")
        rows = arr.reshape(-1, nj)
        bad = ~np.isfinite(rows)
        if bad.any():
            r, c = np.argwhere(bad)[0]
            raise InputError(f"{where}: row {r + row_offset}: {names[c]} is not a finite number")
        qe = self.apply_offset(rows)
        ends = qe[:, :n] + self.lengths_mm
        problems = []
        for i in range(n - 1):
            problems += [
                (qe[:, i] > qe[:, i + 1] + 1e-9, f"tube order violated: need beta{i + 1} <= beta{i + 2}"),
                (ends[:, i] < ends[:, i + 1] - 1e-9,
                 f"tube {i + 2} reaches past tube {i + 1}: "
                 f"need beta{i + 1} + L{i + 1} >= beta{i + 2} + L{i + 2}"),
            ]
        problems += [
            (qe[:, n - 1] > 1e-9, f"tube {n} base in front of the plate: need beta{n} <= 0"),
            (ends[:, n - 1] <= 0, f"tube {n} does not reach the plate: need beta{n} + L{n} > 0"),
        ]
        for mask, message in problems:
            if mask.any():
                r = int(np.argmax(mask))
                raise InputError(f"{where}: row {r + row_offset}: {message} "
                                 f"(q = {np.array2string(rows[r], precision=4)})")
        outside = self.domain.violations(rows)
        if outside:
            r, v = outside[0]
            more = f" (and {len(outside) - 1} more rows)" if len(outside) > 1 else ""
            msg = f"{where}: row {r + row_offset}: outside the snap-free domain: {v}{more}"
            if not allow_outside_domain:
                raise DomainError(msg)
            warnings.warn(msg, stacklevel=2)
        return arr

    def sample_joints(self, n: int, rng: np.random.Generator | int | None = None) -> np.ndarray:
        """``n`` configurations (n, 2N) uniform in the domain box (mm, rad)."""
        return self.domain.sample(n, rng)


def _rounded(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: _rounded(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_rounded(v) for v in obj]
    if isinstance(obj, float):
        return float(f"{obj:.12g}")
    return obj


# ---- YAML ---------------------------------------------------------------------------------------
#: file key -> (Tube attribute, factor from file unit to attribute unit)
_TUBE_KEYS = {
    "inner_diameter_mm": ("inner_diameter_mm", 1.0),
    "outer_diameter_mm": ("outer_diameter_mm", 1.0),
    "straight_length_mm": ("straight_length_mm", 1.0),
    "curved_length_mm": ("curved_length_mm", 1.0),
    "curvature_1_per_m": ("curvature_per_mm", 1e-3),
    "youngs_modulus_gpa": ("youngs_modulus_mpa", 1e3),
    "shear_modulus_gpa": ("shear_modulus_mpa", 1e3),
    "density_kg_m3": ("density_kg_m3", 1.0),
    "transmission_length_mm": ("transmission_length_mm", 1.0),
}
#: Tube keys written only when not 0.
_OPTIONAL_TUBE_KEYS = ("transmission_length_mm",)
_REQUIRED_TUBE_KEYS = ("inner_diameter_mm", "outer_diameter_mm", "straight_length_mm",
                       "curved_length_mm", "curvature_1_per_m")

#: Physically plausible range of every tube field, in file units: (low, high, what the limit is).
#: Outside it a robot file is refused; the message names the limit.
TUBE_LIMITS = {
    "inner_diameter_mm": (0.0, 20.0, "diameters of CTR tubes are below 20 mm"),
    "outer_diameter_mm": (0.01, 20.0, "diameters of CTR tubes are 0.01 mm to 20 mm"),
    "straight_length_mm": (0.0, 2000.0, "tube lengths are below 2 m"),
    "curved_length_mm": (0.0, 2000.0, "tube lengths are below 2 m"),
    "curvature_1_per_m": (0.0, 1000.0, "pre-curvature is below 1000 1/m (1 mm radius)"),
    "youngs_modulus_gpa": (1.0, 1000.0, "Young's modulus of tube materials is 1 GPa to 1000 GPa"),
    "shear_modulus_gpa": (0.3, 500.0, "shear modulus of tube materials is 0.3 GPa to 500 GPa"),
    "density_kg_m3": (100.0, 25000.0, "density of tube materials is 100 to 25,000 kg/m^3"),
    "transmission_length_mm": (-2000.0, 2000.0, "tube lengths are below 2 m"),
}
#: Largest bending strain a pre-curved tube can hold, kappa * outer radius (superelastic nitinol
#: recovers about 8 %; 10 % is the ceiling of any tube material).
MAX_PRECURVE_STRAIN = 0.10
MAX_GRAVITY_M_S2 = 1000.0
MAX_TIP_FORCE_N = 100.0
MAX_TUBES = 4


def _number(doc: YamlDoc, keys: tuple, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise doc.error(keys, f"expected a finite number, got {value!r}")
    return float(value)


def _vector(doc: YamlDoc, keys: tuple, value: Any, n: int) -> tuple[float, ...]:
    if not isinstance(value, list) or len(value) != n:
        raise doc.error(keys, f"expected a list of {n} numbers, got {value!r}")
    return tuple(_number(doc, keys + (i,), v) for i, v in enumerate(value))


def _unknown(doc: YamlDoc, keys: tuple, mapping: dict, allowed) -> None:
    for k in mapping:
        if k not in allowed:
            raise doc.error(keys + (k,), f"unknown key (allowed: {', '.join(sorted(allowed))})")


def _tube_from_yaml(doc: YamlDoc, i: int, raw: Any) -> Tube:
    keys = ("tubes", i)
    if not isinstance(raw, dict):
        raise doc.error(keys, "expected a mapping of tube parameters")
    _unknown(doc, keys, raw, _TUBE_KEYS)
    for k in _REQUIRED_TUBE_KEYS:
        if k not in raw:
            raise doc.error(keys, f"missing required key {k!r}")
    values = {k: _number(doc, keys + (k,), raw[k]) for k in _TUBE_KEYS if k in raw}
    for k, v in values.items():
        lo, hi, why = TUBE_LIMITS[k]
        if not lo <= v <= hi:
            raise doc.error(keys + (k,), f"{v:g} is outside the physical range [{lo:g}, {hi:g}] ({why})")
    tube = Tube(**{attr: values[k] * scale for k, (attr, scale) in _TUBE_KEYS.items() if k in values})
    if tube.length_mm <= 0:
        raise doc.error(keys + ("curved_length_mm",), "straight and curved length are both 0: the tube "
                                                       "has no length")
    if tube.inner_diameter_mm >= tube.outer_diameter_mm:
        raise doc.error(keys + ("inner_diameter_mm",),
                        f"inner diameter {tube.inner_diameter_mm} mm must be < outer diameter "
                        f"{tube.outer_diameter_mm} mm")
    strain = tube.curvature_per_mm * tube.outer_radius_mm
    if tube.curved_length_mm > 0 and strain > MAX_PRECURVE_STRAIN:
        raise doc.error(keys + ("curvature_1_per_m",),
                        f"pre-curvature {values['curvature_1_per_m']:g} 1/m bends a tube of outer diameter "
                        f"{tube.outer_diameter_mm:g} mm to {100 * strain:.0f} % strain; no tube survives "
                        f"more than {100 * MAX_PRECURVE_STRAIN:.0f} % (kappa * OD / 2)")
    poisson = tube.youngs_modulus_mpa / (2 * tube.shear_modulus_mpa) - 1
    if not -1.0 < poisson <= 0.5:
        raise doc.error(keys + ("shear_modulus_gpa",),
                        f"E / (2 G) - 1 = {poisson:.3g} is not a Poisson ratio of a real material (-1, 0.5]")
    return tube


def _domain_from_yaml(doc: YamlDoc, n: int) -> JointDomain:
    if "domain" not in doc.data:
        if n == 3:
            return JointDomain()
        raise doc.error(("tubes",), f"a robot of {n} tubes needs a 'domain' mapping with the keys "
                                    f"{', '.join(box_keys(n)[:n])}, alpha_rad")
    raw = doc.data["domain"]
    if not isinstance(raw, dict):
        raise doc.error(("domain",), "expected a mapping")
    relative = {f"alpha{j + 1}_minus_alpha{i + 1}_rad": (j, i) for j in range(n) for i in range(j)}
    _unknown(doc, ("domain",), raw, set(box_keys(n)) | {"alpha_rad"} | set(relative))
    refs = [-1] * n
    for key, (j, i) in relative.items():
        if key in raw:
            if refs[j] >= 0 or f"alpha{j + 1}_rad" in raw:
                raise doc.error(("domain", key), f"tube {j + 1}'s rotation is limited twice (give one of "
                                                 f"alpha{j + 1}_rad, alpha{j + 1}_minus_alphaI_rad)")
            refs[j] = i
    keys = box_keys(n, tuple(refs))
    bounds: list[tuple[float, float] | None] = [None] * (2 * n)
    if n == 3:
        bounds = list(PAPER_BOX)
    if "alpha_rad" in raw:
        bounds[n:] = [_vector(doc, ("domain", "alpha_rad"), raw["alpha_rad"], 2)] * n
    for c, k in enumerate(keys):
        if k in raw:
            bounds[c] = _vector(doc, ("domain", k), raw[k], 2)
    for c, b in enumerate(bounds):
        key = keys[c] if keys[c] in raw or c < n else "alpha_rad"
        if b is None:
            raise doc.error(("domain",), f"missing {keys[c] if c < n else keys[c] + ' or alpha_rad'}")
        if b[0] > b[1]:
            raise doc.error(("domain", key), f"lower bound {b[0]:g} exceeds upper bound {b[1]:g}")
        if c >= n and (b[0] < -2 * math.pi or b[1] > 2 * math.pi):
            raise doc.error(("domain", key), "rotations must lie within [-2 pi, 2 pi] rad")
        if 0 < c < n and b[0] < 0:
            raise doc.error(("domain", key), "tube order needs a difference of translations >= 0")
    return JointDomain(tuple(bounds), tuple(refs) if any(r >= 0 for r in refs) else ())


def robot_from_yaml(doc: YamlDoc) -> Robot:
    """Build a validated `Robot` from a parsed robot file; errors name the key and line."""
    d = doc.data
    _unknown(doc, (), d, {"name", "tubes", "domain", "loads", "joint_offset", "limits", CALIBRATION_KEY,
                          SESSIONS_KEY, ACTUATORS_KEY})
    tubes_raw = d.get("tubes")
    if not isinstance(tubes_raw, list) or not 1 <= len(tubes_raw) <= MAX_TUBES:
        raise doc.error(("tubes",), f"expected a list of 1 to {MAX_TUBES} tubes (innermost first)")
    tubes = [_tube_from_yaml(doc, i, raw) for i, raw in enumerate(tubes_raw)]
    n = len(tubes)
    for i in range(n - 1):
        if tubes[i].outer_diameter_mm > tubes[i + 1].inner_diameter_mm:
            raise doc.error(("tubes", i + 1, "inner_diameter_mm"),
                            f"tube {i + 2} (inner diameter {tubes[i + 1].inner_diameter_mm} mm) cannot "
                            f"hold tube {i + 1} (outer diameter {tubes[i].outer_diameter_mm} mm)")
        if tubes[i].length_mm < tubes[i + 1].length_mm:
            raise doc.error(("tubes", i, "straight_length_mm"),
                            f"tube {i + 1} must be at least as long as tube {i + 2}")
    domain = _domain_from_yaml(doc, n)
    bad = domain.impossible(np.array([t.length_mm for t in tubes]))
    if bad is not None:
        raise doc.error(("domain", domain.keys[bad[0]]), bad[1])

    loads = Loads()
    if "loads" in d:
        raw = d["loads"]
        if not isinstance(raw, dict):
            raise doc.error(("loads",), "expected a mapping")
        _unknown(doc, ("loads",), raw, {"gravity_m_s2", "tip_force_n", "tip_follower_force_n"})
        loads = Loads(**{k: _vector(doc, ("loads", k), v, 3) for k, v in raw.items()})
        for k, limit in (("gravity_m_s2", MAX_GRAVITY_M_S2), ("tip_force_n", MAX_TIP_FORCE_N),
                         ("tip_follower_force_n", MAX_TIP_FORCE_N)):
            if np.linalg.norm(getattr(loads, k)) > limit:
                raise doc.error(("loads", k), f"magnitude above the physical range of a CTR ({limit:g})")

    offset = (0.0,) * (2 * n)
    if "joint_offset" in d:
        offset = _vector(doc, ("joint_offset",), d["joint_offset"], 2 * n)
        if any(abs(v) > 1000.0 for v in offset[:n]) or any(abs(v) > 2 * math.pi for v in offset[n:]):
            raise doc.error(("joint_offset",), "offsets must be within 1000 mm and 2 pi rad")

    calibration = Calibration.from_doc(doc, n)
    name = d.get("name", doc.path.stem)
    robot = Robot(tubes=tuple(tubes), domain=domain, loads=loads, joint_offset=offset,
                  calibration=calibration, name=str(name), limits=_limits_from_yaml(doc),
                  actuators=actuators_from_yaml(doc, joint_names(n)))
    if SESSIONS_KEY in d:
        sessions = SessionValues.from_doc(doc, (SESSIONS_KEY,), d[SESSIONS_KEY], robot)
        robot = robot.with_changes(sessions=sessions)
    return robot


def robot_from_dict(data: dict[str, Any], where: str) -> Robot:
    """A `Robot` from a robot-file dict (what `Robot.to_dict` writes) through `robot_from_yaml`
    (`InputError` when it refuses; ``where`` names the source in its message)."""
    return robot_from_yaml(YamlDoc(data=data, path=Path(where), lines={}))


def _limits_from_yaml(doc: YamlDoc) -> JointLimits:
    raw = doc.data.get("limits")
    if raw is None:
        return JointLimits()
    if not isinstance(raw, dict):
        raise doc.error(("limits",), "expected a mapping")
    allowed = {f.name for f in fields(JointLimits)}
    _unknown(doc, ("limits",), raw, allowed)
    values = {k: _number(doc, ("limits", k), v) for k, v in raw.items()}
    for k, v in values.items():
        if not 0.0 < v < 1e6:
            raise doc.error(("limits", k), f"must be > 0 (and finite), got {v:g}")
    return JointLimits(**values)


def read_joints(path: str | Path, robot: Robot, *, allow_outside_domain: bool = False) -> Table:
    """Read a configurations CSV (header ``beta1,...,betaN,alpha1,...,alphaN`` for the robot's N tubes,
    optionally a ``session`` column: `Table.labels`) and validate every row against ``robot``.

    Out-of-domain rows raise `DomainError` (or warn, with ``allow_outside_domain``) naming the row's
    line and the violated inequality; physically impossible rows always raise `InputError`.
    """
    table = read_table(path, robot.joint_names, n_tubes=robot.n_tubes, labels=(SESSION_COLUMN,))
    check_joint_rows(robot, table.joints, table.lines, str(table.path),
                     allow_outside_domain=allow_outside_domain)
    return table


def check_joint_rows(robot: Robot, q: np.ndarray, lines: np.ndarray, where: str, *,
                     allow_outside_domain: bool = False) -> None:
    """`Robot.check_joints` on joints ``q`` (N, 6) read from lines ``lines`` (N,) of file ``where``,
    so that every message names the row's line in the file."""
    if len(q) == 0:
        return
    # check_joints numbers rows from an offset; split where skipped blank lines break the numbering.
    runs = np.split(np.arange(len(q)), np.flatnonzero(np.diff(lines) != 1) + 1)
    for run in runs:
        robot.check_joints(q[run], allow_outside_domain=allow_outside_domain, where=where,
                           row_offset=int(lines[run[0]]))
