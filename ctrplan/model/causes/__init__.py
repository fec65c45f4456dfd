"""The library of candidate causes: physical extensions of a robot model, each owning its parameters
(unit, plausible range and where that range comes from), where the robot file keeps it, what the data
must show for it to be seen, and how it changes the model.

Every subclass of `Effect` with a ``name`` registers itself in `EFFECTS` (definition order); `CAUSES`
is derived from it, and the command line, the library and the tests use those.

An effect acts on one side of the model (``Effect.side``), in the order a prediction applies them:

* ``joints``    -- reported joints -> the joints the mechanics sees (backlash, windup);
* ``mechanics`` -- tube parameters, transmission lengths, joint offsets, loads (`Robot` fields, solved
  by the Cosserat backend);
* ``tip``       -- the tracked point relative to the solved tip of tube 1 (sensor offset);
* ``frame``     -- robot frame -> tracker frame (registration).

The measurement-side effects (`MeasurementEffect`; a cause derives from the class of its side,
`JointsEffect`, `TipEffect` or `FrameEffect`, which declares the one map it must define) live in the
robot's `ctrplan.model.measurement.Calibration`, under the robot file's ``calibration`` key.

The table of causes (cause, side, parameters) follows, rendered from the registered classes
(`base.cause_table`). Adding a cause is one `Effect` subclass (in `mechanics` or
`measurement_side`): the command line, the library, the reports and the tests read `EFFECTS` (a
mechanics-side cause sets `Robot` fields; a new physical parameter is also a field of the robot file
and of the solver).

"""

from __future__ import annotations

# Importing a module registers its causes, in this order (the order of `CAUSES`: mechanics first).
from ctrplan.model.causes import mechanics  # noqa: F401

# isort: split
from ctrplan.model.causes import measurement_side  # noqa: F401
from ctrplan.model.causes.base import EFFECTS, cause_table

#: Every cause name, in definition order.
CAUSES = tuple(EFFECTS)
#: The causes `diagnose` tries unless told which (`Effect.tried_by_default`).
DEFAULT_CAUSES = tuple(name for name, effect in EFFECTS.items() if effect.tried_by_default)

if __doc__ is not None:  # the package's table of causes (absent under python -OO)
    __doc__ += cause_table()
