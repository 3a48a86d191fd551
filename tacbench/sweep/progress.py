"""One progress display for a whole sweep: runs done of total, environment steps done of total,
steps per second and the ETA of the steps left; a rich bar on a terminal, plain lines (every
``every_s`` seconds and whenever a run ends) otherwise."""

from __future__ import annotations

import math
import sys
import time
from typing import IO, Any


class SweepProgress:
    """Counts steps over every run of the sweep; the ETA divides the steps left by the rate
    measured since the sweep started (steps trained in this session per second)."""

    def __init__(
        self,
        runs_total: int,
        steps_total: int,
        steps_done: int,
        stream: IO[str] | None = None,
        every_s: float = 60.0,
    ) -> None:
        self.runs_total, self.steps_total = runs_total, steps_total
        self.stream = stream if stream is not None else sys.stderr
        self.every_s = every_s
        self._start_steps, self._steps, self._runs = steps_done, steps_done, 0
        self._t0 = self._last_line = time.monotonic()
        self._bar: Any = None
        if self.stream.isatty():
            from rich.console import Console
            from rich.progress import BarColumn, Progress, TextColumn

            self._bar = Progress(
                TextColumn("sweep"),
                BarColumn(),
                TextColumn("{task.fields[text]}"),
                console=Console(file=self.stream),
            )
            self._task = self._bar.add_task("sweep", total=steps_total, text="")
            self._bar.start()

    def line(self) -> str:
        """``runs 3/8 | steps 2,000/8,000 | 350 steps/s | ETA 0m17s``."""
        elapsed = time.monotonic() - self._t0
        rate = (self._steps - self._start_steps) / elapsed if elapsed > 0 else 0.0
        eta = (self.steps_total - self._steps) / rate if rate > 0 else math.inf
        return (
            f"runs {self._runs}/{self.runs_total} | steps {self._steps:,}/{self.steps_total:,} | "
            f"{rate:,.0f} steps/s | ETA {duration(eta)}"
        )

    def update(self, runs_done: int, steps_done: int) -> None:
        """Record the sweep's state; redraw the bar, or print a line when one is due."""
        ended = runs_done != self._runs
        self._runs, self._steps = runs_done, steps_done
        if self._bar is not None:
            self._bar.update(self._task, completed=steps_done, text=self.line())
        elif ended or time.monotonic() - self._last_line >= self.every_s:
            self.message(f"sweep: {self.line()}")
            self._last_line = time.monotonic()

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
