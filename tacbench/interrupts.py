"""Ctrl-C and SIGTERM as a request to stop cleanly: every trainer and the sweep driver poll
:func:`stop_signals`' record instead of dying mid-step, then checkpoint and stop."""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

StopCheck = Callable[[int], bool]  # polled with the step count; True: checkpoint and stop


@contextmanager
def stop_signals(*, second_interrupts: bool = True) -> Iterator[dict[str, int]]:
    """Record SIGINT and SIGTERM while active instead of dying: the dict counts them
    (``count``) and keeps the last one (``signal``), so a loop can checkpoint and stop. With
    ``second_interrupts`` a second signal raises KeyboardInterrupt at once (no checkpoint).
    The previous handlers come back afterwards. No-op outside the main thread."""
    received: dict[str, int] = {}
    if threading.current_thread() is not threading.main_thread():
        yield received
        return

    def handler(signum: int, _frame: Any) -> None:
        if received and second_interrupts:
            raise KeyboardInterrupt
        received["count"] = received.get("count", 0) + 1
        received["signal"] = signum

    previous = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield received
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)
