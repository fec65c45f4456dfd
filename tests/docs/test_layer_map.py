"""The layer map of docs/design.md §2 is the code's: every layer a folder, the table generated from the
import-linter contract, the modules on disk and the package docstrings (scripts/draw_layers.py)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def _draw_layers():
    spec = importlib.util.spec_from_file_location("draw_layers", REPO / "scripts" / "draw_layers.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_every_layer_is_a_folder_and_the_root_holds_at_most_two_modules():
    root = REPO / "ctrplan"
    loose = sorted(p.name for p in root.glob("*.py"))
    assert len(loose) <= 2, loose
    packages = {p.name for p in root.iterdir() if (p / "__init__.py").exists()} - {"data"}
    in_contract = {name for layer in _draw_layers().contract_layers() for name in layer}
    assert packages == in_contract


def test_the_design_documents_layer_table_is_generated_from_the_code():
    layers = _draw_layers()
    assert layers.table_is_current(), "run python scripts/draw_layers.py"
    table = layers.table()
    assert "| `collision` | `broadphase`, `capsules`, `checker`, `world` |" in table
