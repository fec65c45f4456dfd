"""The robot model: tube parameters, loads, the snap-free joint domain, validation and sampling.

Everything here is immutable physical description (Pinocchio's *model*); solver workspaces and warm
starts live with the kinematics backends. Units at this interface: mm, rad, N, kg/m^3, m/s^2.

Joint vector, everywhere: ``q = [beta1, beta2, beta3, alpha1, alpha2, alpha3]`` (mm, rad); tube 1 is
the innermost (longest) tube. Tube i occupies arc length ``[beta_i, beta_i + L_i]``; ``s = 0`` is the
front plate.
"""

from __future__ import annotations

import hashlib
import json
import math
import warnings
from dataclasses import asdict, dataclass, field, replace
from functools import cached_property
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from ctrplan.measurement import CALIBRATION_KEY, Calibration
from ctrplan.errors import DomainError, InputError
from ctrplan.yamlio import YamlDoc, load_yaml

JOINT_NAMES = ("beta1", "beta2", "beta3", "alpha1", "alpha2", "alpha3")
BUILTIN_ROBOTS = ("nominal",)


@dataclass(frozen=True)
class Tube:
    """One pre-curved nitinol tube. Lengths in mm, curvature in 1/mm, moduli in N/mm^2 (MPa)."""

    inner_diameter_mm: float
    outer_diameter_mm: float
    straight_length_mm: float
    curved_length_mm: float
    curvature_per_mm: float
    youngs_modulus_mpa: float = 50e3
    shear_modulus_mpa: float = 19.23e3
    density_kg_m3: float = 6450.0

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
    """External loads in the robot frame: gravity (m/s^2) on tube material in front of the plate,
    and a point force (N) at the tip of tube 1."""

    gravity_m_s2: tuple[float, float, float] = (0.0, 0.0, 0.0)
    tip_force_n: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def is_free(self) -> bool:
        return not any(self.gravity_m_s2) and not any(self.tip_force_n)


@dataclass(frozen=True)
class JointDomain:
    """Snap-free domain: a box in ``(beta3, beta3-beta2, beta2-beta1, alpha1, alpha2, alpha3)``.

    Bounds in mm and rad. ``box_lower``/``box_upper`` are the box corners, shape (6,).
    """

    beta3_mm: tuple[float, float] = (-10.0, 0.0)
    beta3_minus_beta2_mm: tuple[float, float] = (0.0, 55.0)
    beta2_minus_beta1_mm: tuple[float, float] = (0.0, 15.0)
    alpha_rad: tuple[float, float] = (-math.pi, math.pi)

    @property
    def box_lower(self) -> np.ndarray:
        return np.array([self.beta3_mm[0], self.beta3_minus_beta2_mm[0], self.beta2_minus_beta1_mm[0]]
                        + [self.alpha_rad[0]] * 3)

    @property
    def box_upper(self) -> np.ndarray:
        return np.array([self.beta3_mm[1], self.beta3_minus_beta2_mm[1], self.beta2_minus_beta1_mm[1]]
                        + [self.alpha_rad[1]] * 3)

    @staticmethod
    def to_box(q: np.ndarray) -> np.ndarray:
        """Joints (..., 6) -> box coordinates (..., 6)."""
        q = np.asarray(q, dtype=float)
        b1, b2, b3 = q[..., 0], q[..., 1], q[..., 2]
        return np.stack([b3, b3 - b2, b2 - b1, q[..., 3], q[..., 4], q[..., 5]], axis=-1)

    @staticmethod
    def from_box(x: np.ndarray) -> np.ndarray:
        """Box coordinates (..., 6) -> joints (..., 6)."""
        x = np.asarray(x, dtype=float)
        b3 = x[..., 0]
        b2 = b3 - x[..., 1]
        b1 = b2 - x[..., 2]
        return np.stack([b1, b2, b3, x[..., 3], x[..., 4], x[..., 5]], axis=-1)

    def sample(self, n: int, rng: np.random.Generator | int | None = None) -> np.ndarray:
        """``n`` joint vectors (n, 6) drawn uniformly in the box coordinates."""
        rng = np.random.default_rng(rng)
        x = rng.uniform(self.box_lower, self.box_upper, size=(n, 6))
        return self.from_box(x)

    def violations(self, q: np.ndarray, tol: float = 1e-9) -> list[tuple[int, str]]:
        """``(row, message)`` for the first violated inequality of every offending row of q (..., 6)."""
        box = self.to_box(np.atleast_2d(q))
        lo, hi = self.box_lower - tol, self.box_upper + tol
        bad = (box < lo) | (box > hi)
        out = []
        for r in np.flatnonzero(bad.any(axis=1)):
            c = int(np.argmax(bad[r]))
            name = _BOX_NAMES[c]
            out.append((int(r), f"{self.box_lower[c]:g} <= {name} <= {self.box_upper[c]:g} violated "
                                f"({name} = {box[r, c]:.6g})"))
        return out


_BOX_NAMES = ("beta3", "beta3 - beta2", "beta2 - beta1", "alpha1", "alpha2", "alpha3")


@dataclass(frozen=True)
class Robot:
    """Immutable description of a three-tube CTR: tubes (1 = innermost), loads, joint domain.

    ``joint_offset`` (6,) is added to every commanded q before the mechanics (calibration extension:
    zero offsets of beta in mm and alpha in rad). ``calibration`` holds the measurement-side
    extensions (registration to a tracker frame, backlash of the alphas); backends never apply it --
    backbones stay in the robot frame -- but measured-data tools and `fk` on ordered rows do.
    """

    tubes: tuple[Tube, Tube, Tube]
    domain: JointDomain = field(default_factory=JointDomain)
    loads: Loads = field(default_factory=Loads)
    joint_offset: tuple[float, ...] = (0.0,) * 6
    calibration: Calibration = field(default_factory=Calibration)
    name: str = "custom"

    # ---- construction -------------------------------------------------------------------------
    @classmethod
    def nominal(cls) -> Robot:
        """The paper's Table I robot (built in)."""
        return cls.load("nominal")

    @classmethod
    def load(cls, spec: str | Path | None = None) -> Robot:
        """Load a built-in robot by name (``nominal``) or a robot YAML file; None -> nominal."""
        if spec is None or str(spec) in BUILTIN_ROBOTS:
            name = "nominal" if spec is None else str(spec)
            with resources.as_file(resources.files("ctrplan.data") / f"{name}.yaml") as p:
                return robot_from_yaml(load_yaml(p))
        return robot_from_yaml(load_yaml(spec))

    def with_changes(self, **changes: Any) -> Robot:
        return replace(self, **changes)

    # ---- derived ------------------------------------------------------------------------------
    @cached_property
    def lengths_mm(self) -> np.ndarray:
        return np.array([t.length_mm for t in self.tubes])

    @cached_property
    def outer_radii_mm(self) -> np.ndarray:
        return np.array([t.outer_radius_mm for t in self.tubes])

    def tube_ends_mm(self, q: np.ndarray) -> np.ndarray:
        """Distal ends ``l_i = beta_i + L_i`` (..., 3) for joints (..., 6) (offsets applied)."""
        q = self.apply_offset(q)
        return q[..., :3] + self.lengths_mm

    def apply_offset(self, q: np.ndarray) -> np.ndarray:
        return np.asarray(q, dtype=float) + np.asarray(self.joint_offset)

    def to_dict(self) -> dict[str, Any]:
        """Plain, JSON/YAML-ready description in file units (the format `Robot.load` reads)."""
        tubes = [
            {
                "inner_diameter_mm": t.inner_diameter_mm,
                "outer_diameter_mm": t.outer_diameter_mm,
                "straight_length_mm": t.straight_length_mm,
                "curved_length_mm": t.curved_length_mm,
                "curvature_1_per_m": t.curvature_per_mm * 1e3,
                "youngs_modulus_gpa": t.youngs_modulus_mpa * 1e-3,
                "shear_modulus_gpa": t.shear_modulus_mpa * 1e-3,
                "density_kg_m3": t.density_kg_m3,
            }
            for t in self.tubes
        ]
        d = asdict(self.domain)
        out = {
            "name": self.name,
            "tubes": tubes,
            "domain": {k: list(v) for k, v in d.items()},
            "loads": {"gravity_m_s2": list(self.loads.gravity_m_s2),
                      "tip_force_n": list(self.loads.tip_force_n)},
            "joint_offset": list(self.joint_offset),
        }
        if not self.calibration.is_identity:  # absent when unused: fingerprints stay stable
            out[CALIBRATION_KEY] = self.calibration.to_dict()
        return out

    @cached_property
    def fingerprint(self) -> str:
        """SHA-256 of every parameter that changes the mechanics or the domain (not the name).

        Numbers enter at 12 significant digits, so a robot survives a round trip through its file.
        """
        d = self.to_dict()
        d.pop("name")
        text = json.dumps(_rounded(d), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()

    # ---- joints ---------------------------------------------------------------------------------
    def check_joints(self, q: np.ndarray, *, allow_outside_domain: bool = False,
                     where: str = "q", row_offset: int = 0) -> np.ndarray:
        """Validate joints (6,) or (B, 6); return them as a float array of the same shape.

        Non-finite values and physically impossible configurations (tube order, a tube base in
        front of the plate, an outer tube reaching past an inner one) raise `InputError`. Leaving the
        snap-free domain raises `DomainError`, or only warns with ``allow_outside_domain``.
        ``where``/``row_offset`` name the source in messages (e.g. a file and its first data row).
        """
        arr = np.asarray(q, dtype=float)
        if arr.shape[-1:] != (6,) or arr.ndim not in (1, 2):
            raise InputError(f"{where}: expected joints of shape (6,) or (N, 6), got {arr.shape}")
        rows = arr.reshape(-1, 6)
        bad = ~np.isfinite(rows)
        if bad.any():
            r, c = np.argwhere(bad)[0]
            raise InputError(f"{where}: row {r + row_offset}: {JOINT_NAMES[c]} is not a finite number")
        qe = self.apply_offset(rows)
        ends = qe[:, :3] + self.lengths_mm
        problems = [
            (qe[:, 0] > qe[:, 1] + 1e-9, "tube order violated: need beta1 <= beta2"),
            (qe[:, 1] > qe[:, 2] + 1e-9, "tube order violated: need beta2 <= beta3"),
            (qe[:, 2] > 1e-9, "tube 3 base in front of the plate: need beta3 <= 0"),
            (ends[:, 0] < ends[:, 1] - 1e-9, "tube 2 reaches past tube 1: need beta1 + L1 >= beta2 + L2"),
            (ends[:, 1] < ends[:, 2] - 1e-9, "tube 3 reaches past tube 2: need beta2 + L2 >= beta3 + L3"),
            (ends[:, 2] <= 0, "tube 3 does not reach the plate: need beta3 + L3 > 0"),
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
        """``n`` configurations (n, 6) uniform in the snap-free box (mm, rad)."""
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
_TUBE_KEYS = {
    "inner_diameter_mm": ("inner_diameter_mm", 1.0),
    "outer_diameter_mm": ("outer_diameter_mm", 1.0),
    "straight_length_mm": ("straight_length_mm", 1.0),
    "curved_length_mm": ("curved_length_mm", 1.0),
    "curvature_1_per_m": ("curvature_per_mm", 1e-3),
    "youngs_modulus_gpa": ("youngs_modulus_mpa", 1e3),
    "shear_modulus_gpa": ("shear_modulus_mpa", 1e3),
    "density_kg_m3": ("density_kg_m3", 1.0),
}
_REQUIRED_TUBE_KEYS = ("inner_diameter_mm", "outer_diameter_mm", "straight_length_mm",
                       "curved_length_mm", "curvature_1_per_m")


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


def robot_from_yaml(doc: YamlDoc) -> Robot:
    """Build a validated `Robot` from a parsed robot file; errors name the key and line."""
    d = doc.data
    _unknown(doc, (), d, {"name", "tubes", "domain", "loads", "joint_offset", CALIBRATION_KEY})
    tubes_raw = d.get("tubes")
    if not isinstance(tubes_raw, list) or len(tubes_raw) != 3:
        raise doc.error(("tubes",), "expected a list of exactly 3 tubes (innermost first)")
    tubes = []
    for i, raw in enumerate(tubes_raw):
        keys = ("tubes", i)
        if not isinstance(raw, dict):
            raise doc.error(keys, "expected a mapping of tube parameters")
        _unknown(doc, keys, raw, _TUBE_KEYS)
        for k in _REQUIRED_TUBE_KEYS:
            if k not in raw:
                raise doc.error(keys, f"missing required key {k!r}")
        kw = {attr: _number(doc, keys + (k,), raw[k]) * scale
              for k, (attr, scale) in _TUBE_KEYS.items() if k in raw}
        tube = Tube(**kw)
        positive = ["outer_diameter_mm", "curved_length_mm", "youngs_modulus_gpa", "shear_modulus_gpa",
                    "density_kg_m3"]
        for k in positive:
            if k in raw and raw[k] <= 0:
                raise doc.error(keys + (k,), f"must be > 0, got {raw[k]!r}")
        for k in ("inner_diameter_mm", "straight_length_mm", "curvature_1_per_m"):
            if raw[k] < 0:
                raise doc.error(keys + (k,), f"must be >= 0, got {raw[k]!r}")
        if tube.inner_diameter_mm >= tube.outer_diameter_mm:
            raise doc.error(keys + ("inner_diameter_mm",),
                            f"inner diameter {tube.inner_diameter_mm} mm must be < outer diameter "
                            f"{tube.outer_diameter_mm} mm")
        tubes.append(tube)
    for i in range(2):
        if tubes[i].outer_diameter_mm > tubes[i + 1].inner_diameter_mm:
            raise doc.error(("tubes", i + 1, "inner_diameter_mm"),
                            f"tube {i + 2} (inner diameter {tubes[i + 1].inner_diameter_mm} mm) cannot "
                            f"hold tube {i + 1} (outer diameter {tubes[i].outer_diameter_mm} mm)")
        if tubes[i].length_mm < tubes[i + 1].length_mm:
            raise doc.error(("tubes", i, "straight_length_mm"),
                            f"tube {i + 1} must be at least as long as tube {i + 2}")

    domain = JointDomain()
    if "domain" in d:
        raw = d["domain"]
        if not isinstance(raw, dict):
            raise doc.error(("domain",), "expected a mapping")
        fields_ = JointDomain.__dataclass_fields__
        _unknown(doc, ("domain",), raw, fields_)
        kw = {}
        for k, v in raw.items():
            lo, hi = _vector(doc, ("domain", k), v, 2)
            if lo > hi:
                raise doc.error(("domain", k), f"lower bound {lo} exceeds upper bound {hi}")
            kw[k] = (lo, hi)
        domain = JointDomain(**kw)

    loads = Loads()
    if "loads" in d:
        raw = d["loads"]
        if not isinstance(raw, dict):
            raise doc.error(("loads",), "expected a mapping")
        _unknown(doc, ("loads",), raw, {"gravity_m_s2", "tip_force_n"})
        loads = Loads(**{k: _vector(doc, ("loads", k), v, 3) for k, v in raw.items()})

    offset = (0.0,) * 6
    if "joint_offset" in d:
        offset = _vector(doc, ("joint_offset",), d["joint_offset"], 6)

    calibration = Calibration.from_doc(doc) if CALIBRATION_KEY in d else Calibration()
    name = d.get("name", doc.path.stem)
    return Robot(tubes=tuple(tubes), domain=domain, loads=loads, joint_offset=offset,
                 calibration=calibration, name=str(name))
