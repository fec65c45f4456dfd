"""The kinematics backends, registered once: everything that lists, builds, budgets or pairs a backend
(``make_backend``, the ``--backend`` and ``--model`` help texts and checks, `bench` defaults, the
planning work budget, the exact companion that validates a plan) reads this table. Adding a backend:
its class, and one `BackendKind` here.

A kind declares what callers would otherwise ask its name for: whether it reads PINN weights
(``uses_model``), how many states a second of search buys with it (``reference_states_per_s``), and
which exact backend validates and repairs what it plans (``exact_companion``; None: it is exact and
validates itself). What an instance can do (warm starts, an analytic tip Jacobian, a calibrated error
bound, a model card) it declares on the `Backend` interface.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from ctrplan.base.errors import InputError
from ctrplan.kinematics.base import Backend
from ctrplan.model.robot import Robot

#: The backend `ctrplan plan` (and `ctrplan.plan`) uses when none is named.
DEFAULT_PLANNING_BACKEND = "pinn"
#: The exact model: the backend that validates what a backend plans when its kind names no companion
#: (an exact backend of another robot, a backend not registered), and that design studies plan with.
EXACT_MODEL = "cosserat"


@dataclass(frozen=True)
class BackendKind:
    """One backend: its ``name``; how to ``build(robot, model)`` it; whether it reads PINN weights
    (``uses_model``: the ``--model`` option); ``reference_states_per_s``: states per second of
    search on the reference machine (AMD EPYC, one of its 2 cores per search), which a planning time
    limit converts into a work budget (`ctrplan.planning.budget`); and ``exact_companion``: the kind
    whose backend validates and repairs its plans (None: the kind is exact and does so itself)."""

    name: str
    build: Callable[[Robot, str | Path | None], Backend]
    uses_model: bool
    reference_states_per_s: float
    exact_companion: str | None = None

    @property
    def exact(self) -> bool:
        """Whether its backbones are the exact model's (it is its own exact companion)."""
        return self.exact_companion is None


def _cosserat(robot: Robot, model: str | Path | None) -> Backend:
    from ctrplan.kinematics.cosserat import CosseratBackend

    return CosseratBackend(robot)


def _pinn(robot: Robot, model: str | Path | None) -> Backend:
    from ctrplan.kinematics.pinn import PinnBackend

    return PinnBackend.load(model, robot)


def _hybrid(robot: Robot, model: str | Path | None) -> Backend:
    from ctrplan.kinematics.hybrid import HybridBackend

    return HybridBackend(robot, model)


#: Rates of the idle reference machine (2-core AMD EPYC): `ctrplan bench plan scenes/skullbase.yaml`
#: (docs/benchmarks.md), searches that use their whole 10 s (RRT, RRT*: 15,000-17,000 with the PINN,
#: 4,900-5,300 with the exact backends). `scripts/reference_rates.py` measures them again (docs/benchmarks.md
#: "Reference rates": on the same box shared with other sessions, load 7-8, 8,200 states per CPU-second
#: with the PINN and 2,600-2,800 with the exact backends, the same 3:1 ratio).
BACKEND_KINDS: dict[str, BackendKind] = {kind.name: kind for kind in (
    BackendKind("cosserat", _cosserat, uses_model=False, reference_states_per_s=5000.0),
    BackendKind("pinn", _pinn, uses_model=True, reference_states_per_s=16000.0, exact_companion=EXACT_MODEL),
    BackendKind("hybrid", _hybrid, uses_model=True, reference_states_per_s=5000.0),
)}
#: Backend names in registration order (help texts; checks read `BACKEND_KINDS` itself).
BACKENDS = tuple(BACKEND_KINDS)
#: The backends that read PINN weights (``--model``).
MODEL_BACKENDS = tuple(name for name, kind in BACKEND_KINDS.items() if kind.uses_model)
#: Backend names with the planning default first (``ctrplan plan`` help, ``bench plan`` default).
PLANNING_ORDER = (DEFAULT_PLANNING_BACKEND, *(n for n in BACKENDS if n != DEFAULT_PLANNING_BACKEND))


def backend_kind(name: str) -> BackendKind:
    """The registered kind ``name``; `InputError` naming the registered ones otherwise."""
    kind = BACKEND_KINDS.get(name)
    if kind is None:
        raise InputError(f"backend: unknown backend {name!r} (available: {', '.join(BACKEND_KINDS)})")
    return kind


def reference_states_per_s(name: str) -> float:
    """States per second of search with the backend ``name`` on the reference machine (a backend not
    registered: the exact model's rate)."""
    return BACKEND_KINDS.get(name, BACKEND_KINDS[EXACT_MODEL]).reference_states_per_s


def exact_companion(backend: Backend, robot: Robot) -> Backend:
    """The exact backend that validates and repairs what ``backend`` plans for ``robot``: ``backend``
    itself when it is exact and models ``robot``, else its kind's ``exact_companion`` built for
    ``robot`` (`EXACT_MODEL` for an exact backend of another robot or a backend not registered)."""
    if backend.exact and backend.robot is robot:
        return backend
    kind = BACKEND_KINDS.get(backend.name)
    name = kind.exact_companion if kind is not None and not backend.exact else None
    return backend_kind(name or EXACT_MODEL).build(robot, None)
