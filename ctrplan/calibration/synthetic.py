"""Generated measured data with a hidden cause, for tests, examples and studies.

`generate` draws a sequence of configurations (a random walk, as a lab acquires them), a hidden
cause with a magnitude a lab would see, solves the true model and adds tracker noise. The true
parameters come back with the data so a diagnosis can be scored.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from ctrplan.calibration.data import MeasuredData
from ctrplan.kinematics import CosseratBackend
from ctrplan.measurement import Calibration, motion_direction
from ctrplan.robot import Loads, Robot

HIDDEN_CAUSES = ("curvature", "stiffness_ratio", "joint_offset", "gravity", "tip_force", "registration",
                 "backlash", "none")


@dataclass
class Synthetic:
    """Generated data and its hidden truth."""

    data: MeasuredData
    cause: str
    truth: dict = field(default_factory=dict)
    robot: Robot | None = None
    calibration: Calibration = field(default_factory=Calibration)
    noise_mm: np.ndarray | None = None       # (n, 3, 3) the noise that was added
    clean_tips_mm: np.ndarray | None = None  # (n, 3, 3) noiseless measurements


def _signed(rng, lo, hi, size=None):
    return rng.uniform(lo, hi, size) * rng.choice([-1.0, 1.0], size)


def draw_truth(cause: str, robot: Robot, rng: np.random.Generator) -> tuple[Robot, Calibration, dict]:
    """A hidden cause with a lab-sized magnitude: returns the true robot, calibration and a dict of
    the true parameters."""
    calib = Calibration()
    if cause == "none":
        return robot, calib, {}
    if cause == "curvature":
        f = 1.0 + _signed(rng, 0.05, 0.15, 3)
        tubes = tuple(replace(t, curvature_per_mm=t.curvature_per_mm * fi)
                      for t, fi in zip(robot.tubes, f, strict=True))
        return robot.with_changes(tubes=tubes), calib, {
            f"kappa{i + 1}_1_per_m": t.curvature_per_mm * 1e3 for i, t in enumerate(tubes)}
    if cause == "stiffness_ratio":
        t0 = robot.tubes[0]
        nu0 = t0.youngs_modulus_mpa / (2 * t0.shear_modulus_mpa) - 1
        # torsional stiffness off by 15-30 % (superelastic nitinol's G is poorly known)
        g_scale = 1.0 + _signed(rng, 0.15, 0.30)
        nu = (1 + nu0) / g_scale - 1
        tubes = tuple(replace(t, shear_modulus_mpa=t.youngs_modulus_mpa / (2 * (1 + nu)))
                      for t in robot.tubes)
        return robot.with_changes(tubes=tubes), calib, {"poisson_ratio": nu}
    if cause == "joint_offset":
        off = np.concatenate([_signed(rng, 1.0, 3.0, 3), np.radians(_signed(rng, 1.0, 5.0, 3))])
        return robot.with_changes(joint_offset=tuple(off)), calib, {
            **{f"beta{i + 1}_offset_mm": off[i] for i in range(3)},
            **{f"alpha{i + 1}_offset_rad": off[3 + i] for i in range(3)}}
    if cause == "gravity":
        # robot horizontal (insertion axis z level, within 5 deg), rho*g/E within +-20 %
        phi = rng.uniform(0, 2 * math.pi)
        tilt = math.radians(rng.uniform(-5, 5))
        g = 9.81 * rng.uniform(0.8, 1.2) * np.array([math.cos(phi) * math.cos(tilt),
                                                      math.sin(phi) * math.cos(tilt), math.sin(tilt)])
        return robot.with_changes(loads=Loads(gravity_m_s2=tuple(g))), calib, {
            f"gravity_{a}_m_s2": v for a, v in zip("xyz", g, strict=True)}
    if cause == "tip_force":
        d = rng.normal(size=3)
        d[2] *= 0.3
        f = d / np.linalg.norm(d) * rng.uniform(1e-3, 3e-3)
        return robot.with_changes(loads=Loads(tip_force_n=tuple(f))), calib, {
            f"tip_force_{a}_n": v for a, v in zip("xyz", f, strict=True)}
    if cause == "registration":
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        rot = axis * math.radians(rng.uniform(1.0, 3.0))
        tdir = rng.normal(size=3)
        trans = tdir / np.linalg.norm(tdir) * rng.uniform(0.5, 1.5)
        calib = Calibration(rotation_vector_rad=tuple(rot), translation_mm=tuple(trans))
        return robot, calib, {**{f"rotation_{a}_rad": v for a, v in zip("xyz", rot, strict=True)},
                              **{f"translation_{a}_mm": v for a, v in zip("xyz", trans, strict=True)}}
    if cause == "backlash":
        b = np.radians(rng.uniform(1.5, 4.0, 3))
        calib = Calibration(backlash_rad=tuple(b))
        return robot, calib, {f"backlash{i + 1}_rad": b[i] for i in range(3)}
    raise ValueError(f"unknown hidden cause {cause!r}")


def random_walk(n: int, robot: Robot, rng: np.random.Generator, margin_mm: float = 3.0) -> np.ndarray:
    """``n`` configurations (n, 6) acquired as a sequence: a random walk in the snap-free box (each
    joint moves with probability 0.6 per row, reflecting at the bounds). The beta bounds are pulled in
    by ``margin_mm`` so that the commanded joints stay physical under joint offsets of a few mm."""
    dom = robot.domain
    lo, hi = dom.box_lower.copy(), dom.box_upper.copy()
    lo[:3] += np.array([0.0, 2 * margin_mm, 2 * margin_mm])
    hi[:2] -= np.array([margin_mm, 2 * margin_mm])   # beta3 <= 0 and beta3 - beta2 <= L2 - L3
    span = hi - lo
    step = np.array([1.5, 8.0, 3.0, 0.5, 0.5, 0.5])
    x = rng.uniform(lo, hi)
    out = np.empty((n, 6))
    for r in range(n):
        out[r] = x
        move = rng.random(6) < 0.6
        x = x + move * rng.normal(0.0, step)
        y = np.mod(x - lo, 2 * span)  # reflect into [lo, hi]
        x = lo + np.where(y > span, 2 * span - y, y)
    return dom.from_box(out)


def generate(n: int = 200, cause: str = "none", seed: int | None = 0, noise_mm: float = 0.1,
             robot: Robot | None = None, tubes: tuple[int, ...] = (0, 1, 2)) -> Synthetic:
    """Measured data of ``n`` rows with a hidden ``cause`` (see `HIDDEN_CAUSES`; ``a+b`` hides two) and
    Gaussian noise of ``noise_mm`` per coordinate."""
    rng = np.random.default_rng(seed)
    robot = robot or Robot.nominal()
    true_robot, calib, truth = robot, Calibration(), {}
    for part in cause.split("+"):
        true_robot, c, t = draw_truth(part, true_robot, rng)
        calib = _merge(calib, c)
        truth.update(t)
    q_true = random_walk(n, robot, rng)
    # the commanded joints are what the file holds; joint offsets act on top of the command
    q_cmd = q_true - np.asarray(true_robot.joint_offset) + np.asarray(robot.joint_offset)
    qe = calib.effective_joints(q_cmd, motion_direction(q_cmd))
    bb = CosseratBackend(true_robot).forward(qe, points=2, check=False)
    if not bb.converged.all():  # pragma: no cover - the walk stays in the snap-free domain
        raise RuntimeError("synthetic truth did not converge")
    clean = calib.to_measurement_frame(bb.tips_mm)
    noise = rng.normal(0.0, noise_mm, clean.shape)
    tips = clean + noise
    mask = np.full((3,), False)
    mask[list(tubes)] = True
    tips[:, ~mask] = np.nan
    data = MeasuredData(q=q_cmd, tips_mm=tips, tubes=tuple(tubes), lines=np.arange(2, n + 2),
                        source=f"<synthetic {cause}>", format="csv",
                        outside_domain=np.zeros(n, dtype=bool))
    return Synthetic(data=data, cause=cause, truth=truth, robot=true_robot, calibration=calib,
                     noise_mm=noise, clean_tips_mm=clean)


def _merge(a: Calibration, b: Calibration) -> Calibration:
    if b.has_registration:
        a = replace(a, rotation_vector_rad=b.rotation_vector_rad, translation_mm=b.translation_mm)
    if any(b.backlash_rad):
        a = replace(a, backlash_rad=b.backlash_rad)
    return a
