"""A run's two clocks, summed over the sessions that trained it: wall seconds, which
``eval.csv`` and ``train.csv`` log as ``wall_s``, and the CPU seconds of the process that trains
it (all its threads, shared by the members it trains together), which ``eval.csv`` logs as
``cpu_s``. A checkpoint keeps both, so a resumed run's clocks go on where they stopped.

Other work on the machine stretches the wall clock by about the share of the cores it takes; the
CPU clock much less (only through the caches and memory bandwidth it shares: docs/sweep.md), so
the dry run prices steps left from CPU seconds where a run records them
(:mod:`tacbench.sweep.cost`).
"""

from __future__ import annotations

from time import perf_counter, process_time


class RunClock:
    """Seconds since the clock was made, plus the ``wall_s`` and ``cpu_s`` that earlier sessions
    took (a checkpoint's). A checkpoint from before tacbench kept CPU time gives ``cpu_s`` 0: its
    run's ``eval.csv`` has no ``cpu_s`` column, so that count is never written."""

    def __init__(self, wall_s: float = 0.0, cpu_s: float = 0.0) -> None:
        self._wall_offset, self._cpu_offset = wall_s, cpu_s
        self._wall_0, self._cpu_0 = perf_counter(), process_time()

    @property
    def wall_s(self) -> float:
        """Wall seconds of training so far."""
        return self._wall_offset + perf_counter() - self._wall_0

    @property
    def cpu_s(self) -> float:
        """CPU seconds of training so far."""
        return self._cpu_offset + process_time() - self._cpu_0
