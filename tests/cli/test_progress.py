"""Long jobs are not silent when stderr is a log or a pipe: a plain progress line about every
`PROGRESS_EVERY_S` seconds (shortened here), never terminal control sequences, stdout untouched --
stability, plan (with its kernel count), bench kinematics and bench plan."""

from __future__ import annotations

import json
import re
import time

import ctrplan.cli.progress as progress
from ctrplan.cli.app import main
from tests.paths import SCENES


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


def plain_lines(err: str, what: str) -> list[str]:
    """The plain progress lines of ``what`` on stderr: each ``what: <seconds> s, <text>``, and no
    terminal control sequence anywhere."""
    assert "\x1b[" not in err
    lines = [line for line in err.splitlines() if line.startswith(f"{what}: ")]
    assert lines and all(re.fullmatch(rf"{what}: \d+ s, .+", line) for line in lines), err
    return lines


def test_plan_counts_its_kernels_in_the_plain_lines(capsys, monkeypatch):
    """The PINN plans and the Cosserat model validates: two backends, each with a single-query and a
    batched kernel set, and the exact path solver of the validation (the robot is certified), so the
    count runs 0/5 ... 5/5 and never backwards."""
    monkeypatch.setattr(progress, "PROGRESS_EVERY_S", 0.001)
    assert main(["plan", str(SCENES / "open.yaml"), "--json"]) == 0
    captured = capsys.readouterr()
    json.loads(captured.out)
    counts = [tuple(map(int, m.groups())) for line in plain_lines(captured.err, "plan")
              if (m := re.search(r"compiling kernels (\d+)/(\d+) \(first run only\)$", line))]
    assert counts, captured.err
    assert {total for _, total in counts} == {5}
    done = [k for k, _ in counts]
    assert done == sorted(done) and set(done) <= set(range(6))


def test_bench_kinematics_prints_plain_counts_from_the_caller(tmp_path, capsys, monkeypatch):
    """No timer thread beside the timed calls: the lines come from the caller after a call once the
    interval has passed. The Cosserat solver is timed cold and warm: 2 x 5 calls."""
    monkeypatch.setattr(progress, "PROGRESS_EVERY_S", 1e-6)
    rc = main(["bench", "kinematics", "--backend", "cosserat", "--n", "5", "--points", "20", "--batch", "0",
               "--out", str(tmp_path / "b"), "--json"])
    assert rc == 0
    captured = capsys.readouterr()
    json.loads(captured.out)
    counts = [re.search(r"(\d+) of (\d+)$", line).groups() for line in
              plain_lines(captured.err, "bench kinematics")]
    assert counts[-1] == ("10", "10") and {total for _, total in counts} == {"10"}, counts


def test_bench_plan_prints_plain_run_counts(tmp_path, capsys, monkeypatch):
    """Runs are counted as their batches (runs of one scene and backend) finish; the second batch takes
    far longer than the interval, so the count after the first is written (by the caller or the timer
    thread)."""
    monkeypatch.setattr(progress, "PROGRESS_EVERY_S", 0.001)
    rc = main(["bench", "plan", str(SCENES / "open.yaml"), str(SCENES / "pipe.yaml"), "--backend", "cosserat",
               "--planner", "rrtconnect", "--runs", "1", "--time-limit", "5", "--out", str(tmp_path / "b"),
               "--json"])
    assert rc == 0
    captured = capsys.readouterr()
    json.loads(captured.out)
    counts = {line.rsplit(", ", 1)[1] for line in plain_lines(captured.err, "bench plan")}
    assert "1 of 2" in counts and counts <= {"starting", "1 of 2", "2 of 2"}, counts
