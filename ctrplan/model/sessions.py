"""`SessionValues`: the parameters of a robot that differ between measurement sessions -- a
curvature that relaxed between two days, a tracker registered anew -- as one shared model (the
robot's own fields) plus, per session, the values of the causes that differ in it.

A measured-data CSV names each row's session in its optional ``session`` column (any name or number);
`ctrplan diagnose` fits a cause that differs between sessions as per-session values
(`ctrplan.model.causes.base.PerSession`), and the extended robot keeps them under ``sessions``::

    sessions:
      monday:   {registration: {rotation_x_rad: 0.02, ..., translation_z_mm: 0.4}}
      thursday: {registration: {rotation_x_rad: -0.01, ...}}

`Robot.for_session` is the robot of one session (the shared robot for a session it does not name);
`fk` and `shape` predict each row of a file with a ``session`` column with its session's robot. The
shared values are the mean over the sessions (what `plan` uses).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ctrplan.model.causes.base import EFFECTS

if TYPE_CHECKING:
    from ctrplan.base.yamlio import KeyPath, YamlDoc
    from ctrplan.model.robot import Robot

SESSIONS_KEY = "sessions"
#: The optional column of a measured-data or configurations CSV naming each row's measurement session.
SESSION_COLUMN = "session"


@dataclass(frozen=True)
class SessionValues:
    """Per session name, the (cause, values) pairs that differ from the shared robot (file units, in the
    order of the cause's parameters)."""

    by_session: tuple[tuple[str, tuple[tuple[str, tuple[float, ...]], ...]], ...] = ()

    def __bool__(self) -> bool:
        return bool(self.by_session)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(name for name, _ in self.by_session)

    def causes(self, session: str) -> dict[str, tuple[float, ...]]:
        """The values of every cause that differs in ``session`` (none for a session not named)."""
        return dict(dict(self.by_session).get(session, ()))

    def with_cause(self, cause: str, values: dict[str, np.ndarray]) -> SessionValues:
        """These values with ``cause`` set to ``values`` (session -> values) in every session named."""
        table = {name: dict(terms) for name, terms in self.by_session}
        for name, v in values.items():
            table.setdefault(name, {})[cause] = tuple(float(x) for x in v)
        return SessionValues(tuple((name, tuple(terms.items())) for name, terms in table.items()))

    def apply(self, robot: Robot, session: str) -> Robot:
        """``robot`` (the shared model, its sessions dropped) with the values of ``session``."""
        shared = robot.with_changes(sessions=SessionValues())
        for cause, values in self.causes(session).items():
            shared = EFFECTS[cause]().with_values(shared, np.array(values))
        return shared

    # ---- the robot file -------------------------------------------------------------------------
    def to_dict(self, robot: Robot) -> dict[str, Any]:
        """The ``sessions`` mapping of a robot file: session -> cause -> parameter -> value."""
        out: dict[str, Any] = {}
        for name, terms in self.by_session:
            out[name] = {cause: {p.name: float(v) for p, v in zip(EFFECTS[cause]().params(robot), values,
                                                                   strict=True)}
                         for cause, values in terms}
        return out

    @classmethod
    def from_doc(cls, doc: YamlDoc, keys: KeyPath, raw: Any, robot: Robot) -> SessionValues:
        """The validated ``sessions`` mapping of a robot file for the shared ``robot``."""
        if not isinstance(raw, dict) or not raw:
            raise doc.error(keys, "expected a mapping: session -> cause -> parameter -> value")
        out = cls()
        for session, causes in raw.items():
            where = keys + (session,)
            if not isinstance(causes, dict):
                raise doc.error(where, "expected a mapping: cause -> parameter -> value")
            for cause, params in causes.items():
                if cause not in EFFECTS:
                    raise doc.error(where + (cause,), f"unknown cause (known: {', '.join(EFFECTS)})")
                effect = EFFECTS[cause]()
                names = [p.name for p in effect.params(robot)]
                if not isinstance(params, dict) or set(params) - set(names):
                    raise doc.error(where + (cause,), f"expected a mapping of some of {', '.join(names)}")
                values = effect.values(robot).copy()
                for i, n in enumerate(names):
                    if n in params:
                        v = params[n]
                        if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
                            raise doc.error(where + (cause, n), f"expected a finite number, got {v!r}")
                        values[i] = float(v)
                out = out.with_cause(cause, {str(session): values})
        return out
