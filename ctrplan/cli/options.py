"""Option types and option readers shared by several commands: one flag, metavar, range and error
message for each option everywhere."""

from __future__ import annotations

import math
import re
from typing import Annotated, Any

import typer

from ctrplan.base.errors import InputError
from ctrplan.kinematics import BACKEND_KINDS, BACKENDS, MODEL_BACKENDS, Backend, make_backend
from ctrplan.model.robot import Robot

#: Seconds per unit of a duration (`parse_duration`).
DURATION_UNITS = {"s": 1.0, "m": 60.0, "min": 60.0, "h": 3600.0}
_DURATION = re.compile(r"^\s*([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*(s|m|min|h)?\s*$")


def parse_duration(text: str | float | None, bare_unit: str, option: str = "--time-limit") -> float | None:
    """Seconds of a duration such as ``90s``, ``10m``, ``1.5h``; a bare number is in ``bare_unit``
    (the unit the command always used: ``s`` or ``min``). None stays None. `InputError` otherwise."""
    if text is None:
        return None
    match = _DURATION.match(str(text))
    seconds = float(match.group(1)) * DURATION_UNITS[match.group(2) or bare_unit] if match else math.nan
    if not (math.isfinite(seconds) and seconds > 0):
        raise InputError(f"{option}: must be a positive duration (e.g. 90s, 10m, 1.5h; a bare number is "
                         f"in {'seconds' if bare_unit == 's' else 'minutes'}), got {str(text)!r}")
    return seconds


# ---- option types shared by several commands --------------------------------------------------
# A command's help text says what the option means for it, so most shared options are factories of
# Annotated types (one flag, metavar and range everywhere); a command keeps its alias beside it.

RobotOpt = Annotated[str | None, typer.Option(
    "--robot", metavar="R.yaml", show_default=False,
    help="Robot file, or a built-in robot name (nominal); default: nominal.")]
BackendOpt = Annotated[str, typer.Option(
    "--backend", metavar="NAME", help=f"Kinematics backend: {' | '.join(BACKENDS)}.")]
ModelOpt = Annotated[str | None, typer.Option(
    "--model", metavar="NAME|PATH", show_default=False,
    help=f"PINN for the {' and '.join(MODEL_BACKENDS)} backends: a name (looked up in models/, then among "
         "the shipped models pinn_nominal, pinn_nominal_h100, pinn_two_tube) or a .safetensors path; "
         "default: the model trained for the robot in use (pinn_nominal for the nominal robot).")]
#: ``--json`` of the benchmarks.
JsonSummaryOpt = Annotated[bool, typer.Option("--json", help="Print the JSON summary on stdout.")]


def json_option(help: str) -> Any:
    """``--json``: print one JSON document on stdout (what it holds: ``help``)."""
    return Annotated[bool, typer.Option("--json", help=help)]


def seed_option(help: str | None = None, metavar: str | None = None, optional: bool = False) -> Any:
    """``--seed``, an integer >= 0 (``optional``: None when not given)."""
    return Annotated[int | None if optional else int, typer.Option(
        "--seed", min=0, help=help, metavar=metavar, show_default=not optional)]


def time_limit_option(help: str, show_default: bool = True) -> Any:
    """``--time-limit DURATION`` as text, read by `parse_duration` (``90s``, ``10m``, ``1.5h``)."""
    return Annotated[str | None, typer.Option(
        "--time-limit", metavar="DURATION", help=help, show_default=show_default)]


def max_states_option(help: str) -> Any:
    """``--max-states N``: a work budget in states."""
    return Annotated[int | None, typer.Option("--max-states", metavar="N", show_default=False, help=help)]


def check_max_states(value: int | None) -> int | None:
    """``--max-states``: None or an integer >= 1 (`InputError` otherwise)."""
    if value is not None and value < 1:
        raise InputError(f"--max-states: must be an integer >= 1 (states), got {value}")
    return value


def workers_option(help: str, metavar: str | None = None) -> Any:
    """``--workers``: local worker processes, one per core."""
    return Annotated[int, typer.Option("--workers", metavar=metavar, help=help)]


def ray_option(help: str, metavar: str | None = None) -> Any:
    """``--ray ADDRESS``: a Ray cluster to run on."""
    return Annotated[str | None, typer.Option("--ray", metavar=metavar, help=help)]


def heldout_options(heldout_help: str, last_help: str) -> tuple[Any, Any]:
    """``--heldout FRACTION`` and ``--heldout-last FRACTION`` (read them with `heldout_split`)."""
    return (Annotated[float | None, typer.Option("--heldout", metavar="FRACTION", show_default=False,
                                                 help=heldout_help)],
            Annotated[float | None, typer.Option("--heldout-last", metavar="FRACTION", show_default=False,
                                                 help=last_help)])


def as_option(exc: InputError, options: dict[str, str]) -> InputError:
    """A library error about a parameter (``"shots: ..."``) as one about its command-line option
    (``"--shots: ..."``); library code names its parameters, the CLI maps them to its flags."""
    name, sep, rest = str(exc).partition(": ")
    return InputError(f"{options[name]}: {rest}" if sep and name in options else str(exc))


def heldout_split(heldout: float | None, heldout_last: float | None) -> tuple[float, bool]:
    """The held-out fraction and whether it is the last rows, from ``--heldout``/``--heldout-last``
    (one of them, default ``--heldout 0.25``); `InputError` naming the option."""
    if heldout is not None and heldout_last is not None:
        raise InputError("--heldout and --heldout-last: give one of them")
    last = heldout_last is not None
    option = "--heldout-last" if last else "--heldout"
    fraction = heldout_last if last else (0.25 if heldout is None else heldout)
    if not 0.0 < fraction < 1.0:
        raise InputError(f"{option}: must be in (0, 1), got {fraction}")
    return fraction, last


def load_backend(backend: str, robot: Robot, model: str | None) -> Backend:
    """The backend named ``backend`` for ``robot`` with PINN weights ``model``.

    Raises `InputError` naming the option when it cannot be used: never a silent fallback.
    """
    if backend not in BACKEND_KINDS:
        raise InputError(f"--backend: unknown backend {backend!r} (available: {', '.join(BACKEND_KINDS)})")
    if model is not None and not BACKEND_KINDS[backend].uses_model:
        users = [name for name, kind in BACKEND_KINDS.items() if kind.uses_model]
        raise InputError(f"--model: only the {' and '.join(users)} backends use a model, not {backend}")
    try:
        return make_backend(backend, robot, model)
    except InputError as exc:
        raise InputError(f"--backend {backend}: {exc}") from None
