"""Progress displays: a rich bar on a terminal, plain lines otherwise.

:class:`Progress` follows one training process (``tacbench run``); the sweep's display
(``tacbench.sweep.progress.SweepProgress``) follows a whole grid. Both build on
:class:`Display`, which owns the stream, the bar and the lines printed above it.
"""

from __future__ import annotations

import math
import sys
import time
from collections import deque
from typing import IO, Any


class Display:
    """The part every display shares: where it writes, its rich bar (started by the subclass
    with :meth:`_start_bar` when the stream is a terminal), :meth:`message` and :meth:`close`."""

    def __init__(self, stream: IO[str] | None) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self._bar: Any = None

    def _start_bar(self, *columns: Any) -> Any:
        """Start a rich bar with these columns on the stream; returns it."""
        from rich.console import Console
        from rich.progress import Progress as RichProgress

        self._bar = RichProgress(*columns, console=Console(file=self.stream))
        self._bar.start()
        return self._bar

    def message(self, text: str) -> None:
        """Print a line (above the bar when there is one)."""
        if self._bar is not None:
            self._bar.console.print(text, highlight=False, markup=False)
        else:
            print(text, file=self.stream, flush=True)

    def close(self) -> None:
        """Stop the bar."""
        if self._bar is not None:
            self._bar.stop()


class Progress(Display):
    """A progress display for one training process: a rich bar (steps, steps/s, last evaluation
    return, ETA) on a terminal; plain lines at each evaluation, or every 5% without evaluation,
    when the output is not a terminal or ``quiet`` is set.

    The ETA divides the steps left by the rate of the learning steps only: the warm-up's random
    steps are many times faster, so until learning starts the ETA is unknown (``- (warm-up)``)
    rather than a tenth of the truth."""

    def __init__(
        self,
        label: str,
        total: int,
        start: int,
        every: int,
        quiet: bool,
        stream: IO[str] | None = None,
    ) -> None:
        super().__init__(stream)
        self.label, self.total, self.start_step = label, total, start
        # a line per evaluation, or every 5 % where none falls before the end (every 0 or over)
        self.every = every if 0 < every < total else max(1, total // 20)
        self.last_eval = "-"
        self._step = start
        if not quiet and self.stream.isatty():
            from rich.progress import BarColumn, MofNCompleteColumn, TextColumn

            bar = self._start_bar(
                TextColumn("{task.description}"),
                BarColumn(),
                MofNCompleteColumn(),
                TextColumn("{task.fields[rate]} steps/s"),
                TextColumn("eval {task.fields[last_eval]}"),
                TextColumn("ETA {task.fields[eta]}"),
            )
            self._task = bar.add_task(
                label, total=total, completed=start, rate="-", last_eval="-", eta="-"
            )
        # steps/s over the last ~2,000 steps (bar) or since the previous line (plain)
        window = 20 if self._bar is not None else 2
        self._window: deque[tuple[float, int]] = deque([(time.perf_counter(), start)], window)
        self._learning_since: tuple[float, int] | None = None  # (time, step) of the first report

    def _rate(self) -> float:
        self._window.append((time.perf_counter(), self._step))
        (t_first, s_first), (t_last, s_last) = self._window[0], self._window[-1]
        return (s_last - s_first) / (t_last - t_first) if t_last > t_first else 0.0

    def _eta(self) -> str:
        """The steps left over the rate of the window's learning steps (after :meth:`_rate`)."""
        if self._learning_since is None:
            return "- (warm-up)"
        (t_first, s_first), (t_last, s_last) = self._window[0], self._window[-1]
        if t_first < self._learning_since[0]:
            t_first, s_first = self._learning_since
        if s_last <= s_first or t_last <= t_first:
            return "-"
        return duration((self.total - s_last) * (t_last - t_first) / (s_last - s_first))

    def update(self, step: int, eval_return: float | None = None, learning: bool = True) -> None:
        """Record progress to ``step`` (cheap enough to call every step); ``learning``: whether
        the updates have begun (the steps before are the warm-up's)."""
        previous, self._step = self._step, step
        if learning and self._learning_since is None:
            self._learning_since = (time.perf_counter(), step)
        if eval_return is not None:
            self.last_eval = f"{eval_return:.1f}"
        if self._bar is not None:
            if eval_return is not None or step // 100 != previous // 100 or step == self.total:
                rate, eta = f"{self._rate():.0f}", self._eta()
                self._bar.update(
                    self._task, completed=step, rate=rate, last_eval=self.last_eval, eta=eta
                )
        elif step // self.every != previous // self.every or step == self.total:
            rate, eta = f"{self._rate():.0f}", self._eta()
            self.message(
                f"{self.label}: step {step}/{self.total} | {rate} steps/s | "
                f"eval {self.last_eval} | ETA {eta}"
            )


def duration(seconds: float) -> str:
    """``3d04h``, ``2h05m``, ``4m09s`` or ``-`` (unknown)."""
    if not math.isfinite(seconds):
        return "-"
    minutes, secs = divmod(int(seconds), 60)
    hours, minutes = divmod(minutes, 60)
    days, hours = divmod(hours, 24)
    if days:
        return f"{days}d{hours:02d}h"
    return f"{hours}h{minutes:02d}m" if hours else f"{minutes}m{secs:02d}s"
