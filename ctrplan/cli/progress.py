"""Progress of long jobs when nobody watches a terminal: a plain line on stderr about every
`PROGRESS_EVERY_S` seconds (a log, a pipe, CI). On a terminal the commands draw rich bars instead."""

from __future__ import annotations

import sys
import threading
import time

from rich.progress import Progress

#: Seconds between plain progress lines when stderr is not a terminal.
PROGRESS_EVERY_S = 10.0


class PlainProgress:
    """``what: <elapsed> s, <latest text>`` on stderr about every ``every_s`` seconds while the block
    runs: from the caller when it reports after a quiet ``every_s``, and (``thread``) from a timer
    thread, so that one long compiled call does not silence it; silent when ``enabled`` is False
    (stderr is a terminal and a rich bar shows the progress). Call it with the latest text. Without
    ``thread`` only the caller writes (a benchmark's timed calls share no core with a thread)."""

    def __init__(self, what: str, enabled: bool | None = None, every_s: float | None = None,
                 thread: bool = True):
        self.what = what
        self.enabled = (not sys.stderr.isatty()) if enabled is None else enabled
        self.every_s = PROGRESS_EVERY_S if every_s is None else every_s
        self.text = "starting"
        self.t0 = time.monotonic()
        self._last = self.t0  # when the last line was written
        self._lock = threading.Lock()
        self._done = threading.Event()
        self._timer = threading.Thread(target=self._lines, daemon=True) if thread else None

    def __enter__(self) -> PlainProgress:
        if self.enabled and self._timer is not None:
            self._timer.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._done.set()

    def __call__(self, text: str) -> None:
        self.text = text
        if self.enabled and not self._done.is_set():
            self._write_if_due()

    def line(self) -> str:
        return f"{self.what}: {time.monotonic() - self.t0:.0f} s, {self.text}"

    def _write_if_due(self) -> None:
        with self._lock:
            now = time.monotonic()
            if now - self._last >= self.every_s:
                self._last = now
                sys.stderr.write(self.line() + "\n")
                sys.stderr.flush()

    def _lines(self) -> None:
        while not self._done.wait(self.every_s):
            self._write_if_due()


class CountProgress(Progress):
    """A rich bar of counted work on stderr on a terminal (refreshed only when the caller refreshes
    it: no thread shares a pinned core with timed calls), else `PlainProgress` lines naming the first
    task's description and count. ``thread``: see `PlainProgress`."""

    def __init__(self, console, what: str, columns: tuple, thread: bool = True):
        super().__init__(*columns, console=console, auto_refresh=False, disable=not console.is_terminal)
        self.plain = PlainProgress(what, enabled=not console.is_terminal, thread=thread)

    def __enter__(self) -> CountProgress:
        super().__enter__()
        self.plain.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        self.plain.__exit__(*exc)
        super().__exit__(*exc)

    def advance(self, task_id, advance: float = 1) -> None:
        super().advance(task_id, advance)
        self._report(task_id)

    def update(self, task_id, **fields) -> None:
        super().update(task_id, **fields)
        self._report(task_id)

    def _report(self, task_id) -> None:
        if self.plain.enabled:
            task = self._tasks[task_id]
            named = "" if task.description == self.plain.what else f"{task.description}: "
            self.plain(f"{named}{task.completed:,.0f} of {task.total:,.0f}")


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
