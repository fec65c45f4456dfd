"""The kinematics backend interface shared by the Cosserat solver, the PINN and the hybrid."""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from functools import lru_cache
from typing import ClassVar, NamedTuple

import numpy as np
from numba import njit

from ctrplan.base.errors import InputError
from ctrplan.kinematics.backbone import Backbone
from ctrplan.model.robot import Robot

DEFAULT_POINTS = 64


@lru_cache(maxsize=64)  # a pure function of n with read-only results
def _uniform_fractions(n: int) -> np.ndarray:
    frac = np.linspace(0.0, 1.0, n)
    frac.flags.writeable = False
    return frac


def arc_fractions(points: Points) -> np.ndarray:
    """Output arc lengths as fractions of l1: ``points`` uniform samples in [0, 1], the given
    ascending fractions (N,) (checked on every call), or the values of an `ArcFractions` (checked
    once, when it was made: what a caller passes again and again, a planner its validity stages)."""
    if isinstance(points, ArcFractions):
        return points.values
    if np.isscalar(points):
        n = int(points)
        if n < 2:
            raise InputError(f"points: need at least 2 backbone points, got {n}")
        return _uniform_fractions(n)
    frac = np.asarray(points, dtype=float).ravel()
    if frac.size < 1 or not np.all(np.isfinite(frac)) or frac.min() < 0 or frac.max() > 1 \
            or np.any(np.diff(frac) < 0):
        raise InputError("points: arc fractions must be ascending values in [0, 1]")
    frac = frac.copy()
    frac.flags.writeable = False
    return frac


def kernel_array(a: np.ndarray) -> np.ndarray:
    """``a`` as the kernels take every array: float64, C-contiguous and writable (a copy where it is
    not). numba compiles a kernel once per argument type, and a read-only array (a broadcast view, the
    cached arc fractions) is another type: without this one kernel compiled up to five times a tube
    count, minutes on a first run. Both backends pass their arrays through it."""
    a = np.asarray(a, dtype=float)
    return a if a.flags.writeable and a.flags.c_contiguous else np.array(a, order="C")


class ArcFractions:
    """Backbone output points as arc fractions of l1, checked once (`arc_fractions`): ``values``, a
    read-only ascending (P,) array in [0, 1]. A backend takes one as ``points`` without checking
    it again."""

    __slots__ = ("values",)

    def __init__(self, points: Points) -> None:
        self.values = arc_fractions(points)


#: What a backend takes as ``points``: a count (uniform), fractions of l1 (N,), or `ArcFractions`.
Points = int | np.ndarray | ArcFractions


def outer_radius_along(robot: Robot, s_mm: np.ndarray, ends_mm: np.ndarray) -> np.ndarray:
    """Outer radius (mm) of the outermost tube present at each arc length; s (B, P), ends (B, N)."""
    out = np.empty(s_mm.shape)
    outer_radius(np.ascontiguousarray(s_mm, dtype=float), np.ascontiguousarray(ends_mm, dtype=float),
                 robot.outer_radii_mm, out)
    return out


@njit(cache=True)
def outer_radius(s, ends, radii, out):
    """Compiled `outer_radius_along`: ``out`` (B, P) from s (B, P), ends (B, N), tube radii (N,)."""
    for b in range(s.shape[0]):
        for p in range(s.shape[1]):
            r = radii[0]
            for i in range(1, radii.shape[0]):
                if s[b, p] <= ends[b, i] + 1e-9:
                    r = radii[i]
            out[b, p] = r


class Body(NamedTuple):
    """What a collision check needs of B backbones at P points (robot frame): positions (B, P, 3) mm,
    outer radius (B, P) mm, whether each row may be used (B,) -- converged, and stable where
    stability is computed -- and the states at s = 0 (B, 2N + 9) for warm starts (None from a backend
    that takes none)."""

    positions_mm: np.ndarray
    radius_mm: np.ndarray
    usable: np.ndarray
    initial_state: np.ndarray | None = None


class Backend(ABC):
    """Turns joint configurations into backbones. Batched: q is (n_joints,) or (B, n_joints); output
    has B rows.

    Capabilities are declared here, so callers never ask which kind of backend they hold:

    * ``exact`` -- solves the Cosserat equations itself (no surrogate error to allow for);
    * ``warm_startable`` -- ``forward(..., guess=)`` uses initial states (B, 2N + 9), e.g.
      ``Backbone.initial_state`` of a neighbouring configuration; other backends ignore ``guess``;
    * ``analytic_tip_jacobian`` -- `tip_jacobian` is the backend's own derivative and cheaper than
      forward differences through `forward` (which is what callers use otherwise);
    * ``partial_backbones_cheap`` -- a backbone's cost grows with the stretch of it requested (a
      surrogate evaluated along the arc), so part of one (a distal stretch, the tip) costs less than
      the whole; a shooting solver integrates the whole rod either way;

    and, as properties, ``error_bound`` (a surrogate's calibrated error) and ``model_card`` (the
    weights it evaluates). What a backend *kind* declares -- the ``--model`` option, its work rate,
    its exact companion -- is registered in `ctrplan.kinematics.registry`.

    Implementations keep the robot (immutable model) apart from any per-call workspace.
    """

    name: ClassVar[str] = "backend"
    exact: ClassVar[bool] = False
    warm_startable: ClassVar[bool] = False
    analytic_tip_jacobian: ClassVar[bool] = False
    partial_backbones_cheap: ClassVar[bool] = False

    def __init__(self, robot: Robot):
        self.robot = robot

    @abstractmethod
    def forward(self, q: np.ndarray, points: Points = DEFAULT_POINTS, *,
                guess: np.ndarray | None = None, check: bool = True) -> Backbone:
        """Backbones of configurations q (mm, rad) at ``points`` arc lengths (count or fractions of l1).

        ``guess``: initial states (B, 2N + 9) to start from (used only if ``warm_startable``).
        With ``check``, joints are validated against the robot (`Robot.check_joints`).
        """

    def forward_path(self, q: np.ndarray, points: Points = DEFAULT_POINTS, *,
                     guess: np.ndarray | None = None, check: bool = True) -> Backbone:
        """Backbones of consecutive configurations along a densely sampled path (K, 2N), as `forward`
        (``guess``: initial states of the rows, where a solver cannot do better): a shooting solver
        starts each row from its predecessor's solution. Default: `forward`."""
        return self.forward(q, points, guess=guess, check=check)

    def body(self, q: np.ndarray, points: Points, *, guess: np.ndarray | None = None,
             check: bool = True) -> Body:
        """The `Body` of configurations q (B, 2N) at ``points`` (as `forward`): a planner's validity
        check needs no more. Default: from `forward`; a backend may compute less."""
        bb = self.forward(q, points, guess=guess, check=check)
        return Body(bb.positions_mm, bb.radius_mm, bb.stable,
                    bb.initial_state if self.warm_startable else None)

    def body_query(self, points: Points) -> Callable[[np.ndarray], Body]:
        """`body` at fixed ``points`` for joints (B, 2N) known to lie in the domain (no checks, no warm
        start), prepared once: a planner asks for the same points hundreds of thousands of times, one
        configuration at a time, and a backend may bind everything but q here. Default: `body`."""
        return lambda q: self.body(q, points, check=False)

    def describe(self) -> dict:
        """Settings that shape this backend's backbones (JSON-ready), reported next to its timings."""
        return {}

    def checking_stability(self) -> Backend:
        """This backend with elastic stability computed for every backbone (`Backbone.stability`),
        where it can compute it (the exact backends); a surrogate returns itself -- its paths are
        checked by exact validation."""
        return self

    @property
    def model_card(self) -> dict | None:
        """The model card of the weights this backend evaluates (`ctrplan.kinematics.model_file`: the
        weights file, their SHA-256, the robot, the recipe, ...); None for a backend without weights.
        Outputs name the weights from it, roadmaps key on their hash."""
        return None

    @property
    def error_bound(self) -> dict | None:
        """A surrogate's calibrated backbone position error bound (mm, by arc-length region and
        coverage; see `ctrplan.training.evaluate.error_bound`); None for exact backends and for
        surrogates without one."""
        return None

    def tips(self, q: np.ndarray, *, check: bool = True) -> np.ndarray:
        """Tube tip positions (B, N, 3), mm."""
        return self.forward(q, points=2, check=check).tips_mm

    def tip_and_tangent(self, q: np.ndarray, *, check: bool = True
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """What inverse kinematics needs: the tip of tube 1 (B, 3) mm, its unit tangent (B, 3) and
        whether each row converged (B,), robot frame. Default: from a two-point `forward`."""
        bb = self.forward(q, points=2, check=check)
        return bb.tip_mm, tangent_of(bb.quaternions[:, -1]), bb.converged

    def tip_jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Tip of tube 1 (B, 3) mm, its Jacobian d tip / d q (B, 3, n_joints) in mm per mm|rad, and
        whether each row is valid (B,). Default: forward differences through one batched `forward`,
        with steps taken inside the joint domain."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        return forward_difference_tip_jacobian(self.forward, self.robot, q)[:3]


def tangent_of(quaternions: np.ndarray) -> np.ndarray:
    """Backbone tangent (third column of the rotation) of scalar-first unit quaternions (..., 4)."""
    w, x, y, z = np.moveaxis(np.asarray(quaternions, dtype=float), -1, 0)
    return np.stack([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)], -1)


def forward_difference_tip_jacobian(forward, robot: Robot, q: np.ndarray, eps: float = 1e-3,
                                    guess: np.ndarray | None = None):
    """Forward-difference tip Jacobian of ``forward(q, points=2, guess=)`` at joints q (B, n).

    Steps of ``eps`` (mm or rad) are taken in the domain's box coordinates, towards the interior at
    a bound, and mapped back to joints. Returns ``(tips (B, 3), J (B, 3, n), ok (B,),
    initial_states (B, 2N + 9))``; the last are the base configurations' (warm starts).
    """
    domain = robot.domain
    b, n = q.shape
    y = domain.to_box(q)
    h = np.where(y + eps <= domain.box_upper, eps, -eps)
    Y = np.repeat(y[:, None, :], n + 1, axis=1)
    Y[:, 1:, :] += h[:, None, :] * np.eye(n)[None]
    Q = domain.from_box(Y.reshape(-1, n))
    g = None if guess is None else np.repeat(guess, n + 1, axis=0)
    bb = forward(Q, points=2, guess=g, check=False)
    tips = bb.tip_mm.reshape(b, n + 1, 3)
    ok = bb.converged.reshape(b, n + 1).all(axis=1)
    Jy = (tips[:, 1:, :] - tips[:, :1, :]).transpose(0, 2, 1) / h[:, None, :]  # d tip / d box
    Jq = Jy @ domain.box_from_joints[None]
    return tips[:, 0], Jq, ok, bb.initial_state.reshape(b, n + 1, -1)[:, 0]
