"""Ctrl-C, SIGTERM and SIGHUP as a request to stop cleanly: every trainer and the sweep driver
poll :func:`stop_signals`' record instead of dying mid-step, then checkpoint and stop. A second
signal stops at once (:class:`SecondSignal`). Either way the command exits with 128 + the
signal's number (130 Ctrl-C, 143 SIGTERM, 129 SIGHUP: :func:`exit_status`) and the runs it
stopped record the state ``interrupted``; docs/results-schema.md tabulates the exit statuses."""

from __future__ import annotations

import shlex
import signal
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

StopCheck = Callable[[int], bool]  # polled with the step count; True: checkpoint and stop

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
# A signal that comes again this soon after the first is the same request: timeout(1), and a
# signal sent to a process group, can deliver one signal to the process twice (to it and to
# its group), microseconds apart; counted twice, it would stop at once, without a checkpoint.
# A person's second Ctrl-C comes later.
SAME_REQUEST_S = 0.5
# the stop signals received since the outermost stop_signals() began, in order, and its depth
_received: list[int] = []
_depth = [0]


class SecondSignal(KeyboardInterrupt):
    """A second stop signal: stop at once, without a checkpoint. ``resume`` is the command
    that continues the stopped runs, where the trainer knows it."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum
        self.resume = ""

    @property
    def exit_status(self) -> int:
        """128 + the signal's number."""
        return 128 + self.signum


def received_signals() -> tuple[int, ...]:
    """The stop signals received since the outermost :func:`stop_signals` began, in order."""
    return tuple(_received)


def exit_status() -> int:
    """The exit status of a command that a stop signal interrupted: 128 + the number of the
    first signal received by the last :func:`stop_signals` (130 when none was: a stop asked for
    otherwise)."""
    return 128 + (_received[0] if _received else signal.SIGINT)


def resume_command(command: str, out: Path | None = None) -> str:
    """``command`` with ``--resume`` in place of any ``--force`` (which would delete what the
    resume continues, and which ``--resume`` refuses beside it), and with ``--out`` the folder
    ``out`` where given (the results were moved or copied since; added where the command wrote
    to the default folder); the library call's
    equivalent when there is no command; a sweep's command as it is: a sweep resumes by being
    run again, and has no ``--resume``."""
    if not command:
        return "train(..., resume=True)"
    words = shlex.split(command)
    if words[:2] == ["tacbench", "sweep"]:
        return command
    if out is not None and "--out" in words[:-1]:
        words[words.index("--out") + 1] = str(out)
    elif out is not None:
        words += ["--out", str(out)]
    return shlex.join([*(w for w in words if w not in ("--force", "--resume")), "--resume"])


@contextmanager
def stop_signals(*, second_interrupts: bool = True) -> Iterator[dict[str, int]]:
    """Record SIGINT, SIGTERM and SIGHUP while active instead of dying: the dict counts them
    (``count``) and keeps the last one (``signal``), so a loop can checkpoint and stop. With
    ``second_interrupts`` a second signal raises :class:`SecondSignal` at once (no checkpoint);
    the first signal again within :data:`SAME_REQUEST_S` is not a second one. SIGHUP stays
    ignored where it was (``nohup``). The previous handlers come back afterwards. No-op outside
    the main thread."""
    received: dict[str, int] = {}
    if threading.current_thread() is not threading.main_thread():
        yield received
        return
    first_at = [0.0]  # when the first signal came

    def handler(signum: int, _frame: Any) -> None:
        now = time.monotonic()
        if not received:
            first_at[0] = now
        elif received["signal"] == signum and now - first_at[0] < SAME_REQUEST_S:
            return  # the first one delivered again (timeout(1), a process group's signal)
        _received.append(signum)
        if received and second_interrupts:
            raise SecondSignal(signum)
        received["count"] = received.get("count", 0) + 1
        received["signal"] = signum

    if not _depth[0]:
        _received.clear()
    _depth[0] += 1
    # a hangup this process was told to ignore (nohup) stays ignored: the session may go away
    caught = [
        sig
        for sig in STOP_SIGNALS
        if not (sig == signal.SIGHUP and signal.getsignal(sig) == signal.SIG_IGN)
    ]
    previous = {sig: signal.signal(sig, handler) for sig in caught}
    try:
        yield received
    finally:
        _depth[0] -= 1
        for sig, old in previous.items():
            signal.signal(sig, old)
