"""Tube materials, for plausible ranges that follow from the robot file: what a tube of the file's
Young's modulus is made of (`material_of`), and the spread of stiffness, density and heat-set
curvature a real tube of that material has -- each with its source.

A robot file states E and density, not a material: the material is the one whose range of E holds the
file's E (the nearest on a log scale otherwise). A nylon tube 1/25 as stiff as nitinol then carries
gravity and a tool at its tip with the deflections a soft tube has, and its curvature may relax by
tens of per cent; a nitinol tube's may not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ctrplan.model.robot import Tube

STANDARD_GRAVITY = 9.81


@dataclass(frozen=True)
class Material:
    """A tube material: Young's modulus (GPa) and density (kg/m^3) ranges of real tubes, the relative
    change of a heat-set curvature that real tubes show against their drawing (low, high), the
    largest bending strain it recovers, and where these numbers come from."""

    name: str
    youngs_gpa: tuple[float, float]
    density_kg_m3: tuple[float, float]
    curvature_change: tuple[float, float]
    max_strain: float
    source: str

    def holds(self, youngs_gpa: float) -> bool:
        return self.youngs_gpa[0] <= youngs_gpa <= self.youngs_gpa[1]


NITINOL = Material(
    "superelastic NiTi", (28.0, 83.0), (6400.0, 6500.0), (-0.5, 0.5), 0.08,
    "superelastic NiTi: E 28-41 GPa (martensite) to 70-83 GPa (austenite), density 6450 kg/m^3, "
    "Johnson Matthey 'Nitinol technical properties'; E of polycrystalline NiTi moves with processing "
    "(Bucsek, Paranjape & Stebner 2016); heat-set curvature is reproduced within tens of per cent "
    "(springback after shape setting; CTR model calibrations fit it for that reason, e.g. Webster, "
    "Romano & Cowan 2009): +- 50 %; it recovers 8 % bending strain")
STEEL = Material(
    "stainless steel", (180.0, 210.0), (7700.0, 8100.0), (-0.3, 0.3), 0.005,
    "stainless steel (AISI 304/316): E 190-200 GPa, density 7900-8000 kg/m^3 (ASM handbook values); a "
    "curvature bent into it plastically springs back by tens of per cent: +- 30 %; it stays elastic to "
    "about 0.5 % strain")
POLYMER = Material(
    "polymer (nylon, PEEK, PTFE, Pebax)", (0.3, 4.5), (900.0, 2200.0), (-0.6, 0.2), 0.05,
    "engineering polymers: E 0.3 GPa (PTFE) to 4 GPa (PEEK), nylon 1.1-3 GPa dry and less when it has "
    "taken up water, density 900-2200 kg/m^3 (manufacturers' data sheets); a curvature heat-set into "
    "a thermoplastic relaxes by creep and stress relaxation by tens of per cent (to 60 %) at body or "
    "room temperature over hours to days, and never grows by more than its springback: -60 % to +20 %; "
    "about 5 % strain is elastic")
MATERIALS = (NITINOL, STEEL, POLYMER)


def material_of(tube: Tube) -> Material:
    """The material a tube of the robot file is made of: the one whose E range holds the tube's E,
    else the nearest on a log scale."""
    e = tube.youngs_modulus_mpa * 1e-3
    for m in MATERIALS:
        if m.holds(e):
            return m

    def distance(m: Material) -> float:
        lo, hi = m.youngs_gpa
        return min(abs(math.log(e / lo)), abs(math.log(e / hi)))

    return min(MATERIALS, key=distance)


def max_load_ratio(tube: Tube) -> float:
    """How much larger rho * g / E can really be than the file's (only rho g / E shapes a robot under
    gravity): the material's highest density over its lowest E, against the file's density and E."""
    m = material_of(tube)
    file_ratio = tube.density_kg_m3 / tube.youngs_modulus_mpa
    return (m.density_kg_m3[1] / (m.youngs_gpa[0] * 1e3)) / file_ratio
