"""New-user pitfalls of `ctrplan plan` (issue 10): no silent backend fallback, --model, --out parents,
OMPL noise and Ctrl-C, a meaningful target in the JSON; help that is never cut, and a --version that
imports no command."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time

import pytest
from test_cli_kinematics import run

from ctrplan.cli.app import main
from ctrplan.kinematics.model_file import resolve_model
from tests.paths import REPO

OPEN = (REPO / "scenes" / "open.yaml").read_text()
TARGET = "target:\n  point: [37.2, -27.2, 181.6]\n  tolerance_mm: 3.0\n"
#: The target behind a wall across the whole workspace: every goal configuration collides.
BLOCKED = OPEN.replace(TARGET, "target:\n  ellipsoid:\n    center: [37.2, -27.2, 181.6]\n"
                               "    semi_axes_mm: [2.0, 3.0, 4.0]\n").replace(
    "obstacles:\n", "obstacles:\n- {name: wall, box: {center: [0.0, 0.0, 165.0], "
                     "size: [400.0, 400.0, 2.0]}}\n")
#: The target inside the ball: refused before any search.
INSIDE = OPEN.replace(TARGET, "target:\n  ellipsoid:\n    center: [43.0, -47.0, 150.0]\n"
                              "    semi_axes_mm: [2.0, 3.0, 4.0]\n")


def one_line_error(rc: int, out: str, err: str, *fragments: str) -> None:
    assert rc == 2 and out == "", err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("ctrplan: error: "), err
    for fragment in fragments:
        assert fragment in lines[0], lines[0]


def test_unusable_model_is_an_error_not_a_fallback(tmp_path, capsys):
    shipped = resolve_model(None)
    for ext in (".safetensors", ".json"):
        shutil.copy(shipped.with_suffix(ext), tmp_path / f"broken{ext}")
    data = bytearray((tmp_path / "broken.safetensors").read_bytes())
    data[-10] ^= 0xFF
    (tmp_path / "broken.safetensors").write_bytes(bytes(data))
    scene = REPO / "scenes" / "open.yaml"
    one_line_error(*run(capsys, "plan", str(scene), "--model", str(tmp_path / "broken"), "--json"),
                   "--backend pinn", "broken.safetensors", "SHA-256")
    one_line_error(*run(capsys, "plan", str(scene), "--model", "no_such_model"),
                   "no_such_model", "not found", "pinn_nominal_h100")
    one_line_error(*run(capsys, "plan", str(scene), "--backend", "cosserat", "--model", "pinn_nominal"),
                   "--model", "cosserat")


def test_plan_default_pinn_out_with_new_parents(tmp_path, capsys):
    out = tmp_path / "runs" / "deep" / "open"
    rc, stdout, err = run(capsys, "plan", str(REPO / "scenes" / "open.yaml"), "--out", str(out),
                          "--json", "--time-limit", "5", "--seed", "1")
    assert rc == 0, err
    doc = json.loads(stdout)
    assert doc["backend"] == "pinn" and doc["model"] == "pinn_nominal.safetensors"
    assert doc["goal_tolerance_mm"] == 3.0 and doc["target"]["kind"] == "sphere"
    assert sorted(p.name for p in out.iterdir()) == ["obstacles.ply", "path.json", "plan.html", "plan.png",
                                                     "trajectory.csv"]
    assert "warning" not in err  # e.g. matplotlib's tight_layout warning


def test_out_under_a_file_is_refused_before_planning(tmp_path, capsys):
    (tmp_path / "runs").write_text("")
    one_line_error(*run(capsys, "plan", str(REPO / "scenes" / "open.yaml"), "--out",
                        str(tmp_path / "runs" / "x")), "--out", "not a directory")


def test_blocked_goal_reports_our_cause_not_ompl_noise(tmp_path, capfd):
    scene = tmp_path / "blocked.yaml"
    scene.write_text(BLOCKED)
    rc = main(["plan", str(scene), "--backend", "cosserat", "--time-limit", "2", "--json"])
    out, err = capfd.readouterr()  # file descriptors: OMPL writes from C++
    assert rc == 1
    doc = json.loads(out)
    assert "all in collision" in doc["message"]
    assert doc["goal_tolerance_mm"] is None
    assert doc["target"]["kind"] == "ellipsoid" and doc["target"]["semi_axes_mm"] == [2.0, 3.0, 4.0]
    assert "Skipping invalid goal" not in err and "at line" not in err and "Warning:" not in err


def test_a_target_inside_an_obstacle_is_refused_before_searching(tmp_path, capsys):
    scene = tmp_path / "inside.yaml"
    scene.write_text(INSIDE)
    one_line_error(*run(capsys, "plan", str(scene), "--backend", "cosserat", "--time-limit", "60"),
                   "target", "inside the obstacle 'ball'")


def test_ctrl_c_prints_one_line(tmp_path):
    """Ctrl-C 3 s into planning (the planner would search for 60 s), sent from outside as a terminal
    sends it, to a process that does not ignore it (a shell starts background jobs, e.g. a CI script
    run with `&`, with SIGINT ignored, and ctrplan keeps an ignored SIGINT ignored)."""
    scene = tmp_path / "blocked.yaml"
    scene.write_text(BLOCKED)
    started = tmp_path / "planning"
    script = ("import sys\n"
              "from pathlib import Path\n"
              "import ctrplan.planning as planning\n"
              "from ctrplan.cli.app import main\n"
              "plan = planning.plan\n"
              "def announced_plan(*args, **kwargs):\n"
              f"    Path({str(started)!r}).touch()\n"
              "    return plan(*args, **kwargs)\n"
              "planning.plan = announced_plan\n"
              "sys.exit(main(sys.argv[1:]))\n")
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen([sys.executable, "-c", script, "plan", str(scene), "--backend", "cosserat",
                             "--time-limit", "60", "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=env,
                            # as at a terminal: a shell starts background jobs with SIGINT ignored
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 120
    while not started.exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(3.0)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, (out[-3000:], err[-3000:])
    assert err.strip() == "ctrplan: aborted", err
    assert out == ""


@pytest.mark.parametrize("command", [[], ["fk"], ["shape"], ["plan"], ["train"], ["eval-model"],
                                     ["diagnose"], ["bench", "kinematics"], ["bench", "plan"]])
def test_help_is_never_cut_and_flags_have_no_metavar(capsys, monkeypatch, command):
    monkeypatch.setenv("COLUMNS", "60")
    rc, out, _ = run(capsys, *command, "--help")
    assert rc == 0 and "Usage:" in out
    assert "…" not in out
    cut = [line for line in out.splitlines()[1:] if re.search(r"\w\.\.\.$", line)]  # click's short help
    assert not cut
    assert "<bool>" not in out and "BOOLEAN" not in out


def test_version_does_not_import_the_commands():
    code = ("import sys\nfrom ctrplan.cli.app import main\nrc = main(['--version'])\n"
            "print(rc, 'torch' in sys.modules, 'ompl' in sys.modules, 'matplotlib' in sys.modules)")
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                            timeout=60, check=True)
    version, flags = result.stdout.splitlines()
    assert version.startswith("ctrplan ") and flags == "0 False False False"
