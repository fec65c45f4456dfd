"""BLAS threading for small matrix products: a surrogate's single queries and planner edges lose far
more to BLAS thread synchronisation than they gain, so its calls run BLAS on one thread.

`one_blas_thread` is the guard around each such call: it sets the BLAS libraries found at import to
one thread and back (``threadpool_limits`` costs ~40 us a call, a sixth of a query), unless a
`single_threaded_blas` scope already did for everything inside it -- a planner's search, which makes
tens of thousands of such calls, enters one once, and its calls then skip even the ~5 us of asking the
libraries how many threads they use.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from threadpoolctl import ThreadpoolController

_LIBS = ThreadpoolController().select(user_api="blas").lib_controllers
_scopes = 0  # nesting depth of `single_threaded_blas`


def _set_one_thread() -> list:
    """Set every BLAS library not on one thread to one; return (library, previous count) pairs."""
    changed = [(lib, n) for lib in _LIBS if (n := lib.num_threads) != 1]
    for lib, _ in changed:
        lib.set_num_threads(1)
    return changed


def _restore(changed: list) -> None:
    for lib, n in changed:
        lib.set_num_threads(n)


class _OneThread:
    """Context manager: BLAS on one thread for the enclosed calls only (see the module docstring)."""

    __slots__ = ("_changed",)

    def __enter__(self) -> None:
        self._changed = [] if _scopes else _set_one_thread()

    def __exit__(self, *exc) -> None:
        _restore(self._changed)


def one_blas_thread() -> _OneThread:
    """``with one_blas_thread(): ...`` runs the block with BLAS on one thread."""
    return _OneThread()


@contextmanager
def single_threaded_blas() -> Iterator[None]:
    """BLAS on one thread for everything inside; `one_blas_thread` guards inside are then free."""
    global _scopes
    changed = _set_one_thread()
    _scopes += 1
    try:
        yield
    finally:
        _scopes -= 1
        _restore(changed)
