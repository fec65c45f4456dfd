"""Every ``from ctrplan… import name`` in the package resolves, the lazy ones inside functions too
(commands import their libraries when they run, so a moved module would otherwise surface only when
that command is used)."""

from __future__ import annotations

import ast
import importlib
import importlib.util

from tests.paths import REPO


def ctrplan_imports() -> list[tuple[str, int, str, str]]:
    """(file, line, module, name) of every absolute ``from ctrplan… import name`` in ctrplan/."""
    found = []
    for path in sorted((REPO / "ctrplan").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            absolute = isinstance(node, ast.ImportFrom) and node.level == 0
            if absolute and (node.module or "").startswith("ctrplan"):
                found += [(str(path.relative_to(REPO)), node.lineno, node.module, a.name) for a in node.names]
    return found


def test_every_imported_name_exists():
    imports = ctrplan_imports()
    assert sum(where.startswith("ctrplan/cli/") for where, *_ in imports) > 50  # the lazy ones are there
    missing = []
    for where, line, module, name in imports:
        try:
            loaded = importlib.import_module(module)
        except ImportError:
            missing.append(f"{where}:{line}: {module}")
            continue
        if not hasattr(loaded, name) and importlib.util.find_spec(f"{module}.{name}") is None:
            missing.append(f"{where}:{line}: {module}.{name}")
    assert not missing, missing
