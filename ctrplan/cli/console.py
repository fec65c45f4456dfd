"""The process around a command: Ctrl-C, at any moment, ends it with one line and exit 130.

The first Ctrl-C raises `KeyboardInterrupt` where the main thread is, so that `with` blocks clean up
(temporary files, progress displays, worker processes), and is remembered: whatever it turns into
on its way out -- numba's SystemError when it lands in a compiled kernel, a RuntimeError from a
half-compiled one, an exception OMPL's C++ solve passes on, an "Exception ignored in ..." of a
finaliser, or nothing -- the command ends with ``ctrplan: aborted``. A second Ctrl-C ends the
process at once. Before the command (imports) and after it (atexit callbacks) there is nothing to
clean up: Ctrl-C then ends the process at once, and the process leaves right after the atexit
callbacks, before the interpreter's own teardown, where Python no longer handles signals.

Only the standard library is imported here, so the console script catches Ctrl-C from its start.
"""

from __future__ import annotations

import atexit
import contextlib
import gc
import os
import signal
import sys
import threading
import traceback
from collections.abc import Callable
from typing import NoReturn

#: Exit code after Ctrl-C (128 + SIGINT); no command returns it otherwise.
INTERRUPTED = 130

_interrupted = False
_exit_code = 1  # what the process exits with if the command never returned one


def run() -> NoReturn:
    """The ``ctrplan`` console script: `ctrplan.cli.app.main` inside the Ctrl-C handling above."""
    global _exit_code
    _on_ctrl_c(_abort_now)
    atexit.register(_leave)  # registered first, so it runs after the callbacks of every later import
    from ctrplan.cli.app import main

    _exit_code = main()  # puts `_abort_now` back as the Ctrl-C handler when it returns
    sys.exit(_exit_code)


def interrupted() -> bool:
    """Whether Ctrl-C came since `catch_ctrl_c`."""
    return _interrupted


def catch_ctrl_c() -> Callable | None:
    """Handle Ctrl-C as described above while a command runs (main thread only; a SIGINT the caller
    ignores stays ignored); return the handler to put back with `restore`, or None."""
    global _interrupted
    _interrupted = False
    sys.unraisablehook = _unraisable
    if threading.current_thread() is not threading.main_thread():
        return None
    return _on_ctrl_c(_on_sigint)


def restore(previous: Callable | None) -> None:
    if previous is not None:
        signal.signal(signal.SIGINT, previous)


def abort(exc: BaseException | None = None) -> NoReturn:
    """End an interrupted command: release what the frames of ``exc`` (its traceback and context
    chain) still hold, so that finalisers run (a process pool's semaphores, say, which the
    multiprocessing resource tracker would otherwise report as leaked), then `_abort_now`."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        traceback.clear_frames(exc.__traceback__)
        exc = exc.__context__
    gc.collect()
    _abort_now()


def _abort_now(*_signal) -> NoReturn:
    """One line, then end the process now: skip the interpreter's exit, where nanobind would list
    the OMPL objects a half-finished planner still holds as "leaked"."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a further Ctrl-C cannot interrupt the goodbye
    with contextlib.suppress(Exception):  # e.g. a reentrant flush when the signal came mid-write
        sys.stdout.flush()
    os.write(2, b"ctrplan: aborted\n")
    os._exit(INTERRUPTED)


def _on_ctrl_c(handler: Callable) -> Callable | None:
    previous = signal.getsignal(signal.SIGINT)
    if previous is signal.SIG_IGN:
        return None
    signal.signal(signal.SIGINT, handler)
    return previous


def _on_sigint(signum: int, frame: object) -> None:
    global _interrupted
    if _interrupted:
        _abort_now()
    _interrupted = True
    raise KeyboardInterrupt


def _unraisable(info: sys.UnraisableHookArgs) -> None:
    """"Exception ignored in ..." after Ctrl-C: no traceback, the one line."""
    if _interrupted or isinstance(info.exc_value, KeyboardInterrupt):
        _abort_now()
    sys.__unraisablehook__(info)


def _leave() -> NoReturn:
    """The last atexit callback: flush and exit with the command's code."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(_exit_code)


if __name__ == "__main__":
    run()
