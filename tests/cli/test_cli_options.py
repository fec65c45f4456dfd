"""Durations on the command line: one convention for every --time-limit."""

from __future__ import annotations

import pytest

from ctrplan.base.errors import InputError
from ctrplan.cli.options import parse_duration
from tests.paths import REPO


@pytest.mark.parametrize(("text", "bare", "seconds"), [
    ("90s", "min", 90.0), ("10m", "s", 600.0), ("1.5h", "s", 5400.0), ("2min", "s", 120.0),
    ("12", "s", 12.0), ("12", "min", 720.0), ("0.05", "min", 3.0), (" 3 s ", "min", 3.0)])
def test_units_and_the_bare_number(text, bare, seconds):
    assert parse_duration(text, bare) == pytest.approx(seconds)


@pytest.mark.parametrize("text", ["", "ten", "5 days", "-3s", "0", "1e999s", "5ms"])
def test_what_is_not_a_duration_is_one_line(text):
    with pytest.raises(InputError, match="--time-limit"):
        parse_duration(text, "s")


@pytest.mark.parametrize("command", [["plan", "scenes/open.yaml"], ["bench", "plan", "scenes/open.yaml"],
                                     ["design", "scenes/skullbase_design.yaml"], ["train"]])
def test_every_time_limit_reads_durations_the_same_way(command, capsys, monkeypatch):
    from ctrplan.cli.app import main

    monkeypatch.chdir(REPO)
    assert main([*command, "--time-limit", "ten minutes"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--time-limit: must be a positive duration (e.g. 90s, 10m, 1.5h" in err[0], err
