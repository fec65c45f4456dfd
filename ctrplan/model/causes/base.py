"""What a cause is: `Effect` (its parameters with units, plausible ranges and their sources, how it
changes the model) and the registry `EFFECTS` every subclass with a ``name`` enters; `Combined`
(several causes at once), `make_effect` (a cause by name) and the helpers the causes share.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from ctrplan.base.errors import InputError

if TYPE_CHECKING:
    from ctrplan.base.yamlio import KeyPath, YamlDoc
    from ctrplan.model.robot import Robot


#: Every effect by cause name, in definition order (filled by `Effect.__init_subclass__`).
EFFECTS: dict[str, type[Effect]] = {}
#: The order in which the sides act on a prediction.
SIDES = ("joints", "mechanics", "tip", "frame")



@dataclass(frozen=True)
class Plausible:
    """The range a real robot can have for a parameter (file units), and where it comes from."""

    low: float
    high: float
    source: str

    def __contains__(self, value: float) -> bool:
        return self.low - 1e-12 <= value <= self.high + 1e-12


@dataclass(frozen=True)
class Param:
    """One fitted parameter: name, unit, the typical size of a lab deviation (scales the optimisation
    and its finite-difference steps), hard bounds the fit keeps to (where the model stops making
    sense) and the plausible range of a real robot (outside it a fit is reported implausible)."""

    name: str
    unit: str
    scale: float
    lower: float = -np.inf
    upper: float = np.inf
    plausible: Plausible | None = None


#: Half-width of a confidence interval in standard deviations (about 95 %).
CONFIDENCE_Z = 2.0
#: Half-width (standard deviations) of the interval that must miss a plausible range for a value to be
#: implausible: 3, so that a true value at the range's edge (a nearly incompressible tube, nu = 0.5) is
#: refused in 0.1 % of fits; with 2 it was refused in 2.3 %, and a wrong cause named instead.
IMPLAUSIBLE_Z = 3.0


@dataclass(frozen=True)
class Check:
    """A quantity of the parameters ``x`` (file units) and the range a real robot can have for it."""

    name: str
    unit: str
    value: Callable[[np.ndarray], float]
    plausible: Plausible


@dataclass(frozen=True)
class Verdict:
    """A check outside its plausible range: its value and standard deviation, and whether the whole
    confidence interval misses the range (``implausible``) or overlaps it (at the edge)."""

    check: Check
    value: float
    std: float
    implausible: bool

    def reason(self) -> str:
        p = self.check.plausible
        std = "" if not self.std else f" +- {self.std:.2g}"
        where = "is outside" if self.implausible else "is at the edge of (its interval overlaps)"
        return f"{self.value:.4g}{std} {self.check.unit} {where} [{p.low:.4g}, {p.high:.4g}]"


def _component(i: int) -> Callable[[np.ndarray], float]:
    return lambda x: float(x[i])


def _norm(x: np.ndarray) -> float:
    return float(np.linalg.norm(x))


def _shifted(f: Callable[[np.ndarray], float], start: int, k: int) -> Callable[[np.ndarray], float]:
    """``f`` of the ``k`` parameters from ``start`` on (an effect inside `Combined`)."""
    return lambda x: f(x[start:start + k])


def _propagated_std(f: Callable[[np.ndarray], float], x: np.ndarray, cov: np.ndarray | None) -> float:
    """Standard deviation of ``f(x)`` for a covariance ``cov`` of ``x`` (linearised; 0 without cov,
    inf when a parameter it depends on is not resolved)."""
    if cov is None:
        return 0.0
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    grad = np.zeros(len(x))
    for i in range(len(x)):
        if not np.isfinite(sd[i]):
            h = 1e-6 * max(abs(x[i]), 1.0)
        elif sd[i] == 0:
            continue
        else:
            h = 1e-3 * sd[i]
        xp = x.copy()
        xp[i] += h
        grad[i] = (f(xp) - f(x)) / h
    used = grad != 0
    if (~np.isfinite(sd[used])).any():
        return float("inf")
    c = np.where(np.isfinite(cov), cov, 0.0)
    return float(np.sqrt(max(grad @ c @ grad, 0.0)))


class Effect(ABC):
    """A candidate cause. Subclasses set ``name``, ``side``, ``key`` and ``description`` and define
    `params`, `values` and `with_values`; `unseen`, `limits`, `implausible`, `derived` and
    `initial_guess` have defaults."""

    name: ClassVar[str] = ""
    side: ClassVar[str] = "mechanics"
    #: Where the robot file keeps the parameters (documentation and messages).
    key: ClassVar[str] = ""
    description: ClassVar[str] = ""
    #: Whether its values may differ between measurement sessions (a tracker registered anew, a curvature
    #: that relaxed, a robot mounted anew): data of several sessions also try ``<name>@sessions``.
    between_sessions: ClassVar[bool] = False
    #: Whether `diagnose` tries it unless ``--candidates`` names the causes (`DEFAULT_CAUSES`); a cause
    #: that costs many times the others' solves is tried when asked for.
    tried_by_default: ClassVar[bool] = True

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if cls.name:
            EFFECTS[cls.name] = cls

    @abstractmethod
    def params(self, robot: Robot) -> list[Param]:
        """The fitted parameters, in the order of ``x``."""

    @abstractmethod
    def values(self, robot: Robot) -> np.ndarray:
        """The robot's current parameter values (len(params),), file units."""

    @abstractmethod
    def with_values(self, robot: Robot, x: np.ndarray) -> Robot:
        """``robot`` with this effect's parameters set to ``x``."""

    def unseen(self, q: np.ndarray, direction: np.ndarray, robot: Robot) -> dict[str, str]:
        """Parameters the rows (joints q (R, 2N), directions of motion (R, 2N)) cannot show -> why,
        naming the joint the reason is about. They are held at their base value, not fitted."""
        return {}

    def limits(self, q: np.ndarray, robot: Robot) -> dict[str, tuple[float, float]]:
        """Hard bounds that depend on the rows (e.g. keeping every row physical): name -> (lo, hi)."""
        return {}

    def checks(self, robot: Robot) -> list[Check]:
        """The quantities with a plausible range: every parameter that has one, and (subclasses)
        quantities of several parameters, e.g. the magnitude of a vector. ``robot`` is the base model
        (the ranges refer to its file values)."""
        return [Check(p.name, p.unit, _component(i), p.plausible)
                for i, p in enumerate(self.params(robot)) if p.plausible is not None]

    def plausibility(self, robot: Robot, x: np.ndarray, cov: np.ndarray | None = None,
                     z: float = IMPLAUSIBLE_Z) -> dict[str, Verdict]:
        """Every check outside its plausible range at ``x`` (file units): `Verdict.implausible` when
        its confidence interval (``z`` standard deviations from the covariance ``cov`` of ``x``,
        propagated linearly) misses the range, else at the edge (the range lies within the
        interval). Without ``cov`` the interval is the value itself."""
        x = np.asarray(x, dtype=float)
        out = {}
        for c in self.checks(robot):
            v = float(c.value(x))
            if v in c.plausible:
                continue
            std = _propagated_std(c.value, x, cov)
            out[c.name] = Verdict(c, v, std, implausible=not (v - z * std <= c.plausible.high + 1e-12
                                                              and v + z * std >= c.plausible.low - 1e-12))
        return out

    def implausible(self, robot: Robot, x: np.ndarray, cov: np.ndarray | None = None) -> dict[str, str]:
        """Checks whose confidence interval misses the plausible range -> why (value, interval and
        range; the source is `Check.plausible.source`)."""
        return {k: v.reason() for k, v in self.plausibility(robot, x, cov).items() if v.implausible}

    def derived(self, robot: Robot, x: np.ndarray) -> dict[str, float]:
        """Readable quantities derived from the parameters ``x`` of the base ``robot``."""
        return {}

    def draw(self, robot: Robot, rng: np.random.Generator) -> np.ndarray:
        """Lab-sized values for generated data (`ctrplan.calibration.synthetic`): each parameter 1-3
        typical deviations (``scale``) from the robot's value -- either sign, or upwards where the
        value sits on its lower bound -- inside its hard bounds and plausible range."""
        out = []
        for p, v in zip(self.params(robot), self.values(robot), strict=True):
            step = p.scale * rng.uniform(1.0, 3.0)
            x = v + (step if v <= p.lower else step * rng.choice([-1.0, 1.0]))
            lo, hi = (p.lower, p.upper) if p.plausible is None else \
                (max(p.lower, p.plausible.low), min(p.upper, p.plausible.high))
            out.append(float(np.clip(x, lo, hi)))
        return np.array(out)

    def initial_guess(self, robot: Robot, predicted: np.ndarray, measured: np.ndarray) -> np.ndarray | None:
        """A closed-form start from the base model's robot-frame tips and the measured ones (both
        (M, 3) point lists), or None to start from `values`."""
        return None

    @property
    def causes(self) -> tuple[str, ...]:
        return (self.name,)

    def __repr__(self) -> str:
        return f"<Effect {'+'.join(self.causes)}>"

def cause_table(width: int = 100) -> str:
    """The registered causes as a reStructuredText table: cause, side, parameters (``description``)."""
    import textwrap

    name_w, side_w = max(map(len, ("cause", *EFFECTS))) + 2, max(map(len, SIDES)) + 2
    rule = f"{'=' * (name_w - 2)}  {'=' * (side_w - 2)}  {'=' * (width - name_w - side_w)}"
    lines = [rule, f"{'cause':<{name_w}}{'side':<{side_w}}parameters (plausible range: see each `Param`)",
             rule]
    for name, cls in EFFECTS.items():
        text = textwrap.wrap(cls.description, width - name_w - side_w)
        lines.append(f"{name:<{name_w}}{cls.side:<{side_w}}{text[0]}")
        lines += [" " * (name_w + side_w) + more for more in text[1:]]
    return "\n".join([*lines, rule, ""])

# ---- several causes at once -----------------------------------------------------------------------
class Combined(Effect):
    """Several effects at once: their parameters concatenated, applied in order."""

    def __init__(self, effects: Sequence[Effect]):
        self.effects = tuple(effects)

    @property
    def causes(self) -> tuple[str, ...]:
        return tuple(c for e in self.effects for c in e.causes)

    def _parts(self, robot: Robot, x: np.ndarray):
        i = 0
        for e in self.effects:
            k = len(e.params(robot))
            yield e, x[i:i + k]
            i += k

    def params(self, robot):
        return [p for e in self.effects for p in e.params(robot)]

    def values(self, robot):
        return np.concatenate([e.values(robot) for e in self.effects])

    def with_values(self, robot, x):
        for e, xe in self._parts(robot, x):
            robot = e.with_values(robot, xe)
        return robot

    def unseen(self, q, direction, robot):
        return {k: v for e in self.effects for k, v in e.unseen(q, direction, robot).items()}

    def limits(self, q, robot):
        return {k: v for e in self.effects for k, v in e.limits(q, robot).items()}

    def checks(self, robot):
        out, i = [], 0
        for e in self.effects:
            k = len(e.params(robot))
            out += [replace(c, value=_shifted(c.value, i, k)) for c in e.checks(robot)]
            i += k
        return out

    def derived(self, robot, x):
        return {k: v for e, xe in self._parts(robot, x) for k, v in e.derived(robot, xe).items()}


#: A cause whose values differ between measurement sessions is named ``<cause>@sessions``.
PER_SESSION = "@sessions"


class PerSession(Effect):
    """A cause whose values differ between measurement sessions (`ctrplan.model.sessions`): one value
    set per session -- one shared model (their mean, in the robot's fields) plus per-session deviations
    -- each session's rows predicted with its own. Its checks hold for every session's values."""

    def __init__(self, inner: Effect, sessions: Sequence[str]):
        self.inner, self.sessions = inner, tuple(sessions)

    @property
    def causes(self) -> tuple[str, ...]:
        return (self.inner.name + PER_SESSION,)

    def _k(self, robot) -> int:
        return len(self.inner.params(robot))

    def params(self, robot):
        return [replace(p, name=f"{p.name}@{s}") for s in self.sessions for p in self.inner.params(robot)]

    def values(self, robot):
        return np.concatenate([self.inner.values(robot.for_session(s)) for s in self.sessions])

    def with_values(self, robot, x):
        per = np.asarray(x, dtype=float).reshape(len(self.sessions), -1)
        shared = self.inner.with_values(robot, per.mean(axis=0))
        return shared.with_changes(sessions=robot.sessions.with_cause(
            self.inner.name, dict(zip(self.sessions, per, strict=True))))

    def unseen(self, q, direction, robot):
        unseen = self.inner.unseen(q, direction, robot)
        return {f"{k}@{s}": v for s in self.sessions for k, v in unseen.items()}

    def limits(self, q, robot):
        return {f"{k}@{s}": v for s in self.sessions for k, v in self.inner.limits(q, robot).items()}

    def checks(self, robot):
        k = self._k(robot)
        return [replace(c, name=f"{c.name}@{s}", value=_shifted(c.value, i * k, k))
                for i, s in enumerate(self.sessions) for c in self.inner.checks(robot)]

    def initial_guess(self, robot, predicted, measured):
        g = self.inner.initial_guess(robot, predicted, measured)
        return None if g is None else np.tile(g, len(self.sessions))

    def derived(self, robot, x):
        per = np.asarray(x, dtype=float).reshape(len(self.sessions), -1)
        names = [p.name for p in self.inner.params(robot)]
        out = {f"{n}_shared": float(v) for n, v in zip(names, per.mean(axis=0), strict=True)}
        out |= {f"{n}_spread_between_sessions": float(np.ptp(per[:, i])) for i, n in enumerate(names)}
        return out


def make_effect(name: str, sessions: Sequence[str] = ()) -> Effect:
    """The effect of a cause name; ``a+b`` combines several; ``a@sessions`` is cause ``a`` differing
    between the measurement ``sessions`` (`PerSession`)."""
    parts = [p.strip() for p in name.split("+") if p.strip()]
    effects = []
    for p in parts:
        base = p.removesuffix(PER_SESSION)
        if base not in EFFECTS:
            raise InputError(f"unknown cause {base!r} (known: {', '.join(EFFECTS)})")
        if base != p and len(sessions) < 2:
            raise InputError(f"cause {p!r}: values that differ between sessions need data of two or more "
                             f"measurement sessions (a 'session' column)")
        effects.append(EFFECTS[base]() if base == p else PerSession(EFFECTS[base](), sessions))
    return effects[0] if len(effects) == 1 else Combined(effects)


# ---- helpers --------------------------------------------------------------------------------------
def numbers(doc: YamlDoc, keys: KeyPath, value: Any, n: int) -> tuple[float, ...]:
    """A list of ``n`` finite numbers from a robot file, or `InputError` naming the key."""
    ok = isinstance(value, list) and len(value) == n and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)
    if not ok:
        raise doc.error(keys, f"expected a list of {n} finite numbers, got {value!r}")
    return tuple(float(v) for v in value)


def _never_reverses(direction: np.ndarray, n: int) -> list[tuple[int, str]]:
    """Tubes (0-based) whose rotation never reverses its direction of motion, with the reason."""
    out = []
    for i in range(n):
        d = direction[:, n + i]
        if not ((d > 0).any() and (d < 0).any()):
            out.append((i, f"alpha{i + 1} never reverses its direction of motion"))
    return out


def offset_limits(q: np.ndarray, robot: Robot, share: float = 0.5,
                  margin_mm: float = 1e-6) -> dict[str, tuple[float, float]]:
    """Bounds on the beta zero offsets (mm, absolute) under which every row of ``q`` stays physically
    valid (tube order, bases behind the plate, inner tubes reaching furthest; `Robot.check_joints`).
    Each tube may use ``share`` of the slack of a pairwise constraint: 0.5 guarantees validity for
    any offsets in the box, 1.0 is each tube's own limit (check the fitted robot)."""
    n = q.shape[-1] // 2
    base = np.asarray(robot.joint_offset, dtype=float)[:n]
    b = np.asarray(q, dtype=float)[:, :n] + base
    ends = b + robot.lengths_mm
    lo, hi = np.full(n, -np.inf), np.full(n, np.inf)
    for i in range(n - 1):
        gap = max(float((b[:, i + 1] - b[:, i]).min()) - margin_mm, 0.0)      # beta_i <= beta_i+1
        hi[i], lo[i + 1] = min(hi[i], base[i] + share * gap), max(lo[i + 1], base[i + 1] - share * gap)
        gap = max(float((ends[:, i] - ends[:, i + 1]).min()) - margin_mm, 0.0)  # l_i >= l_i+1
        lo[i], hi[i + 1] = max(lo[i], base[i] - share * gap), min(hi[i + 1], base[i + 1] + share * gap)
    hi[n - 1] = min(hi[n - 1], base[n - 1] + max(float(-b[:, n - 1].max()) - margin_mm, 0.0))
    lo[n - 1] = max(lo[n - 1], base[n - 1] - max(float(ends[:, n - 1].min()) - 1e-3, 0.0))
    return {f"beta{i + 1}_offset_mm": (float(lo[i]), float(hi[i])) for i in range(n)}


def kabsch(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares rigid transform (R, t) with ``target ~ R source + t`` for point lists (M, 3)."""
    src = np.asarray(source, dtype=float).reshape(-1, 3)
    dst = np.asarray(target, dtype=float).reshape(-1, 3)
    ok = np.isfinite(src).all(1) & np.isfinite(dst).all(1)
    src, dst = src[ok], dst[ok]
    cs, cd = src.mean(0), dst.mean(0)
    H = (src - cs).T @ (dst - cd)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, cd - R @ cs
