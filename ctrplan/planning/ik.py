"""Damped-least-squares inverse kinematics on the tip position, for a batch of seeds at once.

The solver works in the planner's scaled box coordinates (`BoxSpace`), so every iterate stays inside
the snap-free domain (clipped to the box) and the damping is isotropic in the planning metric. The tip
Jacobian comes from a function ``q (B, 2N) -> (tips (B, 3), J (B, 3, 2N), ok (B,))`` in the robot frame
(mm per mm/rad): a backend that declares ``analytic_tip_jacobian`` plugs its `Backend.tip_jacobian`
in directly (see `backend_tip_jacobian`); `fd_tip_jacobian` makes one from any backend with forward
differences through a single batched backend call.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numba import njit

from ctrplan.kinematics.backbone import Backbone
from ctrplan.kinematics.base import Backend, tangent_of
from ctrplan.planning.space import BoxSpace

TipJacobian = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]
ForwardFn = Callable[..., Backbone]
TipFn = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]


class FDTipJacobian:
    """Forward-difference tip Jacobian of ``forward(q, points=2[, guess=])`` (a backend's ``forward``
    or `ConfigurationChecker.forward`): 7 configurations per seed in one batched call. Steps are taken
    in box coordinates, towards the interior at the domain boundary. Pass ``guess`` (B, 15) initial
    states to warm-start a shooting backend; `last_initial_state` holds those of the last call.
    Without warm starts, ``tips(q) -> (tip (B, 3), tangent (B, 3), ok (B,))`` (e.g.
    `Backend.tip_and_tangent`) is used instead of ``forward`` where given. With ``tangent_weight_mm``
    the task is the tip pose: ``(tip, tangent_weight_mm * tangent)`` (B, 6) and its Jacobian."""

    def __init__(self, forward: ForwardFn, space: BoxSpace, eps: float = 1e-3, warm: bool = False,
                 tips: TipFn | None = None, tangent_weight_mm: float | None = None):
        self.forward = forward
        self.space = space
        self.eps = float(eps)
        self.warm = bool(warm)
        self.tips = tips
        self.tangent_weight_mm = tangent_weight_mm
        self._Minv = np.linalg.pinv(space.joint_from_coords)  # J_q = J_y M^+ (M has full column rank)
        self.last_initial_state: np.ndarray | None = None

    def __call__(self, q: np.ndarray, guess: np.ndarray | None = None):
        q = np.atleast_2d(q)
        b = q.shape[0]
        sp, eps = self.space, self.eps
        y = sp.to_coords(q)
        d = sp.dimension
        h = np.where(y + eps <= sp.upper, eps, -eps)  # (B, D)
        Y = np.repeat(y[:, None, :], d + 1, axis=1)
        Y[:, 1:, :] += h[:, None, :] * np.eye(d)[None]
        Q = sp.to_joints(Y.reshape(-1, d))
        if self.tips is not None and not self.warm:
            tip, tangent, converged = self.tips(Q)
        else:
            bb = self.forward(Q, points=2, guess=np.repeat(guess, d + 1, axis=0)) \
                if self.warm and guess is not None else self.forward(Q, points=2)
            tip, converged = bb.tip_mm, bb.converged
            tangent = tangent_of(bb.quaternions[:, -1]) if self.tangent_weight_mm else None
            self.last_initial_state = bb.initial_state.reshape(b, d + 1, -1)[:, 0]
        if self.tangent_weight_mm:
            tip = np.concatenate([tip, self.tangent_weight_mm * tangent], axis=1)
        tips = tip.reshape(b, d + 1, tip.shape[1])
        ok = converged.reshape(b, d + 1).all(axis=1)
        Jy = (tips[:, 1:, :] - tips[:, :1, :]).transpose(0, 2, 1) / h[:, None, :]  # (B, 3, D)
        return tips[:, 0], Jy @ self._Minv[None], ok


def fd_tip_jacobian(forward: ForwardFn, space: BoxSpace, eps: float = 1e-3,
                    warm: bool = False, tips: TipFn | None = None,
                    tangent_weight_mm: float | None = None) -> FDTipJacobian:
    """Finite-difference tip (or tip pose) Jacobian through one batched call of ``forward`` (or
    ``tips``) per evaluation."""
    return FDTipJacobian(forward, space, eps, warm, tips, tangent_weight_mm)


def backend_tip_jacobian(backend: Backend, space: BoxSpace, forward: ForwardFn | None = None,
                         tips: TipFn | None = None, tangent_weight_mm: float | None = None) -> TipJacobian:
    """A tip Jacobian for ``backend``: its own `Backend.tip_jacobian` where it declares
    ``analytic_tip_jacobian``; otherwise forward differences, one batched call each: warm-started
    through ``forward`` (default: the backend's) where the backend is ``warm_startable``, else through
    ``tips`` (default: the backend's `Backend.tip_and_tangent`, for a surrogate one network row per
    configuration). With ``tangent_weight_mm``, the tip pose (see `FDTipJacobian`)."""
    if backend.analytic_tip_jacobian and not tangent_weight_mm:
        return backend.tip_jacobian
    if forward is None:
        def forward(q, points=2, guess=None):
            return backend.forward(q, points=points, guess=guess, check=False)
    if tips is None:
        def tips(q):
            return backend.tip_and_tangent(q, check=False)
    return fd_tip_jacobian(forward, space, warm=backend.warm_startable, tips=tips,
                           tangent_weight_mm=tangent_weight_mm)


@dataclass(frozen=True)
class IKResult:
    """Per seed: joints (B, 2N), tip (B, 3) -- or tip pose (B, 6) -- robot frame, error to its target
    (B,), success (B,)."""

    q: np.ndarray
    tip: np.ndarray
    error_mm: np.ndarray
    success: np.ndarray
    iterations: int


def solve_ik(jacobian: TipJacobian, space: BoxSpace, seeds: np.ndarray, targets: np.ndarray, *,
             tol_mm: float = 0.05, max_iterations: int = 40, damping: float = 1.0,
             max_step: float = 15.0, rotation_weight: float = 1.0,
             enough: Callable[[IKResult], bool] | None = None, check_after: int = 8) -> IKResult:
    """Move every seed (B, 2N) so its tip reaches its target (B, 3) (robot frame, mm) -- or, with a
    tip-pose Jacobian (``FDTipJacobian(tangent_weight_mm=w)``), its pose target (B, 6) ``(tip, w *
    tangent)``; the error (and ``tol_mm``) is then the norm of both together.

    Levenberg-style: a step is kept only if it lowers that seed's error; otherwise the damping of
    the seed grows. Each iteration is one call of ``jacobian`` for all seeds still running.
    ``rotation_weight`` > 1 makes tube rotations costlier than translations in the least-squares
    step (insertion-first solutions, which stay closer to a seed's shape). ``enough``: asked once,
    after ``check_after`` iterations, with the result so far; True ends the solve there (e.g. a goal
    sampler that found what it needs among the seeds done), False lets it run on unchanged.
    """
    seeds = np.atleast_2d(np.asarray(seeds, dtype=float))
    targets = np.asarray(targets, dtype=float)
    k = targets.shape[-1]  # 3: tip position; 6: tip pose
    # the compiled iteration takes C-ordered, writable arrays (as `compile_ik` compiles it)
    targets = np.array(np.broadcast_to(targets, (seeds.shape[0], k)), dtype=float, order="C")
    b = seeds.shape[0]
    M = np.array(space.joint_from_coords, dtype=float, order="C")
    wcol = np.where(space.is_rotation, 1.0 / float(rotation_weight), 1.0)  # dy = wcol * dz
    lower, upper = np.array(space.lower, dtype=float), np.array(space.upper, dtype=float)
    y = np.array(space.clip(space.to_coords(seeds)), dtype=float, order="C")
    lam = np.full(b, float(damping))
    best_err = np.full(b, np.inf)
    best_y = y.copy()
    best_tip = np.full((b, k), np.nan)
    best_J = np.zeros((b, k, space.dimension))
    active = np.ones(b, dtype=bool)
    warm = bool(getattr(jacobian, "warm", False))
    best_init = None
    it = 0

    def result(iterations: int) -> IKResult:
        return IKResult(space.to_joints(best_y), best_tip, best_err, best_err <= tol_mm, iterations)

    for it in range(1, max_iterations + 1):  # noqa: B007 - reported
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        if enough is not None and it == check_after + 1 and enough(result(check_after)):
            it = check_after
            break
        if warm and best_init is not None:
            g = best_init[idx]
            g = np.where(np.isfinite(g), g, 0.0) if np.isfinite(g).all() else None
            tips, Jq, ok = jacobian(space.to_joints(y[idx]), guess=g)
        else:
            tips, Jq, ok = jacobian(space.to_joints(y[idx]))
        tips, Jq = np.array(tips, dtype=float, order="C"), np.array(Jq, dtype=float, order="C")
        ok = np.array(ok, dtype=np.bool_)
        better = _lm_iteration(idx, tips, Jq, ok, targets, M, wcol, lower, upper, float(max_step),
                               float(tol_mm), y, lam, best_err, best_y, best_tip, best_J, active)
        init = getattr(jacobian, "last_initial_state", None) if warm else None
        if init is not None:
            if best_init is None:
                best_init = np.full((b, init.shape[1]), np.nan)
            best_init[idx[better]] = init[better]
        if not active.any():
            break
    return result(it)


def compile_ik(space: BoxSpace) -> None:
    """Compile (or load from numba's cache) `solve_ik`'s kernel before a planning clock starts: one
    iteration of one seed in ``space``, through the same argument preparation as every call (numba
    compiles one version per array layout)."""
    def still(q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # a robot that does not move
        return np.zeros((len(q), 3)), np.zeros((len(q), 3, q.shape[1])), np.ones(len(q), dtype=bool)

    solve_ik(still, space, space.to_joints(0.5 * (space.lower + space.upper)), np.ones(3), max_iterations=1)


@njit(cache=True)
def _lm_iteration(idx, tips, Jq, ok, targets, M, wcol, lower, upper, max_step, tol_mm,
                  y, lam, best_err, best_y, best_tip, best_J, active):
    """One Levenberg iteration of `solve_ik` for the running seeds ``idx`` (R,), in place: each
    seed's new tip (R, k), joint Jacobian (R, k, 2N) and ``ok`` (R,) at its iterate ``y[idx]``; an
    improvement is kept (``best_*``, damping halved), otherwise the damping grows 4x; seeds within
    ``tol_mm``, with damping above 1e6, without any finite error or with a non-finite Jacobian stop
    (``active``); the others take a `_damped_step` from their best iterate, clipped to the box
    [lower, upper] (D,). Returns which seeds improved (R,)."""
    better = np.zeros(idx.size, dtype=np.bool_)
    for r in range(idx.size):
        i = idx[r]
        e2 = 0.0
        for c in range(targets.shape[1]):
            d = targets[i, c] - tips[r, c]
            e2 += d * d
        err = math.sqrt(e2) if ok[r] else math.inf
        if err < best_err[i]:  # NaN compares False: not an improvement
            better[r] = True
            best_err[i] = err
            best_y[i] = y[i]
            best_tip[i] = tips[r]
            best_J[i] = Jq[r] @ M
            lam[i] *= 0.5
        else:
            lam[i] *= 4.0
        if (best_err[i] <= tol_mm or lam[i] > 1e6 or not math.isfinite(best_err[i])
                or not np.all(np.isfinite(best_J[i]))):
            active[i] = False
            continue
        dy = _damped_step(best_y[i], best_J[i], targets[i] - best_tip[i], lam[i], wcol, lower, upper,
                          max_step)
        y[i] = np.minimum(np.maximum(best_y[i] + dy, lower), upper)
    return better


@njit(cache=True)
def _damped_step(y, J, e, lam, wcol, lower, upper, max_step):
    """Damped least-squares step (D,) from box coordinates y (D,) with Jacobian J (k, D) towards the
    error e (k,), damping lam; coordinates weighted by ``wcol`` (D,) (dy = wcol * dz); coordinates
    at a bound [lower, upper] the step pushes outwards are dropped (an active set, up to 3 passes);
    at most ``max_step`` long (mm, planning metric)."""
    k, d = J.shape
    JwT = np.ascontiguousarray((J * wcol.reshape((1, d))).T)  # (D, k)
    dy = np.zeros(d)
    for _ in range(3):
        A = JwT.T @ JwT + lam * lam * np.eye(k)
        dy = JwT @ np.linalg.solve(A, e)
        blocked = False
        for j in range(d):
            if (y[j] <= lower[j] + 1e-9 and dy[j] < 0) or (y[j] >= upper[j] - 1e-9 and dy[j] > 0):
                JwT[j] = 0.0
                blocked = True
        if not blocked:
            break
    dy = dy * wcol
    n = math.sqrt(np.sum(dy * dy))
    return dy * min(1.0, max_step / max(n, 1e-12))
