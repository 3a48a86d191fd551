"""One progress display for a whole sweep: runs done of total, environment steps done of total,
steps per second and the ETA of the steps left; a rich bar on a terminal, plain lines (every
``every_s`` seconds and whenever a run ends) otherwise."""

from __future__ import annotations

import math
import time
from typing import IO

from tacbench.progress import Display, duration


class SweepProgress(Display):
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
        super().__init__(stream)
        self.runs_total, self.steps_total = runs_total, steps_total
        self.every_s = every_s
        self._start_steps, self._steps, self._runs = steps_done, steps_done, 0
        self._t0 = self._last_line = time.monotonic()
        if self.stream.isatty():
            from rich.progress import BarColumn, TextColumn

            bar = self._start_bar(
                TextColumn("sweep"), BarColumn(), TextColumn("{task.fields[text]}")
            )
            self._task = bar.add_task("sweep", total=steps_total, text="")

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
