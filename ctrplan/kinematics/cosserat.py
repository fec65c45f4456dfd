"""Exact backend: the torsionally compliant Cosserat-rod model (paper eq. 9-13) solved by shooting.

The heavy lifting is in `ctrplan.kinematics._shooting` (numba). This module turns a `Robot` into the
kernel's arrays once, and exposes the `Backend` interface with cold and warm starts.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np

import ctrplan.kinematics._shooting as kernel
from ctrplan.kinematics.backbone import Backbone, quaternion_to_matrix
from ctrplan.kinematics.base import (
    DEFAULT_POINTS,
    Backend,
    Points,
    arc_fractions,
    kernel_array,
    outer_radius_along,
)
from ctrplan.model.robot import Robot

G_TO_N_PER_MM = 1e-9  # rho [kg/m^3] * A [mm^2] * g [m/s^2] * 1e-9 = N/mm


@dataclass(frozen=True)
class SolverSettings:
    """Numerical settings. Steps in mm; tolerance on the normalised boundary residual in 1/m.

    ``exploit_free_space``: without loads, shoot for the N - 1 unknowns left by m_b = 0 and
    sum GJ_i u_iz = 0 (fast); if False, always shoot for all N + 2 (the general loaded path).
    ``stability``: also compute the elastic-stability measure of every solution
    (`Backbone.stability`; about one more Jacobian's worth of integration per configuration).
    ``retry_cold``: a row whose warm start fails is solved again from cold (False: it is reported not
    converged -- for fitters, whose warm starts follow the solution).
    """

    step_multi_mm: float = 2.0
    step_single_mm: float = 4.0
    tolerance_per_m: float = 1e-10
    max_iterations: int = 40
    exploit_free_space: bool = True
    stability: bool = False
    retry_cold: bool = True


@dataclass(frozen=True)
class RodArrays:
    """A `Robot` as the arrays of the numba kernels (`_shooting`) and the PINN's physics, per tube
    (N,): lengths and straight lengths (mm), curvatures (1/mm), EI and GJ (N*mm^2); the tip force (3,)
    N in the robot frame, the weight per length of each tube (N, 3) N/mm and the follower force (3,)
    N in the tip frame of tube 1. The one place tube parameters are packed."""

    lengths: np.ndarray
    straight: np.ndarray
    kappa: np.ndarray
    EI: np.ndarray
    GJ: np.ndarray
    force: np.ndarray
    weight: np.ndarray
    follower: np.ndarray

    def arrays(self) -> tuple[np.ndarray, ...]:
        """The fields in kernel-argument order (lengths, straight, kappa, EI, GJ, force, weight,
        follower), each as the kernels take it (`kernel_array`)."""
        return tuple(kernel_array(a) for a in (self.lengths, self.straight, self.kappa, self.EI, self.GJ,
                                               self.force, self.weight, self.follower))

    def shooting_arrays(self) -> tuple:
        """(lengths, straight, kappa, EI, GJ, force, weight) for the shooting kernels, ``kappa`` as a
        tuple: its length, the tube count, is then part of the compiled type, so numba compiles one
        kernel per tube count with constant loop bounds (as fast as hand-written three-tube code). The
        follower force is not among them: `CosseratBackend` turns it into each row's ``force``."""
        lengths, straight, kappa, EI, GJ, force, weight, _ = self.arrays()
        return lengths, straight, tuple(float(k) for k in kappa), EI, GJ, force, weight

    def tip_forces(self, tip_rotations: np.ndarray) -> np.ndarray:
        """The tip force (B, 3) N in the robot frame of configurations whose tube-1 tip frames are
        ``tip_rotations`` (B, 3, 3) (robot <- tip): the fixed force plus the follower force turned
        with the tip."""
        return self.force + np.einsum("bij,j->bi", tip_rotations, self.follower)

    @classmethod
    def of(cls, robot: Robot) -> RodArrays:
        tubes = robot.tubes
        mass_per_mm = np.array([t.density_kg_m3 * t.area_mm2 for t in tubes]) * G_TO_N_PER_MM
        return cls(lengths=np.array([t.length_mm for t in tubes]),
                   straight=np.array([t.straight_length_mm for t in tubes]),
                   kappa=np.array([t.curvature_per_mm for t in tubes]),
                   EI=np.array([t.bending_stiffness_nmm2 for t in tubes]),
                   GJ=np.array([t.torsional_stiffness_nmm2 for t in tubes]),
                   force=np.asarray(robot.loads.tip_force_n, dtype=float),
                   weight=mass_per_mm[:, None] * np.asarray(robot.loads.gravity_m_s2, dtype=float)[None, :],
                   follower=np.asarray(robot.loads.tip_follower_force_n, dtype=float))


#: Chains `CosseratBackend.forward_path` splits a path into: a constant, so that the backbones (equal
#: to solver tolerance however split) are the same bits on every machine, whatever its thread count;
#: four keep two cores busy with one cold start each.
PATH_CHAINS = 4


#: Iterations of a follower force at most, the turn of its robot-frame direction (rad, each row) below
#: which it has converged (1e-8 rad of a 0.1 N force moves a tip by ~1e-8 mm), and the depth of the
#: Anderson mixing: each iteration solves the rows again from the last solutions with the force turned
#: to the last tip frames; rows that have not converged are reported so.
FOLLOWER_ITERATIONS, FOLLOWER_TOLERANCE_RAD, ANDERSON_DEPTH = 30, 1e-8, 2


def _anderson(history: list[tuple[np.ndarray, np.ndarray]]) -> np.ndarray:
    """The next iterate (B, 3) of the fixed point x = g(x) by Anderson mixing over ``history`` (the
    last iterates x and g(x), each (B, 3), oldest first): g of the newest minus the combination of
    differences of g that best cancels the newest residual g(x) - x, per row."""
    x, g = (np.stack(v, -1) for v in zip(*history, strict=True))     # (B, 3, k)
    f = g - x
    if f.shape[-1] == 1:
        return g[..., -1]
    df, dg = np.diff(f, axis=-1), np.diff(g, axis=-1)                # (B, 3, k - 1)
    a = np.einsum("bim,bin->bmn", df, df) + 1e-30 * np.eye(df.shape[-1])
    gamma = np.linalg.solve(a, np.einsum("bim,bi->bm", df, f[..., -1])[..., None])[..., 0]
    return g[..., -1] - np.einsum("bim,bm->bi", dg, gamma)


class CosseratBackend(Backend):
    """Shooting solver for the Cosserat-rod model of N = 1…4 tubes with gravity, a tip force and a
    follower tip force from ``robot.loads``.

    ``forward(q, guess=...)`` warm-starts from initial states (B, 2N + 9) -- e.g.
    ``backbone.initial_state`` of a neighbouring configuration or a PINN prediction; rows that fail
    from the guess are retried cold. Non-converged rows come back with ``converged = False`` and NaN
    shapes; so do solutions that are not physical (a point farther from the plate than its arc length).

    A tube's transmission length d_i (`Tube.transmission_length_mm`) makes it twist over -beta_i + d_i
    behind the plate: the kernels see tube i starting d_i further back (beta_i - d_i, length L_i + d_i,
    straight part + d_i), which changes only theta_i(0) = alpha_i - (beta_i - d_i) u_iz(0) -- everything
    in front of the plate is the same.

    A follower force (fixed in the tip frame of tube 1) is solved by fixed-point iteration on that
    frame: the kernels see a force fixed in the robot frame, per row, turned to the tip frame of the
    previous solution until it no longer turns (`FOLLOWER_ITERATIONS`, `FOLLOWER_TOLERANCE_RAD`). The
    stability measure is that of the force frozen at its solved direction.
    """

    name = "cosserat"
    exact = True
    warm_startable = True

    def __init__(self, robot: Robot | None = None, settings: SolverSettings | None = None):
        super().__init__(robot or Robot.nominal())
        self.settings = settings or SolverSettings()
        self.rod = RodArrays.of(self.robot)
        self.loaded = not (self.robot.loads.is_free and self.settings.exploit_free_space)
        self._transmission = np.array([t.transmission_length_mm for t in self.robot.tubes])
        d = self._transmission
        rod = replace(self.rod, lengths=self.rod.lengths + d, straight=self.rod.straight + d)
        st = self.settings
        lengths, straight, kappa, EI, GJ, _, weight = rod.shooting_arrays()
        self._kernel_head = (lengths, straight, kappa, EI, GJ)     # then the force, per row or not
        self._kernel_tail = (weight, bool(self.loaded), float(st.step_multi_mm), float(st.step_single_mm),
                             float(st.tolerance_per_m * 1e-3), int(st.max_iterations), bool(st.stability),
                             bool(st.retry_cold))   # one type each, whatever the caller passed

    @property
    def n_unknowns(self) -> int:
        """Shooting unknowns: N - 1 in free space, N + 2 under loads."""
        return self.robot.n_tubes + 2 if self.loaded else self.robot.n_tubes - 1

    def describe(self) -> dict:
        return asdict(self.settings)

    def checking_stability(self) -> CosseratBackend:
        if self.settings.stability:
            return self
        return CosseratBackend(self.robot, replace(self.settings, stability=True))

    def unknowns_from_state(self, state0: np.ndarray) -> np.ndarray:
        """Shooting unknowns (B, N - 1 | N + 2) from initial states (B, 2N + 9)."""
        state0 = np.atleast_2d(state0)
        n = self.robot.n_tubes
        if self.loaded:
            return np.concatenate([state0[:, 0:2] / self.rod.EI[0], state0[:, 2:2 + n]], axis=1)
        return state0[:, 3:2 + n].copy()

    def forward(self, q: np.ndarray, points: Points = DEFAULT_POINTS, *,
                guess: np.ndarray | None = None, check: bool = True) -> Backbone:
        return self._solve(q, points, guess, check, chains=0)

    def forward_path(self, q: np.ndarray, points: Points = DEFAULT_POINTS, *,
                     guess: np.ndarray | None = None, check: bool = True) -> Backbone:
        """Each row after the first of `PATH_CHAINS` chains (run in parallel) starts from the
        solutions of the rows before it: along a densely sampled path about 40 % of the shooting
        iterations of cold starts, on every core."""
        return self._solve(q, points, guess, check, chains=PATH_CHAINS)

    def _solve(self, q: np.ndarray, points: Points, guess: np.ndarray | None, check: bool,
               chains: int) -> Backbone:
        """`forward` (``chains`` 0: every row on its own) or `forward_path` (rows in ``chains``
        consecutive runs)."""
        q = np.atleast_2d(self.robot.check_joints(q) if check else np.asarray(q, dtype=float))
        qm = self.robot.apply_offset(q)
        qk = qm.copy()
        qk[:, :self.robot.n_tubes] -= self._transmission   # the kernels' tube starts (see the class)
        frac = arc_fractions(points)
        b = qm.shape[0]
        x0 = self.unknowns_from_state(guess) if guess is not None else np.zeros((b, self.n_unknowns))
        x0 = np.broadcast_to(x0, (b, self.n_unknowns))      # `_run` makes it a kernel array
        if self.robot.loads.has_follower:
            solved = self._follower_solve(qk, frac, x0, guess is not None, chains)
        else:
            force = np.broadcast_to(self.rod.force, (b, 3))
            solved = self._run(qk, frac, x0, guess is not None, force, chains)[:-1]
        states, tips, conv, iters, resid, stab, initial = solved
        ends = qm[:, :self.robot.n_tubes] + self.rod.lengths
        s_mm = frac[None, :] * ends[:, :1]
        return Backbone(q=q, s_mm=s_mm, state=states, tube_ends_mm=ends, tips_mm=tips,
                        radius_mm=outer_radius_along(self.robot, s_mm, ends), converged=conv,
                        initial_state=initial, iterations=iters, residual=resid, backend=self.name,
                        stability=stab if self.settings.stability else None)

    def _run(self, qk: np.ndarray, frac: np.ndarray, x0: np.ndarray, warm: bool, force: np.ndarray,
             chains: int) -> tuple:
        """One pass of the kernels over kernel joints ``qk`` (B, 2N) with each row's robot-frame tip
        force ``force`` (B, 3): states (B, P, 2N + 9), tips, converged, iterations, residual,
        stability, initial states and shooting unknowns."""
        b, n = qk.shape[0], frac.size
        nt, ns = self.robot.n_tubes, self.robot.n_states
        states = np.empty((b, n, ns))
        tips = np.empty((b, nt, 3))
        conv = np.zeros(b, dtype=np.bool_)
        iters = np.zeros(b, dtype=np.int64)
        resid = np.zeros(b)
        stab = np.full(b, np.nan)
        qk, frac, x0, force = (kernel_array(a) for a in (qk, frac, x0, force))
        xs = np.empty_like(x0)
        initial = np.empty((b, ns))
        head, tail = (frac, *self._kernel_head), self._kernel_tail
        if b == 1:
            x, c, it, r, sb = kernel.solve_one(qk[0], x0[0], warm, *head, force[0], *tail, states[0], tips[0],
                                               initial[0])
            xs[0], conv[0], iters[0], resid[0], stab[0] = x, c, it, r, sb
        else:      # a batch is chains of one row each
            starts = np.linspace(0, b, min(chains, b) + 1).round() if chains else np.arange(b + 1)
            starts = starts.astype(np.int64)
            kernel.solve_chains(qk, x0, warm, starts, *head, force, *tail, states, tips, initial, xs, conv,
                                iters, resid, stab)
        return states, tips, conv, iters, resid, stab, initial, xs

    def _follower_solve(self, qk: np.ndarray, frac: np.ndarray, x0: np.ndarray, warm: bool, chains: int
                        ) -> tuple:
        """`_run` under a follower force: the fixed point F = g(F) of the robot-frame tip force, g the
        fixed force plus the follower force turned to the tip frame solved under F, by Anderson-mixed
        iteration (see the class); each pass solves the rows not yet settled (a path's chains whole), the
        tip added to the requested points. Rows whose force has not stopped turning are not converged
        (NaN)."""
        with_tip = frac if frac[-1] == 1.0 else np.append(frac, 1.0)
        b = qk.shape[0]
        force = np.broadcast_to(self.rod.force, (b, 3)).copy()
        x0, settled, out = x0.copy(), np.zeros(b, dtype=bool), None
        history: list[tuple[np.ndarray, np.ndarray]] = []      # (force, g(force)) of the iterations
        for _ in range(FOLLOWER_ITERATIONS):
            rows = np.arange(b) if chains else np.flatnonzero(~settled)
            *solved, xs = self._run(qk[rows], with_tip, x0[rows], warm, force[rows], chains)
            out = out or [np.empty((b, *a.shape[1:]), dtype=a.dtype) for a in solved]
            for whole, part in zip(out, solved, strict=True):
                whole[rows] = part
            states, conv = out[0], out[2]
            g = self.rod.tip_forces(quaternion_to_matrix(states[:, -1, -4:]))
            settled = conv & (self._follower_turn(force, g) <= FOLLOWER_TOLERANCE_RAD)
            x0[rows], warm = np.where(conv[rows, None], xs, x0[rows]), True
            if settled.all() or not conv[rows].any():
                break
            history = [*history[-ANDERSON_DEPTH:], (force, g)]
            step = _anderson(history)
            moving = conv & ~settled & np.isfinite(step).all(axis=1)    # settled rows keep their force
            force = np.where(moving[:, None], step, force)
        states, tips, _, iters, resid, stab, initial = out
        states = states[:, :frac.size]
        states[~settled], tips[~settled] = np.nan, np.nan
        return states, tips, settled, iters, resid, stab, initial

    @staticmethod
    def _follower_turn(before: np.ndarray, after: np.ndarray) -> np.ndarray:
        """The angle (B,) rad between two robot-frame forces (B, 3) of each row (inf where either
        vanishes or is not finite, or they point apart)."""
        cos = np.einsum("bi,bi->b", before, after)
        with np.errstate(invalid="ignore", divide="ignore"):
            sin = np.linalg.norm(np.cross(before, after), axis=1) / (np.linalg.norm(before, axis=1)
                                                                    * np.linalg.norm(after, axis=1))
        return np.where(np.isfinite(sin) & (cos > 0), np.arcsin(np.clip(sin, 0.0, 1.0)), np.inf)
