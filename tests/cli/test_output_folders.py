"""Nothing half-made is left behind: an output folder check that makes and removes every missing
parent, also when the command fails after the check.

The habit these tests keep (issue 25 §5): every safety or science function gets a test that a sign,
index, bound or unit error would fail -- here the one-level-deep case that hides a check forgetting
the parents (`scripts/mutations.py` applies it; the atomic write interrupted by Ctrl-C is in
`tests/model/test_dataio.py`).
"""

from __future__ import annotations

from ctrplan.base.dataio import check_output_dir
from ctrplan.cli.app import main


def test_the_output_check_leaves_no_folder_of_a_deep_new_path(tmp_path):
    """Three new levels: the check makes them all (proving they can be made) and removes them all."""
    out = tmp_path / "new" / "deeper" / "out"
    assert check_output_dir(out) == out
    assert list(tmp_path.iterdir()) == []


def test_a_command_failing_after_the_output_check_leaves_no_folder(tmp_path, capsys, monkeypatch):
    """`plan` checks --out before it reads the scene; the scene is missing: exit 2, one line, and none
    of the three new folders of --out is left."""
    monkeypatch.chdir(tmp_path)
    rc = main(["plan", "missing.yaml", "--out", "new/deeper/out"])
    err = capsys.readouterr().err
    assert rc == 2 and "missing.yaml" in err and len(err.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []
