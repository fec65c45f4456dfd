"""Exact backend: the torsionally compliant Cosserat-rod model (paper eq. 9-13) solved by shooting.

The heavy lifting is in `ctrplan.kinematics._shooting` (numba). This module turns a `Robot` into the
kernel's arrays once, and exposes the `Backend` interface with cold and warm starts.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np

import ctrplan.kinematics._shooting as kernel
from ctrplan.kinematics.backbone import Backbone
from ctrplan.kinematics.base import DEFAULT_POINTS, Backend, Points, arc_fractions, outer_radius_along
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
    N and the weight per length of each tube (N, 3) N/mm. The one place tube parameters are packed."""

    lengths: np.ndarray
    straight: np.ndarray
    kappa: np.ndarray
    EI: np.ndarray
    GJ: np.ndarray
    force: np.ndarray
    weight: np.ndarray

    def arrays(self) -> tuple[np.ndarray, ...]:
        """The fields in kernel-argument order (lengths, straight, kappa, EI, GJ, force, weight)."""
        return (self.lengths, self.straight, self.kappa, self.EI, self.GJ, self.force, self.weight)

    def shooting_arrays(self) -> tuple:
        """`arrays` with ``kappa`` as a tuple, for the shooting kernels: its length, the tube count, is
        then part of the compiled type, so numba compiles one kernel per tube count with constant loop
        bounds (as fast as hand-written three-tube code)."""
        lengths, straight, kappa, *rest = self.arrays()
        return (lengths, straight, tuple(float(k) for k in kappa), *rest)

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
                   weight=mass_per_mm[:, None] * np.asarray(robot.loads.gravity_m_s2, dtype=float)[None, :])


#: Chains `CosseratBackend.forward_path` splits a path into: a constant, so that the backbones (equal
#: to solver tolerance however split) are the same bits on every machine, whatever its thread count;
#: four keep two cores busy with one cold start each.
PATH_CHAINS = 4


class CosseratBackend(Backend):
    """Shooting solver for the Cosserat-rod model of N = 1…4 tubes with gravity and a tip force from
    ``robot.loads``.

    ``forward(q, guess=...)`` warm-starts from initial states (B, 2N + 9) -- e.g.
    ``backbone.initial_state`` of a neighbouring configuration or a PINN prediction; rows that fail
    from the guess are retried cold. Non-converged rows come back with ``converged = False`` and NaN
    shapes; so do solutions that are not physical (a point farther from the plate than its arc length).

    A tube's transmission length d_i (`Tube.transmission_length_mm`) makes it twist over -beta_i + d_i
    behind the plate: the kernels see tube i starting d_i further back (beta_i - d_i, length L_i + d_i,
    straight part + d_i), which changes only theta_i(0) = alpha_i - (beta_i - d_i) u_iz(0) -- everything
    in front of the plate is the same.
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
        self._kernel_args = (*rod.shooting_arrays(), self.loaded, st.step_multi_mm, st.step_single_mm,
                             st.tolerance_per_m * 1e-3, st.max_iterations, st.stability, st.retry_cold)

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
        b, n = qm.shape[0], frac.size
        nt, ns = self.robot.n_tubes, self.robot.n_states
        warm = guess is not None
        x0 = self.unknowns_from_state(guess) if warm else np.zeros((b, self.n_unknowns))
        if x0.shape[0] != b:
            x0 = np.broadcast_to(x0, (b, self.n_unknowns))
        x0 = np.ascontiguousarray(x0, dtype=float)
        states = np.empty((b, n, ns))
        tips = np.empty((b, nt, 3))
        conv = np.zeros(b, dtype=np.bool_)
        iters = np.zeros(b, dtype=np.int64)
        resid = np.zeros(b)
        stab = np.full(b, np.nan)
        xs = np.empty_like(x0)
        initial = np.empty((b, ns))
        args = (frac, *self._kernel_args)
        if b == 1:
            x, c, it, r, sb = kernel.solve_one(qk[0], x0[0], warm, *args, states[0], tips[0], initial[0])
            xs[0], conv[0], iters[0], resid[0], stab[0] = x, c, it, r, sb
        elif chains:
            starts = np.linspace(0, b, min(chains, b) + 1).round().astype(np.int64)
            kernel.solve_chains(qk, x0, warm, starts, *args, states, tips, initial, xs, conv, iters, resid,
                                stab)
        else:
            kernel.solve_many(qk, x0, warm, *args, states, tips, initial, xs, conv, iters, resid, stab)
        ends = qm[:, :nt] + self.rod.lengths
        s_mm = frac[None, :] * ends[:, :1]
        return Backbone(q=q, s_mm=s_mm, state=states, tube_ends_mm=ends, tips_mm=tips,
                        radius_mm=outer_radius_along(self.robot, s_mm, ends), converged=conv,
                        initial_state=initial, iterations=iters, residual=resid, backend=self.name,
                        stability=stab if self.settings.stability else None)
