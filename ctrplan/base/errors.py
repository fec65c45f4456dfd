"""Error types shared across ctrplan.

`InputError` is raised for anything the *user* got wrong (files, values, domains). The CLI turns it
into one line on stderr and exit code 2; library callers can catch it like any ``ValueError``.
"""

from __future__ import annotations


class InputError(ValueError):
    """Bad user input. The message names what is wrong and where (file, row, field)."""


class DomainError(InputError):
    """A joint configuration lies outside the allowed (snap-free) domain."""
