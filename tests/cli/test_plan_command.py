"""New-user pitfalls of `ctrplan plan` (issue 10): no silent backend fallback, --model, --out parents,
OMPL noise and Ctrl-C, a meaningful target in the JSON, the plan figure and viewer."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from ctrplan.cli import main
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


def run(capsys, *args: str) -> tuple[int, str, str]:
    rc = main(list(args))
    out, err = capsys.readouterr()
    return rc, out, err


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
              "from ctrplan.cli import main\n"
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


def test_plan_figure_names_every_obstacle_target_and_tip_trace(tmp_path):
    from ctrplan.scene import load_scene
    from ctrplan.viz.plan_plot import plan_figure, plot_plan

    balls = "".join(f"- name: ball{i:02d}\n  sphere:\n    center: [{-60 + 8 * i}.0, 40.0, 150.0]\n"
                    f"    radius: 2.0\n" for i in range(16))
    text = OPEN.replace(OPEN[OPEN.index("- name: ball"):OPEN.index("target:")], balls)
    (tmp_path / "many.yaml").write_text(text)
    scene = load_scene(tmp_path / "many.yaml")
    z = np.linspace(0, 180, 30)
    bbs = np.stack([np.column_stack([np.zeros(30) + k, np.zeros(30), z]) for k in range(5)])
    fig = plan_figure(scene, bbs, tip_path=bbs[:, -1])
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert labels[:16] == [f"ball{i:02d}" for i in range(16)]
    assert {"target", "tip trace", "start", "end"} <= set(labels)
    ax3 = next(a for a in fig.axes if a.name == "3d")
    for axis in (ax3.xaxis, ax3.yaxis, ax3.zaxis):
        assert len(axis.get_major_locator()()) <= 6
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the old tight_layout call warned on every figure
        plot_plan(scene, bbs, tmp_path / "p.png", tip_path=bbs[:, -1])
    assert (tmp_path / "p.png").stat().st_size > 0


def test_viewer_has_a_scale_bar(tmp_path):
    from ctrplan.scene import load_scene
    from ctrplan.viz import viewer_data, write_viewer

    scene = load_scene(REPO / "scenes" / "open.yaml")
    bbs = np.zeros((2, 5, 3))
    bbs[..., 2] = np.linspace(0, 100, 5)
    html = write_viewer(tmp_path / "v.html", viewer_data(scene, bbs, np.full((2, 5), 0.75))).read_text()
    assert "function scaleBar()" in html and "scaleBar();" in html and '" mm (at the view centre)"' in html


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
    code = ("import sys\nfrom ctrplan.cli import main\nrc = main(['--version'])\n"
            "print(rc, 'torch' in sys.modules, 'ompl' in sys.modules, 'matplotlib' in sys.modules)")
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                            timeout=60, check=True)
    version, flags = result.stdout.splitlines()
    assert version.startswith("ctrplan ") and flags == "0 False False False"


def test_library_resolve_backend_does_not_fall_back(tmp_path):
    from importlib import resources

    from ctrplan.errors import InputError
    from ctrplan.planning import resolve_backend
    from ctrplan.robot import Robot

    text = resources.files("ctrplan.data").joinpath("nominal.yaml").read_text()
    (tmp_path / "r.yaml").write_text(text.replace("curvature_1_per_m: 28.0", "curvature_1_per_m: 30.0")
                                     .replace("name: nominal", "name: r"))
    other = Robot.load(str(tmp_path / "r.yaml"))  # the shipped PINNs were trained for other robots
    with pytest.raises(InputError) as info:
        resolve_backend(None, other)
    message = str(info.value)  # names this robot, where it looked and how to train one; no other model
    assert message.startswith("no PINN model trained for robot 'r' (fingerprint ")
    assert str(Path("models").resolve()) in message and "shipped models (pinn_nominal" in message
    assert "ctrplan train --robot ROBOT.yaml --name r_pinn" in message and "'nominal'" not in message
    assert resolve_backend("cosserat", other).name == "cosserat"
