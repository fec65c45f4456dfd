"""Causes on the mechanics side: tube parameters, transmission lengths, joint offsets and loads
(`Robot` fields, solved by the Cosserat backend).
"""

from __future__ import annotations

import math
from abc import abstractmethod
from dataclasses import replace
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from ctrplan.model.causes.base import Check, Effect, Param, Plausible, _norm
from ctrplan.model.causes.materials import STANDARD_GRAVITY, material_of, max_load_ratio

if TYPE_CHECKING:
    from ctrplan.model.robot import Robot


class Curvature(Effect):
    """The heat-set curve of each tube: its pre-curvature kappa_i and the length of the curved part (its
    distal end), the straight part taking the rest of the tube -- a tube's length is measured, where its
    curve begins is not. Each alone moves the tip where the other must compensate (a curve set to its
    angle over another length than drawn is both: on a real robot's data neither helped alone, together
    they halved the error left)."""

    name = "curvature"
    between_sessions = True
    key = "tubes[i].curvature_1_per_m, curved_length_mm (straight_length_mm the rest)"
    description = ("pre-curvature kappa_i of each tube (1/m) and the length of its curved part (mm), the "
                   "straight part taking the rest")
    LENGTH_SOURCE = ("a curve is heat-set on a fixture and ends in a transition zone up to 10 mm long "
                     "(where the tube left the fixture, and where the heat reached): file value +- 15 % or "
                     "+- 10 mm, whichever is larger, within the tube")

    def params(self, robot):
        kappas, lengths = [], []
        for i, t in enumerate(robot.tubes):
            k, m = t.curvature_per_mm * 1e3, material_of(t)
            low = max(min((1.0 + m.curvature_change[0]) * k, k - 1.0), 0.0)
            strain_limit = m.max_strain / t.outer_radius_mm * 1e3
            high = min(max((1.0 + m.curvature_change[1]) * k, k + 1.0), strain_limit)
            source = (f"{m.source}; the file's E makes tube {i + 1} {m.name}: file value "
                      f"{100 * m.curvature_change[0]:+.0f} % to {100 * m.curvature_change[1]:+.0f} % "
                      f"(+- 1 1/m for a straight tube), bending strain kappa * OD / 2 at most "
                      f"{100 * m.max_strain:g} %")
            kappas.append(Param(f"kappa{i + 1}_1_per_m", "1/m", max(0.1 * k, 0.5), 0.0, np.inf,
                                Plausible(low, high, source)))
            spread = max(0.15 * t.curved_length_mm, 10.0)
            around = Plausible(max(t.curved_length_mm - spread, 0.0),
                               min(t.curved_length_mm + spread, t.length_mm), self.LENGTH_SOURCE)
            lengths.append(Param(f"curved{i + 1}_mm", "mm", 1.0, 0.0, t.length_mm, around))
        return kappas + lengths

    def values(self, robot):
        return np.array([t.curvature_per_mm * 1e3 for t in robot.tubes]
                        + [t.curved_length_mm for t in robot.tubes])

    def with_values(self, robot, x):
        n = robot.n_tubes
        kappa, curved = np.asarray(x[:n], dtype=float), np.clip(x[n:], 0.0, robot.lengths_mm)
        return robot.with_changes(tubes=tuple(
            replace(t, curvature_per_mm=float(k) * 1e-3, curved_length_mm=float(c),
                    straight_length_mm=t.length_mm - float(c))
            for t, k, c in zip(robot.tubes, kappa, curved, strict=True)))

    def unseen(self, q, direction, robot):
        n = robot.n_tubes
        beta = robot.apply_offset(q)[:, :n]
        begins = beta + np.array([t.straight_length_mm for t in robot.tubes])
        out = {}
        for i, t in enumerate(robot.tubes):
            if t.curved_length_mm <= 0.0:
                out[f"kappa{i + 1}_1_per_m"] = f"tube {i + 1} has no curved part"
                out[f"curved{i + 1}_mm"] = f"tube {i + 1} has no curved part"
            elif begins[:, i].max() <= 1e-9:
                out[f"curved{i + 1}_mm"] = (f"the curve of tube {i + 1} begins at or behind the plate in "
                                            f"every row")
            elif np.ptp(beta[:, i]) <= 1e-9:
                out[f"curved{i + 1}_mm"] = (f"beta{i + 1} never moves: where the curve of tube {i + 1} "
                                            f"begins does not show apart from its curvature")
        return out

    def derived(self, robot, x):
        n = robot.n_tubes
        out = {f"kappa{i + 1}_change_pct": 100.0 * (float(v) / (t.curvature_per_mm * 1e3) - 1.0)
               for i, (t, v) in enumerate(zip(robot.tubes, x[:n], strict=True)) if t.curvature_per_mm > 0}
        out |= {f"tube{i + 1}_bend_deg": float(np.degrees(float(k) * 1e-3 * float(c)))
                for i, (k, c) in enumerate(zip(x[:n], x[n:], strict=True))}
        return out


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
        first, m1 = robot.tubes[0], material_of(robot.tubes[0])
        out = []
        for i in range(1, robot.n_tubes):
            t, m = robot.tubes[i], material_of(robot.tubes[i])
            ratio = first.youngs_modulus_mpa / t.youngs_modulus_mpa     # the file's E_1 / E_i
            low, high = m.youngs_gpa[0] / m1.youngs_gpa[1] * ratio, m.youngs_gpa[1] / m1.youngs_gpa[0] * ratio
            plausible = Plausible(low, high, f"{m.source}: E of tube {i + 1} ({m.name}) over E of tube 1 "
                                             f"({m1.name}) anywhere within their ranges")
            out.append(Param(f"stiffness{i + 1}_rel", "1", 0.1, 0.1, 10.0, plausible))
        return out

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
    between_sessions = True
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


class LoadVector(Effect):
    """A 3-vector of `Robot.loads` fitted whole: the field ``load``, its magnitude checked as
    ``magnitude`` (``unit``) against `max_magnitude`, the range's source from `source`."""

    load: ClassVar[str] = ""
    magnitude: ClassVar[str] = ""
    unit: ClassVar[str] = ""

    @abstractmethod
    def max_magnitude(self, robot: Robot) -> float:
        """The largest plausible magnitude (``unit``) of the load on a robot of this file."""

    @abstractmethod
    def source(self, robot: Robot) -> str:
        """Where the plausible magnitude comes from (cited in reports)."""

    def values(self, robot):
        return np.asarray(getattr(robot.loads, self.load), dtype=float)

    def with_values(self, robot, x):
        return robot.with_changes(loads=replace(robot.loads, **{self.load: tuple(float(v) for v in x)}))

    def checks(self, robot):
        return super().checks(robot) + [Check(self.magnitude, self.unit, _norm,
                                              Plausible(0.0, self.max_magnitude(robot), self.source(robot)))]


class Gravity(LoadVector):
    name = "gravity"
    between_sessions = True
    key = "loads.gravity_m_s2"
    description = "gravity vector (m/s^2) with the file's density and E: only rho*g/E matters"
    load, magnitude, unit = "gravity_m_s2", "gravity_magnitude_m_s2", "m/s^2"

    def source(self, robot: Robot) -> str:
        m = material_of(robot.tubes[0])
        return (f"only rho*g/E matters: |g| <= 9.81 m/s^2 x (the highest density / the lowest E of "
                f"{m.name}) / (the file's density / E) ({m.source})")

    def params(self, robot):
        # hard bounds: huge loads (what a gravity fit reaches for when it tries to explain a frame offset)
        # are slow to solve
        g, source = self.max_magnitude(robot), self.source(robot)
        hard = max(30.0, 2.0 * g)
        return [Param(f"gravity_{a}_m_s2", "m/s^2", 5.0, -hard, hard, Plausible(-g, g, source))
                for a in "xyz"]

    def max_magnitude(self, robot: Robot) -> float:
        """The largest |g| a fit may need (m/s^2): 9.81 x how much larger rho g / E of the tubes'
        material can be than the file's (`materials.max_load_ratio`; the largest over the tubes)."""
        return STANDARD_GRAVITY * max(max_load_ratio(t) for t in robot.tubes)

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


class TipForce(LoadVector):
    name = "tip_force"
    key = "loads.tip_force_n"
    description = "point force at the tip of tube 1 (N), robot frame"
    load, magnitude, unit = "tip_force_n", "tip_force_magnitude_n", "N"
    CABLE_N = 0.02
    #: The heaviest tool a robot carries on its tip: a solid steel cylinder of the robot's largest outer
    #: diameter and this length (mm), density (kg/m^3).
    TOOL_LENGTH_MM, TOOL_DENSITY = 30.0, 7900.0
    SOURCE = ("a sensor cable or tether on the tip of a robot in free space pulls a few mN (20 mN ceiling), "
              "and a tracked tool on the tip weighs at most a solid steel cylinder of the robot's largest "
              "outer diameter and 30 mm length: |F| <= 20 mN + that weight")

    def max_magnitude(self, robot: Robot) -> float:
        """The largest tip force (N) a robot of this file plausibly carries: a cable's pull plus the
        weight of the heaviest tool of its diameter (a soft robot's tool deflects it visibly)."""
        od = max(t.outer_diameter_mm for t in robot.tubes)
        tool_kg = self.TOOL_DENSITY * math.pi / 4 * (od * 1e-3) ** 2 * self.TOOL_LENGTH_MM * 1e-3
        return self.CABLE_N + STANDARD_GRAVITY * tool_kg

    def source(self, robot: Robot) -> str:
        return self.SOURCE

    def params(self, robot):
        f = self.max_magnitude(robot)
        hard = max(0.05, 2.0 * f)
        return [Param(f"tip_force_{a}_n", "N", 2e-3, -hard, hard, Plausible(-f, f, self.SOURCE))
                for a in "xyz"]

    def derived(self, robot, x):
        return {"tip_force_magnitude_mn": 1e3 * float(np.linalg.norm(x))}


class FollowerForce(LoadVector):
    """A force at the tip of tube 1 that turns with it: fixed in its tip frame (x, y across the tube,
    y in the plane its curvature bends it; z along the tangent, distal) -- a tracked sensor's lead or a
    tether running through the lumen and pulling on the tip, a contact that moves with the tip. Unlike
    `TipForce` (fixed in the robot frame, a weight) its direction follows every rotation of the tip."""

    name = "follower_force"
    key = "loads.tip_follower_force_n"
    #: asked for with ``--candidates``: every solve iterates on the tip frame (about 4x the solves of a
    #: fixed force), and on the real data here its held-out gain changes sign with the split
    tried_by_default = False
    description = "point force at the tip of tube 1 (N), tip frame: it turns with the tip (a lead, a tether)"
    load, magnitude, unit = "tip_follower_force_n", "follower_force_magnitude_n", "N"
    MAX_N = 0.1
    SOURCE = ("a tracked sensor's lead or a tether through the lumen, held by the cable management behind "
              "the robot: slack, it pulls a few mN (`tip_force`'s 20 mN cable ceiling); taut, the capstan "
              "friction of the lumen's bends (e^(mu theta), mu 0.1-0.3) and the inner tube's travel add to "
              "it: 0.1 N ceiling -- an engineering estimate, no measurement of lead tension in CTRs known")

    def max_magnitude(self, robot: Robot) -> float:
        return self.MAX_N

    def source(self, robot: Robot) -> str:
        return self.SOURCE

    def params(self, robot):
        return [Param(f"follower_{a}_n", "N", 2e-3, -3.0 * self.MAX_N, 3.0 * self.MAX_N,
                      Plausible(-self.MAX_N, self.MAX_N, self.SOURCE)) for a in "xyz"]

    def draw(self, robot, rng):
        """A lead's pull: 10-40 mN, mostly along the tangent."""
        d = np.array([rng.normal(0, 0.3), rng.normal(0, 0.3), -1.0])
        return rng.uniform(0.01, 0.04) * d / np.linalg.norm(d)

    def derived(self, robot, x):
        return {"follower_force_magnitude_mn": 1e3 * float(np.linalg.norm(x))}
