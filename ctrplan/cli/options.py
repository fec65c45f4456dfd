"""Option types shared by several commands."""

from __future__ import annotations

import math
import re

from ctrplan.errors import InputError

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
