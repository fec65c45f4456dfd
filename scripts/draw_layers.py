#!/usr/bin/env python3
"""Draw ctrplan's layer map from the code: the layers of the import-linter contract in
pyproject.toml, each package's modules as they are on disk and the first sentence of each package's
docstring. Writes docs/figures/layers.svg and the generated table of docs/design.md §2 (between its
``<!-- layers:start -->`` and ``<!-- layers:end -->`` markers).

    python scripts/draw_layers.py            # both
    python scripts/draw_layers.py --check    # exit 1 when docs/design.md's table is out of date
"""

from __future__ import annotations

import ast
import re
import sys
import textwrap
from pathlib import Path

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "ctrplan"
DESIGN = ROOT / "docs" / "design.md"
FIGURE = ROOT / "docs" / "figures" / "layers.svg"
MARKERS = ("<!-- layers:start -->", "<!-- layers:end -->")


def contract_layers() -> list[list[str]]:
    """The layers of the import-linter contract, top first, each a list of package names."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    layers = next(c for c in config["tool"]["importlinter"]["contracts"] if c["type"] == "layers")["layers"]
    return [[p.strip() for p in re.split(r"[|:]", layer)] for layer in layers]


def summary(package: str) -> str:
    """First sentence of the package's docstring."""
    path = PACKAGE / package / "__init__.py"
    if not path.exists():
        path = PACKAGE / f"{package}.py"
    doc = ast.get_docstring(ast.parse(path.read_text())) or ""
    first = " ".join(doc.split("\n\n")[0].split())
    return re.split(r"(?<=[a-z)`])\. ", first + " ")[0].strip().rstrip(".")


def modules(package: str) -> list[str]:
    """The package's modules and subpackages (no private modules, no `__init__`)."""
    folder = PACKAGE / package
    if not folder.is_dir():
        return []
    names = [p.stem for p in folder.glob("*.py") if not p.stem.startswith("_")]
    names += [p.name for p in folder.iterdir() if p.is_dir() and (p / "__init__.py").exists()]
    return sorted(names)


def table() -> str:
    """The markdown table of the layers (numbered bottom up)."""
    layers = contract_layers()
    rows = ["| layer | package | modules | holds |", "|---|---|---|---|"]
    for i, layer in enumerate(layers):
        for package in layer:
            mods = ", ".join(f"`{m}`" for m in modules(package))
            rows.append(f"| {len(layers) - i} | `{package}` | {mods} | {summary(package)} |")
    return "\n".join(rows)


def write_table() -> None:
    text = DESIGN.read_text()
    start, end = text.index(MARKERS[0]) + len(MARKERS[0]), text.index(MARKERS[1])
    DESIGN.write_text(text[:start] + "\n" + table() + "\n" + text[end:])


def table_is_current() -> bool:
    text = DESIGN.read_text()
    start, end = text.index(MARKERS[0]) + len(MARKERS[0]), text.index(MARKERS[1])
    return text[start:end].strip() == table().strip()


def draw(out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import FancyArrowPatch, FancyBboxPatch

    layers = contract_layers()
    colours = ["#dbe9f6", "#e3f1dc", "#fbe7cf", "#f3dcef", "#fff4c2", "#e8e2f7", "#d9f2ee", "#fde0dc",
               "#e6e6e6", "#f4f4f4", "#eef4e4", "#f6ecf3"]
    left, right, height = 1.0, 9.9, 0.84
    plt.rcParams.update({"svg.hashsalt": "ctrplan", "svg.fonttype": "none"})  # stable ids, text as text
    n = len(layers)
    fig, ax = plt.subplots(figsize=(10, 0.7 * n + 0.9))
    ax.set_xlim(0, 10)
    ax.set_ylim(-0.3, n + 0.55)
    ax.axis("off")
    for i, boxes in enumerate(layers):
        y = n - 1 - i
        ax.text(left - 0.15, y + height / 2, str(n - i), ha="right", va="center", fontsize=10, color="#666")
        width = (right - left - 0.1 * (len(boxes) - 1)) / len(boxes)
        chars = int(width * 13)
        for j, name in enumerate(boxes):
            x = left + j * (width + 0.1)
            ax.add_patch(FancyBboxPatch((x, y), width, height, boxstyle="round,pad=0,rounding_size=0.08",
                                        fc=colours[i % len(colours)], ec="#777", lw=0.8))
            ax.text(x + 0.1, y + height - 0.17, f"{name}/", fontsize=11.5, fontweight="bold", va="center")
            body = textwrap.shorten(summary(name), chars) + "\n" + textwrap.shorten(
                " ".join(modules(name)), chars)
            ax.text(x + 0.1, y + 0.3, body, fontsize=7.8, va="center", color="#333", linespacing=1.3)
        if i < n - 1:
            ax.add_patch(FancyArrowPatch((0.45, y + height / 2), (0.45, y - 1 + height / 2 + 0.12),
                                         arrowstyle="-|>", mutation_scale=10, color="#555", lw=1))
    ax.text(0.45, n - 1 + height + 0.08, "imports", ha="center", fontsize=9, color="#555")
    ax.set_title("ctrplan's layers (from pyproject.toml): a package imports only from the layers below it",
                 fontsize=12, fontweight="bold")
    fig.tight_layout()
    fig.savefig(out, dpi=110, metadata={"Date": None} if out.suffix == ".svg" else None)
    plt.close(fig)


if __name__ == "__main__":
    if sys.argv[1:] == ["--check"]:
        ok = table_is_current()
        print("docs/design.md: layer table is current" if ok else
              "docs/design.md: layer table is out of date (run python scripts/draw_layers.py)")
        sys.exit(0 if ok else 1)
    write_table()
    draw(FIGURE)
    print(f"wrote {DESIGN.relative_to(ROOT)} (layer table) and {FIGURE.relative_to(ROOT)}")
