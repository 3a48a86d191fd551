"""The one exception type for user mistakes.

Anything a user can fix (an unknown env, q <= 0, a run directory from another config) raises
:class:`TacbenchError` with a message that says what to do. The CLI prints the message without
a traceback and exits with status 2; library callers catch it like any exception.
"""

from collections.abc import Sequence


class TacbenchError(Exception):
    """A mistake the user can fix; the message says how."""


def listing(items: Sequence[str], shown: int = 5, sep: str = ", ") -> str:
    """The first ``shown`` of ``items`` for a message, and how many more: ``a, b and 3 more``."""
    more = f" and {len(items) - shown} more" if len(items) > shown else ""
    return sep.join(items[:shown]) + more


def plural(count: int, noun: str, nouns: str = "") -> str:
    """``1 run``, ``2 runs`` (``nouns``: the plural, where it is not ``noun`` + s)."""
    return f"{count} {noun if count == 1 else nouns or noun + 's'}"


def one_line(err: BaseException) -> str:
    """``err`` as one line for a message or a record: its type and its message's first line."""
    lines = str(err).strip().splitlines()
    return f"{type(err).__name__}: {lines[0] if lines else ''}"
