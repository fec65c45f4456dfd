"""Sizes that cannot fit are refused before any work: ``--n``, ``--points``, ``--batch`` of the
commands that hold all their configurations in memory at once.

Each command estimates the bytes its arrays take per configuration (or per backbone point) and
`check_fits` compares the total with the memory available now (Linux: ``MemAvailable`` of
``/proc/meminfo``, capped by a cgroup v2 limit; elsewhere the physical memory). A size needing more
than `MEMORY_SHARE` of it is an `InputError` naming the option, with the largest size that fits.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

from ctrplan.base.errors import InputError

#: The share of the available memory a command's arrays may take (the rest: Python, torch, plots).
MEMORY_SHARE = 0.5
#: Bytes of a float64.
F8 = 8


def available_bytes() -> float:
    """Memory the process can still allocate (bytes): ``MemAvailable``, or the room left under a
    cgroup v2 limit if smaller; the physical memory where neither is readable; inf if nothing is."""
    sizes = []
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                sizes.append(int(line.split()[1]) * 1024)
    except (OSError, ValueError, IndexError):
        pass
    try:
        cgroup = Path("/sys/fs/cgroup")
        limit = (cgroup / "memory.max").read_text().strip()
        if limit != "max":
            sizes.append(int(limit) - int((cgroup / "memory.current").read_text()))
    except (OSError, ValueError):
        pass
    if not sizes:
        try:
            sizes.append(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
        except (OSError, ValueError, AttributeError):
            return math.inf
    return float(min(sizes))


def backbone_bytes(n_tubes: int, points: int) -> int:
    """Bytes of one configuration's `Backbone` at ``points`` points: state, arc lengths and radii
    per point, plus the per-configuration fields."""
    n_states = 2 * n_tubes + 9
    return F8 * (points * (n_states + 2) + 2 * n_states + 2 * n_tubes + 3 * n_tubes + 4)


def _size(n_bytes: float) -> str:
    return f"{n_bytes / 2**30:,.1f} GiB" if n_bytes >= 2**30 else f"{n_bytes / 2**20:,.0f} MiB"


def check_fits(option: str, count: int, bytes_each: float, what: str) -> None:
    """Refuse ``count`` items of ``bytes_each`` bytes (``what``: "configurations", "points", …) when
    they need more than `MEMORY_SHARE` of `available_bytes`: an `InputError` naming ``option``, the
    estimate, the memory available and the largest count that fits."""
    room = MEMORY_SHARE * available_bytes()
    need = count * bytes_each
    if need <= room:
        return
    fits = int(room // bytes_each)
    raise InputError(f"{option}: {count:,} {what} need about {_size(need)} of memory, more than half of "
                     f"the {_size(room / MEMORY_SHARE)} available; use at most {fits:,}")


def check_backbones(n_option: str | None, n: int, points_option: str | None, points: int, n_tubes: int,
                    copies: float) -> None:
    """Refuse ``n`` backbones of ``points`` points held at once, ``copies`` arrays of each alive
    together: an `InputError` naming ``points_option`` when one configuration alone does not fit,
    else ``n_option`` (an option None is not the user's to change: the other one is named)."""
    each = copies * backbone_bytes(n_tubes, points)
    if points_option is not None:
        check_fits(points_option, points, each / points, "backbone points per configuration")
    check_fits(n_option or points_option or "size", n, each, f"configurations of {points} points")
