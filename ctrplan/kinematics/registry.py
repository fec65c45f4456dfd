"""The kinematics backends, registered once: everything that lists, builds or budgets a backend by
name (``make_backend``, the ``--backend`` and ``--model`` help texts and checks, `bench` defaults,
the planning work budget) reads this table. Adding a backend: its class, and one `BackendKind` here.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from ctrplan.kinematics.base import Backend
from ctrplan.model.robot import Robot

#: The backend `ctrplan plan` (and `ctrplan.plan`) uses when none is named.
DEFAULT_PLANNING_BACKEND = "pinn"


@dataclass(frozen=True)
class BackendKind:
    """One backend: its ``name``, how to ``build(robot, model)`` it, whether it reads PINN weights
    (``uses_model``: the ``--model`` option), and ``reference_states_per_s``: states per second of
    search on the reference machine (AMD EPYC, one of its 2 cores per search), which a planning time
    limit converts into a work budget (`ctrplan.planning.budget`)."""

    name: str
    build: Callable[[Robot, str | Path | None], Backend]
    uses_model: bool
    reference_states_per_s: float


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
    BackendKind("pinn", _pinn, uses_model=True, reference_states_per_s=16000.0),
    BackendKind("hybrid", _hybrid, uses_model=True, reference_states_per_s=5000.0),
)}
#: Backend names in registration order.
BACKENDS = tuple(BACKEND_KINDS)
#: The backends that read PINN weights (``--model``).
MODEL_BACKENDS = tuple(name for name, kind in BACKEND_KINDS.items() if kind.uses_model)
#: Backend names with the planning default first (``ctrplan plan`` help, ``bench plan`` default).
PLANNING_ORDER = (DEFAULT_PLANNING_BACKEND, *(n for n in BACKENDS if n != DEFAULT_PLANNING_BACKEND))
