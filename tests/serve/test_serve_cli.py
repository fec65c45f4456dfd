"""`ctrplan serve` as a user runs it: the console script in a child process prints its address, answers
the API, and Ctrl-C stops it with the one line ``ctrplan: aborted`` (exit 130), nothing listening
on its port any more;
a port in use and a foreign roadmap are one line, exit 2."""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import time

from ctrplan.cli.app import main
from tests.paths import REPO, SCENES
from tests.serve.conftest import call

START = [sys.executable, "-c", "from ctrplan.cli.console import run; run()", "serve"]


def _child(args: list[str]) -> subprocess.Popen:
    """The console script in a child with Ctrl-C at its default: a suite started in the background
    (``pytest &``) runs with SIGINT ignored, which a child would inherit (an ignored signal survives
    exec) and then never see the test's Ctrl-C."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.Popen(START + args, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def _address(proc: subprocess.Popen, timeout_s: float = 240.0) -> str:
    """The URL the child prints on stderr (its other lines are progress)."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        line = proc.stderr.readline()
        found = re.search(r"ctrplan serve: (http://\S+)", line)
        if found:
            return found.group(1)
        if not line and proc.poll() is not None:
            raise AssertionError(f"serve ended with {proc.returncode}: {proc.stderr.read()}")
    raise AssertionError("no address printed")


def test_ctrl_c_stops_the_server_with_one_line(open_roadmap, tmp_path):
    proc = _child([str(SCENES / "open.yaml"), "--roadmap", str(open_roadmap), "--port", "0",
                   "--out", str(tmp_path / "out")])
    try:
        url = _address(proc)
        status, scene = call(url + "api/scene")
        assert status == 200 and scene["planner"] == "roadmap"
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130
    assert err.strip().splitlines()[-1] == "ctrplan: aborted" and "Traceback" not in err
    port = int(url.rsplit(":", 1)[1].strip("/"))
    with socket.socket() as s:
        assert s.connect_ex(("127.0.0.1", port)) != 0  # nothing listens there any more


def test_a_port_in_use_and_a_foreign_roadmap_are_one_line_exit_2(open_roadmap, tmp_path, capsys):
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        args = ["serve", str(SCENES / "open.yaml"), "--port", str(port), "--out", str(tmp_path / "a")]
        assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith(f"ctrplan: error: --port: cannot listen on 127.0.0.1:{port}")
    assert main(["serve", str(SCENES / "pipe.yaml"), "--roadmap", str(open_roadmap)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "roadmap built for another scene" in err[0]
