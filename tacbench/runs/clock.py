"""A run's two clocks, summed over the sessions that trained it: wall seconds, which
``eval.csv`` and ``train.csv`` log as ``wall_s``, and the run's share of the CPU seconds of the
process that trains it (all its threads, split evenly between the runs it trains together while
they train), which ``eval.csv`` logs as ``cpu_s``. A checkpoint keeps both, so a resumed run's
clocks go on where they stopped, in a group of any size.

Other work on the machine stretches the wall clock by about the share of the cores it takes; the
CPU clock much less (only through the caches and memory bandwidth it shares: docs/sweep.md), so
the dry run prices steps left from CPU seconds where a run records them
(:mod:`tacbench.sweep.cost`).
"""

from __future__ import annotations

from collections.abc import Mapping
from time import perf_counter, process_time
from typing import Any

CPU_CLOCK = "share"
"""config.json's ``cpu_clock`` in a run whose ``cpu_s`` is its share of its process's CPU seconds.
A run begun without it (on 7 December 2026, before members split them) logged the whole
process's; it goes on doing so, and a reader divides by the members config.json lists."""


def shares_cpu(metadata: Mapping[str, Any]) -> bool:
    """Whether the run of config.json's ``metadata`` logs its share of its process's CPU seconds
    (else the whole process's, which its members, as config.json lists them, shared)."""
    return metadata.get("cpu_clock") == CPU_CLOCK


def members_sharing(metadata: Mapping[str, Any]) -> int:
    """What divides the run's ``cpu_s`` into its own: 1, or its first group's members where it
    logged the whole process's (:func:`shares_cpu`)."""
    members = metadata.get("members")
    return 1 if shares_cpu(metadata) or not isinstance(members, list) else max(1, len(members))


class CpuShares:
    """The CPU seconds of this process since it was made, split evenly between the ``runs`` it
    trains while they train: a run that stops (a member whose loss is no longer finite) leaves
    the time after it to the others."""

    def __init__(self, runs: int) -> None:
        self._shares = [0.0] * runs
        self._training = set(range(runs))
        self._read = process_time()

    def share(self, run: int) -> float:
        """Run ``run``'s CPU seconds so far."""
        self._count()
        return self._shares[run]

    def stop(self, run: int) -> None:
        """Run ``run`` trains no more: it takes no share of what the process spends from now."""
        self._count()
        self._training.discard(run)

    def _count(self) -> None:
        now = process_time()
        if self._training:
            each = (now - self._read) / len(self._training)
            for run in self._training:
                self._shares[run] += each
        self._read = now


class RunClock:
    """Seconds since the clock was made, plus the ``wall_s`` and ``cpu_s`` that earlier sessions
    took (a checkpoint's); the CPU seconds are run ``run``'s of ``shares`` (by default a process
    of its own). A checkpoint from before tacbench kept CPU time gives ``cpu_s`` 0: its run's
    ``eval.csv`` has no ``cpu_s`` column, so that count is never written."""

    def __init__(
        self, wall_s: float = 0.0, cpu_s: float = 0.0, shares: CpuShares | None = None, run: int = 0
    ) -> None:
        self._wall_offset, self._cpu_offset = wall_s, cpu_s
        self._shares, self._run = shares or CpuShares(1), run
        self._wall_0 = perf_counter()

    @property
    def wall_s(self) -> float:
        """Wall seconds of training so far."""
        return self._wall_offset + perf_counter() - self._wall_0

    @property
    def cpu_s(self) -> float:
        """This run's CPU seconds of training so far."""
        return self._cpu_offset + self._shares.share(self._run)
