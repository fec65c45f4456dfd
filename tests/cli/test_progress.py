"""Long jobs are not silent when stderr is a log or a pipe: a plain progress line about every
`PROGRESS_EVERY_S` seconds (shortened here), never terminal control sequences, stdout untouched."""

from __future__ import annotations

import json
import time

import ctrplan.cli.progress as progress
from ctrplan.cli import main


def test_stability_prints_plain_sweep_counts_when_not_on_a_terminal(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(progress, "PROGRESS_EVERY_S", 0.005)
    assert main(["stability", "--n", "3", "--steps", "9", "--out", str(tmp_path / "s"), "--json"]) == 0
    captured = capsys.readouterr()
    json.loads(captured.out)
    lines = [line for line in captured.err.splitlines() if line.startswith("stability: ")]
    assert lines and all(" s, " in line for line in lines), captured.err
    assert any(" of 3 sweeps" in line or "starting" in line for line in lines)
    assert "\x1b[" not in captured.err


def test_the_lines_stop_with_the_job(capsys):
    with progress.PlainProgress("job", enabled=True, every_s=0.002) as plain:
        plain("half way")
        for _ in range(200):
            if "half way" in capsys.readouterr().err:
                break
            time.sleep(0.005)
        else:
            raise AssertionError("no progress line")
    time.sleep(0.02)
    capsys.readouterr()
    time.sleep(0.02)
    assert capsys.readouterr().err == ""
