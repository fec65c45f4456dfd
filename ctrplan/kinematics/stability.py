"""Elastic stability over a robot's whole joint domain: where does it snap?

A CTR snaps when the equilibrium it is in stops being stable as a rotation changes: the solution
branch folds and the robot jumps to another branch. `check_domain` looks for that the way it happens
on the hardware: it sweeps one tube rotation at a time across its interval from random configurations
of the domain, following the equilibrium by continuation (each step warm-started from the previous
solution), and flags a configuration when

* the equilibrium the continuation reached is unstable (`Backbone.stability` <= 0: a focal point of
  the Jacobi equation along the arc length, Ha, Park & Dupont 2015);
* the continuation jumped: the tip moved far more than the step warrants (the branch folded);
* the configuration is multi-valued: the cold solve (from zero torsion) reaches a different
  equilibrium than the continuation.

A domain is ``snap_free`` when nothing is flagged; when something is, the report carries advice
(`ctrplan.kinematics.snap_advice`): the relative rotation or translation the snaps lie beyond and the
robot-file limit that keeps the safe part. Two-tube check (docs/design.md §1.4): fully overlapping
curved tubes of length L are snap-free for every rotation iff ``L sqrt((1 + nu) kappa1 kappa2) < pi/2``.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from ctrplan.base.dataio import atomic_write
from ctrplan.base.memory import F8, backbone_bytes
from ctrplan.kinematics.cosserat import CosseratBackend, SolverSettings
from ctrplan.kinematics.snap_advice import SnapAdvice, snap_advice
from ctrplan.model.robot import Robot

#: A step of the sweep moving the tip more than this many times its typical motion is a jump.
JUMP_FACTOR = 8.0
#: ... and by at least this much (mm), so smooth fast motion near the tip is not a jump.
JUMP_MIN_MM = 1.0
#: Continuation and cold solutions further apart than this (mm, tip) are two equilibria.
MULTIVALUED_MM = 0.5


@dataclass
class Sweep:
    """One rotation sweep: the swept tube (1-based), joints (K, 2N), stability measure (K,),
    tip (K, 3) mm, and per step the flags ``unstable``, ``jump`` and ``multivalued`` (K,)."""

    tube: int
    q: np.ndarray
    stability: np.ndarray
    tip_mm: np.ndarray
    unstable: np.ndarray
    jump: np.ndarray
    multivalued: np.ndarray

    @property
    def flagged(self) -> np.ndarray:
        return self.unstable | self.jump | self.multivalued


@dataclass
class StabilityReport:
    """The verdict on a robot's domain (JSON: `to_json`)."""

    robot: str
    snap_free: bool
    checked: int
    unstable_fraction: float
    example_q: list[float] | None
    example_reason: str | None
    counts: dict[str, int]
    sweeps: list[Sweep] = field(repr=False)
    advice: SnapAdvice | None = None

    def to_json(self) -> dict:
        return {"robot": self.robot, "snap_free": self.snap_free, "checked": self.checked,
                "unstable_fraction": self.unstable_fraction, "example_q": self.example_q,
                "example_reason": self.example_reason, "counts": self.counts,
                "sweeps": len(self.sweeps), "advice": None if self.advice is None else self.advice.to_json()}


def sweep_rotation(backend: CosseratBackend, q0: np.ndarray, tube: int, steps: int) -> Sweep:
    """Follow the equilibrium while the rotation coordinate of ``tube`` (0-based; alpha, or alpha
    relative to another tube's, `JointDomain.relative_to`) crosses its domain interval from ``q0``
    (2N,), the other box coordinates held, in ``steps`` configurations, each warm-started from the
    previous solution."""
    robot = backend.robot
    n = robot.n_tubes
    lo, hi = robot.domain.bounds[n + tube]
    q = np.repeat(q0[None], steps, axis=0)
    if robot.domain.relative_to:  # hold the other box coordinates: a relative one turns its tube along
        box = robot.domain.to_box(q)
        box[:, n + tube] = np.linspace(lo, hi, steps)
        q = robot.domain.from_box(box)
    else:
        q[:, n + tube] = np.linspace(lo, hi, steps)
    stab = np.full(steps, np.nan)
    tips = np.full((steps, 3), np.nan)
    guess = None
    converged = np.zeros(steps, dtype=bool)
    for k in range(steps):
        bb = backend.forward(q[k], points=2, guess=guess, check=False)
        converged[k] = bool(bb.converged[0])
        if converged[k]:
            stab[k], tips[k], guess = bb.stability[0], bb.tip_mm[0], bb.initial_state
        else:
            guess = None
    cold = backend.forward(q, points=2, check=False)
    moves = np.linalg.norm(np.diff(tips, axis=0), axis=1)
    typical = np.nanmedian(moves) if np.isfinite(moves).any() else 0.0
    jump = np.zeros(steps, dtype=bool)
    jump[1:] = moves > max(JUMP_FACTOR * typical, JUMP_MIN_MM)
    apart = np.linalg.norm(cold.tip_mm - tips, axis=1)
    multivalued = cold.converged & converged & (apart > MULTIVALUED_MM)
    unstable = ~converged | ~(stab > 0.0)
    return Sweep(tube + 1, q, stab, tips, unstable, jump, multivalued)


def sweep_bytes(n_tubes: int, steps: int) -> int:
    """Memory (bytes) a `Sweep` of ``steps`` configurations holds, with its start and the cold
    backbones solved alongside it (`sweep_rotation`)."""
    return steps * (F8 * (2 * n_tubes + 4) + 3 + 2 * backbone_bytes(n_tubes, 2)) + F8 * 2 * n_tubes


def check_domain(robot: Robot, n: int = 64, steps: int = 73, seed: int = 0,
                 progress=None, stop_at_first: bool = False) -> StabilityReport:
    """Sweep every rotatable tube from ``n`` random configurations of the domain (``steps``
    configurations a sweep) and collect the verdict. ``progress()`` is called after each sweep.
    ``stop_at_first``: stop after the first sweep that flags a configuration (the verdict is then
    known; the counts cover the sweeps done)."""
    backend = CosseratBackend(robot, SolverSettings(stability=True))
    nt = robot.n_tubes
    rotatable = [i for i in range(nt) if not robot.domain.fixed[nt + i]]
    rng = np.random.default_rng(seed)
    starts = robot.sample_joints(n, rng)
    sweeps = []
    for k, q0 in enumerate(starts):
        if not rotatable:
            break
        sweeps.append(sweep_rotation(backend, q0, rotatable[k % len(rotatable)], steps))
        if progress is not None:
            progress()
        if stop_at_first and sweeps[-1].flagged.any():
            break
    if not rotatable:  # nothing turns: check the sampled configurations themselves
        bb = backend.forward(starts, points=2, check=False)
        unstable = ~bb.stable
        sweeps = [Sweep(0, starts, bb.stability, bb.tip_mm, unstable, np.zeros(n, bool), np.zeros(n, bool))]
    checked = sum(len(s.q) for s in sweeps)
    flagged = sum(int(s.flagged.sum()) for s in sweeps)
    counts = {"unstable": sum(int(s.unstable.sum()) for s in sweeps),
              "jump": sum(int(s.jump.sum()) for s in sweeps),
              "multivalued": sum(int(s.multivalued.sum()) for s in sweeps)}
    example, reason = None, None
    for s in sweeps:
        for name in ("unstable", "jump", "multivalued"):
            hits = np.flatnonzero(getattr(s, name))
            if hits.size and example is None:
                example, reason = s.q[hits[0]].tolist(), name
    advice = snap_advice(robot, np.concatenate([s.q for s in sweeps]),
                         np.concatenate([s.flagged for s in sweeps]), steps) if flagged else None
    return StabilityReport(robot.name, flagged == 0, checked, flagged / max(checked, 1), example, reason,
                           counts, sweeps, advice)


def critical_length_mm(robot: Robot) -> float:
    """Two-tube closed form (Dupont et al. 2010): the overlap length (mm) above which two curved tubes
    snap, ``pi / (2 sqrt((1 + nu) kappa1 kappa2))``, nu = E/(2G) - 1 of tube 1."""
    t1, t2 = robot.tubes[:2]
    nu = t1.youngs_modulus_mpa / (2 * t1.shear_modulus_mpa) - 1
    return float(np.pi / (2 * np.sqrt((1 + nu) * t1.curvature_per_mm * t2.curvature_per_mm)))


# ---- certificates ---------------------------------------------------------------------------------
# A robot whose whole domain `check_domain` found snap-free is certified by a small JSON file named
# after its fingerprint: shipped ones in the package (`ctrplan/data/stability/`), the user's own in
# the cache `ctrplan stability` writes to. A certified robot is planned without per-state stability
# checks; any other robot's planning and validation reject unstable states.


def user_certificate_dir() -> Path:
    """Where `ctrplan stability` keeps certificates: ``$XDG_CACHE_HOME/ctrplan/stability`` (default
    ``~/.cache/ctrplan/stability``)."""
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "ctrplan" / "stability"


def _read_certificate(path: Path, robot: Robot) -> bool:
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError):
        return False
    return doc.get("fingerprint") == robot.fingerprint and doc.get("snap_free") is True


def is_certified(robot: Robot) -> bool:
    """Whether a snap-free verdict for exactly this robot (its fingerprint) was shipped or made here."""
    name = f"{robot.fingerprint}.json"
    shipped = resources.files("ctrplan.data") / "stability" / name
    if shipped.is_file():
        with resources.as_file(shipped) as path:
            return _read_certificate(path, robot)
    return _read_certificate(user_certificate_dir() / name, robot)


def write_certificate(report: StabilityReport, robot: Robot, settings: dict,
                      folder: Path | None = None) -> Path:
    """Record a snap-free verdict for ``robot`` (fingerprint, sweep settings, counts); returns the
    file. Only snap-free verdicts certify anything."""
    folder = folder or user_certificate_dir()
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{robot.fingerprint}.json"
    doc = {"fingerprint": robot.fingerprint, "robot": robot.name, **report.to_json(), "settings": settings}
    with atomic_write(path) as fh:
        fh.write(json.dumps(doc, indent=2) + "\n")
    return path


def certify(robot: Robot, n: int = 64, steps: int = 73, seed: int = 0, progress=None,
            stop_at_first: bool = False) -> tuple[StabilityReport, Path | None]:
    """`check_domain` with these settings (those of `ctrplan stability` by default), and the
    certificate it earns (the file, or None when the domain is not snap-free)."""
    report = check_domain(robot, n=n, steps=steps, seed=seed, progress=progress, stop_at_first=stop_at_first)
    if not report.snap_free:
        return report, None
    return report, write_certificate(report, robot, {"n": n, "steps": steps, "seed": seed})
