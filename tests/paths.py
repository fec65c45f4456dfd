"""Where the repository's shipped files are, for every test directory (tests/<package>/ sits two levels
below the repository root)."""

from __future__ import annotations

from pathlib import Path

#: The repository root.
REPO = Path(__file__).resolve().parents[1]
#: The shipped scene files.
SCENES = REPO / "scenes"
