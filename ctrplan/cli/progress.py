"""Progress of long jobs when nobody watches a terminal: a plain line on stderr about every
`PROGRESS_EVERY_S` seconds (a log, a pipe, CI). On a terminal the commands draw rich bars instead."""

from __future__ import annotations

import sys
import threading
import time

#: Seconds between plain progress lines when stderr is not a terminal.
PROGRESS_EVERY_S = 10.0


class PlainProgress:
    """``what: <elapsed> s, <latest text>`` on stderr about every ``every_s`` seconds while the block
    runs, from a timer thread (one long compiled call does not silence it); silent when ``enabled``
    is False (stderr is a terminal and a rich bar shows the progress). Call it with the latest text."""

    def __init__(self, what: str, enabled: bool | None = None, every_s: float | None = None):
        self.what = what
        self.enabled = (not sys.stderr.isatty()) if enabled is None else enabled
        self.every_s = PROGRESS_EVERY_S if every_s is None else every_s
        self.text = "starting"
        self.t0 = time.monotonic()
        self._done = threading.Event()
        self._timer = threading.Thread(target=self._lines, daemon=True)

    def __enter__(self) -> PlainProgress:
        if self.enabled:
            self._timer.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._done.set()

    def __call__(self, text: str) -> None:
        self.text = text

    def line(self) -> str:
        return f"{self.what}: {time.monotonic() - self.t0:.0f} s, {self.text}"

    def _lines(self) -> None:
        while not self._done.wait(self.every_s):
            sys.stderr.write(self.line() + "\n")
            sys.stderr.flush()


class StatusLine:
    """A job's latest step on stderr: a transient rich status line on a terminal (with the elapsed
    time when ``timed``), else `PlainProgress` lines. Call it with the latest text."""

    def __init__(self, console, what: str, first: str, timed: bool = False):
        self.console = console
        self.timed = timed
        self.plain = PlainProgress(what, enabled=not console.is_terminal)
        self.plain(first)
        self.status = None

    def _shown(self) -> str:
        return self.plain.line() if self.timed else self.plain.text

    def __enter__(self) -> StatusLine:
        if self.console.is_terminal:
            self.status = self.console.status(self._shown())
            self.status.__enter__()
        self.plain.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        self.plain.__exit__(*exc)
        if self.status is not None:
            self.status.__exit__(*exc)

    def __call__(self, text: str) -> None:
        self.plain(text)
        if self.status is not None:
            self.status.update(self._shown())
