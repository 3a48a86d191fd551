"""One progress display for a whole sweep: runs done of total, environment steps done of total,
steps per second and the ETA of the steps left; a rich bar on a terminal, plain lines (every
``every_s`` seconds and whenever a run ends) otherwise."""

from __future__ import annotations

import math
import time
from collections.abc import Collection, Mapping
from typing import IO

from tacbench.progress import Display, duration


class SweepProgress(Display):
    """Counts steps over every run of the sweep (a run that ended, complete or given up, counts
    whole), and among them the learning steps (those after each run's random warm-up).

    The ETA divides the learning steps left to the runs that have not ended by the rate of the
    learning steps taken in this session, timed from the last update before the first of them:
    the warm-up's random steps are many times faster, so a rate of all steps would promise a
    fraction of the time early in a sweep. Until a learning step is taken the ETA is unknown
    (``- (warm-up)``). The warm-ups of the units that start later fall inside the measured time,
    as they will in the time left. Where no learning steps are left (every run left is random
    throughout), the ETA divides by the rate of all steps."""

    def __init__(
        self,
        budgets: Mapping[str, tuple[int, int]],
        steps: Mapping[str, int],
        ended: Collection[str],
        stream: IO[str] | None = None,
        every_s: float = 60.0,
    ) -> None:
        """``budgets``: each run's (steps, learning steps), by run key; ``steps``: the step
        each run has reached; ``ended``: the runs that will train no further."""
        super().__init__(stream)
        self.budgets, self.every_s = budgets, every_s
        self.runs_total = len(budgets)
        self.steps_total = sum(total for total, _ in budgets.values())
        self._runs = len(ended)
        self._steps, self._learning, self._learning_left = self._count(steps, ended)
        self._t0 = self._last_line = time.monotonic()
        # steps/s counts the steps trained, not a run's whole credited when it is given up
        self._trained = self._start_trained = sum(steps.values())
        # (time, learning steps) of the last update before this session's first learning step
        self._learning_origin = (self._t0, self._learning)
        if self.stream.isatty():
            from rich.progress import BarColumn, TextColumn

            bar = self._start_bar(
                TextColumn("sweep"), BarColumn(), TextColumn("{task.fields[text]}")
            )
            self._task = bar.add_task("sweep", total=self.steps_total, text="")

    def _count(self, steps: Mapping[str, int], ended: Collection[str]) -> tuple[int, int, int]:
        """Steps taken (an ended run's whole), learning steps taken and learning steps left
        (those of the runs that have not ended)."""
        done = learning = left = 0
        for key, (total, learning_total) in self.budgets.items():
            step = steps[key]
            done += total if key in ended else step
            taken = max(0, step - (total - learning_total))  # after the warm-up
            learning += taken
            left += 0 if key in ended else learning_total - taken
        return done, learning, left

    def _eta(self, now: float, rate: float) -> str:
        """The ETA at ``now``; ``rate``: of all steps trained since the start, per second."""
        if self._learning_left == 0:  # every run left is random throughout
            return duration((self.steps_total - self._steps) / rate if rate > 0 else math.inf)
        t_origin, learning_origin = self._learning_origin
        if self._learning == learning_origin or now <= t_origin:
            return "- (warm-up)" if self._trained > self._start_trained else "-"
        rate = (self._learning - learning_origin) / (now - t_origin)
        return duration(self._learning_left / rate)

    def line(self) -> str:
        """``runs 3/8 | steps 2,000/8,000 | 350 steps/s | ETA 0m17s``."""
        now = time.monotonic()
        elapsed = now - self._t0
        rate = (self._trained - self._start_trained) / elapsed if elapsed > 0 else 0.0
        return (
            f"runs {self._runs}/{self.runs_total} | steps {self._steps:,}/{self.steps_total:,} | "
            f"{rate:,.0f} steps/s | ETA {self._eta(now, rate)}"
        )

    def update(self, steps: Mapping[str, int], ended: Collection[str]) -> None:
        """Record the step each run has reached and the runs that ended; redraw the bar, or
        print a line when one is due."""
        self._steps, learning, self._learning_left = self._count(steps, ended)
        self._trained = sum(steps.values())
        if learning == self._learning_origin[1]:
            self._learning_origin = (time.monotonic(), learning)
        self._learning, previous_runs, self._runs = learning, self._runs, len(ended)
        if self._bar is not None:
            self._bar.update(self._task, completed=self._steps, text=self.line())
        elif self._runs != previous_runs or time.monotonic() - self._last_line >= self.every_s:
            self.message(f"sweep: {self.line()}")
            self._last_line = time.monotonic()
