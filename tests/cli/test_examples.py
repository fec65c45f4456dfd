"""Every script in examples/ runs (fast settings) and writes what it says (issue 10)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from tests.paths import REPO

EXAMPLES = REPO / "examples"

#: example -> (fast arguments, with {out} for an output directory; a fragment of its output;
#: files it must write under {out})
RUNS = {
    "custom_planner.py": (["scenes/open.yaml", "--backend", "cosserat", "--time", "5"],
                          "kinematics calls", []),
    "diagnose_walkthrough.py": (["--rows", "120", "--out", "{out}"], "[4] the hidden cause was",
                                ["measured.csv", "extended_robot.yaml"]),
    "plan_and_plot.py": (["--scene", "scenes/open.yaml", "--time-limit", "5", "--out", "{out}"],
                         "exact model: collision-free True", ["plan.png", "plan.html"]),
}


def test_every_example_has_a_fast_run():
    assert sorted(p.name for p in EXAMPLES.glob("*.py")) == sorted(RUNS)


@pytest.mark.parametrize("name", sorted(RUNS))
def test_example_runs(tmp_path, name):
    args, fragment, files = RUNS[name]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    result = subprocess.run([sys.executable, str(EXAMPLES / name),
                             *(a.format(out=tmp_path) for a in args)],
                            cwd=REPO, capture_output=True, text=True, env=env, timeout=600, check=False)
    assert result.returncode == 0, result.stderr[-2000:]
    assert fragment in result.stdout, result.stdout[-2000:]
    for f in files:
        assert (tmp_path / f).exists(), f
