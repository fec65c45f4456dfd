"""Ctrl-C, really sent, at moments that used to leak a traceback: inside a compiled numba kernel
(also one called from OMPL's C++ solve), inside OMPL's solve, and after `diagnose` wrote its
outputs. Every time: the one line ``ctrplan: aborted`` on stderr, exit 130, no output folder left
empty or half-written.

The command runs in a child process through the console-script entry (`ctrplan.cli.console.run`), with
one of these triggers:

* ``kernel NAME SKIP FILE TEXT``: as numba enters the compiled kernel NAME for the (SKIP+1)-th time
  (the profiler's call event) with a line of FILE containing TEXT on the stack (its caller, or
  OMPL's ``solve``), a 30-microsecond timer is armed; its SIGALRM handler sends SIGINT, which
  Python handles as soon as the kernel calls back into Python -- while the kernel call is still in
  progress (numba boxes its results there), which is where the interrupt used to surface as numba's
  "SystemError: ... returned a result with an exception set".
* ``inside FILE TEXT``: a watcher thread sends SIGINT when the main thread's Python stack is at a
  line of FILE containing TEXT (e.g. OMPL's ``solve``, which calls back into Python).
* ``exists PATH``: SIGINT as soon as PATH exists.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

from tests.paths import REPO

CHILD = r"""
import linecache, os, signal, sys, threading, time

def on_stack(frame, file_end, text):
    while frame is not None:
        name = frame.f_code.co_filename
        if name.endswith(file_end) and text in linecache.getline(name, frame.f_lineno):
            return True
        frame = frame.f_back
    return False

def kernel(name, skip, file_end, text):
    calls = 0
    signal.signal(signal.SIGALRM, lambda *_: os.kill(os.getpid(), signal.SIGINT))
    def profile(frame, event, arg):
        nonlocal calls
        code = frame.f_code
        if event == "call" and code.co_name == name and code.co_filename.endswith("_shooting.py") \
                and on_stack(sys._getframe(1), file_end, text):  # numba's frame has no f_back
            calls += 1
            if calls > int(skip):
                sys.setprofile(None)
                signal.setitimer(signal.ITIMER_REAL, 30e-6)
    sys.setprofile(profile)

def watch(test):
    def run():
        while True:
            try:
                if test():
                    break
            except (AttributeError, TypeError):  # a running thread's stack can change under the walk
                pass
            time.sleep(0.0005)
        os.kill(os.getpid(), signal.SIGINT)
    threading.Thread(target=run, daemon=True).start()

def inside(file_end, text):
    main = threading.main_thread().ident
    watch(lambda: on_stack(sys._current_frames().get(main), file_end, text))

kind, nargs = sys.argv[1], {"kernel": 4, "inside": 2, "exists": 1}[sys.argv[1]]
trigger, sys.argv = sys.argv[2:2 + nargs], ["ctrplan", *sys.argv[2 + nargs:]]
if kind == "kernel":
    kernel(*trigger)
elif kind == "inside":
    inside(*trigger)
else:
    watch(lambda: os.path.exists(trigger[0]))
from ctrplan.cli.console import run
run()
"""


def interrupt(trigger: list[str], args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    """Run ``ctrplan ARGS`` in a child interrupted by ``trigger`` (see the module docstring)."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.run([sys.executable, "-c", CHILD, *trigger, *args], capture_output=True, text=True,
                          timeout=600, env=env, cwd=cwd, check=False,
                          preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


#: A status line of a long step (`ctrplan.cli.progress.StatusLine`), e.g. ``plan: 11 s, compiling kernels
#: (first run only)``: printed before the interrupt when loading the kernels takes over 10 s (a loaded
#: machine), so it may precede the one line of the abort.
STATUS_LINE = re.compile(r"^[a-z -]+: \d+ s, \S")


def assert_aborted(result: subprocess.CompletedProcess, stdout: bool = False) -> None:
    assert result.returncode == 130, result.stderr[-3000:]
    *before, last = result.stderr.splitlines() or [""]
    assert last == "ctrplan: aborted" and result.stderr.endswith("\n"), result.stderr[-3000:]
    assert all(STATUS_LINE.match(line) for line in before), result.stderr[-3000:]
    assert stdout or result.stdout == ""


def test_ctrl_c_inside_a_numba_kernel(tmp_path):
    """The issue's case: `bench kinematics` times single solves, one kernel call each."""
    out = tmp_path / "bench"
    result = interrupt(["kernel", "solve_one", "20", "bench/kinematics.py", "backend.forward("],
                       ["bench", "kinematics", "--backend", "cosserat", "--n", "2000", "--batch", "0",
                        "--out", str(out)], tmp_path)
    assert_aborted(result)
    assert not out.exists()


def test_ctrl_c_inside_a_kernel_called_from_ompl_solve(tmp_path):
    """The issue's other case: `plan --planner rrtstar` with the exact model in the validity checker,
    interrupted in a kernel called back from OMPL's C++ search."""
    out = tmp_path / "plan"
    result = interrupt(["kernel", "solve_one", "20", "planning/search.py", "pl.solve("],
                       ["plan", str(REPO / "scenes" / "open.yaml"), "--backend", "cosserat",
                        "--planner", "rrtstar", "--time-limit", "20", "--out", str(out)], tmp_path)
    assert_aborted(result)
    assert not out.exists()


def test_ctrl_c_inside_ompl_solve(tmp_path):
    out = tmp_path / "plan"
    result = interrupt(["inside", "planning/search.py", "pl.solve("],
                       ["plan", str(REPO / "scenes" / "skullbase.yaml"), "--planner", "rrtstar",
                        "--seed", "1", "--out", str(out)], tmp_path)
    assert_aborted(result)
    assert not out.exists()


def test_ctrl_c_in_a_stability_sweep_leaves_no_output_folder(tmp_path):
    out = tmp_path / "stability"
    result = interrupt(["kernel", "solve_one", "30", "ctrplan/kinematics/stability.py", "backend.forward("],
                       ["stability", "--n", "4", "--steps", "9", "--out", str(out)], tmp_path)
    assert_aborted(result)
    assert not out.exists()


def test_ctrl_c_after_diagnose_wrote_its_outputs(tmp_path):
    from tests.independent.lab import make

    data = tmp_path / "lab.csv"
    make(60, {}, seed=3).write_csv(data)
    out = tmp_path / "diag"
    result = interrupt(["exists", str(out / "candidates.png")],  # its last file
                       ["diagnose", str(data), "--candidates", "curvature", "--pairs", "0", "--out",
                        str(out)], tmp_path)
    assert_aborted(result, stdout=True)  # the summary may be out already
