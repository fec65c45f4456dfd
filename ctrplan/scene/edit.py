"""Change top-level keys of a scene file and keep the rest of its text -- the user's comments, key order
and formatting (`ctrplan scene place` writes a base pose and a start into the user's own scene).

A top-level key's block is its line and every following line that is indented, blank or a list item
(``- ``, which block style writes at the left margin); the block is
replaced by the key dumped anew (block style), or appended where the key is missing. Comments at the
left margin between blocks stay where they are. The edited text is read back and compared with what
was meant; where it differs (a file in flow style, anchors), the whole mapping is dumped instead and
the caller is told the comments were not kept.
"""

from __future__ import annotations

import re
from typing import Any

import yaml

from ctrplan.base.yamlio import dump_yaml

_TOP_KEY = re.compile(r"^([A-Za-z_][\w-]*)\s*:")


def _block(lines: list[str], key: str) -> tuple[int, int] | None:
    """The line range [start, end) of top-level ``key``'s block, None where it is missing."""
    for i, line in enumerate(lines):
        m = _TOP_KEY.match(line)
        if m and m.group(1) == key:
            end = i + 1
            while end < len(lines) and (not lines[end].strip() or lines[end][0] in " \t-"):
                end += 1
            while end > i + 1 and not lines[end - 1].strip():  # trailing blank lines stay outside
                end -= 1
            return i, end
    return None


def with_keys(text: str, changes: dict[str, Any]) -> tuple[str, bool]:
    """``text`` (a YAML mapping) with the top-level keys of ``changes`` set to their values; and whether
    the rest of the text (comments, formatting) was kept (False: the whole mapping was dumped)."""
    lines = text.splitlines(keepends=True)
    for key, value in changes.items():
        new = dump_yaml({key: value}).splitlines(keepends=True)
        span = _block(lines, key)
        if span is None:
            if lines and not lines[-1].endswith("\n"):
                lines[-1] += "\n"
            lines += new
        else:
            lines[span[0]:span[1]] = new
    edited = "".join(lines)
    want = yaml.safe_load(text) or {}
    want.update(changes)
    try:
        kept = yaml.safe_load(edited) == _plain(want)
    except yaml.YAMLError:
        kept = False
    return (edited, True) if kept else (dump_yaml(want), False)


def _plain(value: Any) -> Any:
    """``value`` as YAML reads it back (tuples as lists)."""
    return yaml.safe_load(dump_yaml({"v": value}))["v"] if not isinstance(value, dict) else \
        {k: _plain(v) for k, v in value.items()}
