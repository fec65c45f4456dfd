"""The house rule on module size (docs/design.md §2): no module of the package over 500 lines without
a stated reason in its docstring ("Over 500 lines because ...")."""

from __future__ import annotations

import ast

from tests.paths import REPO

LIMIT = 500
REASON = "Over 500 lines because"


def test_every_long_module_says_why():
    paths = sorted((REPO / "ctrplan").rglob("*.py"))
    assert len(paths) > 100  # the package itself, not an empty folder
    long = {p: p.read_text() for p in paths if p.read_text().count("\n") > LIMIT}
    silent = [p.relative_to(REPO).as_posix() for p, text in long.items()
              if REASON not in (ast.get_docstring(ast.parse(text)) or "")]
    assert not silent, silent
