"""What every trainer shares around its loop (TAC's ``tacbench.training``, the baselines'
``baselines.trainer``) and the sweep driver: planning a call's run directories, the stop
signals, and how each run ended."""

from __future__ import annotations

import shutil
import signal
import threading
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, TypeVar

from tacbench import runs
from tacbench.config import RESULT_NEUTRAL_FIELDS

StopCheck = Callable[[int], bool]  # polled with the step count; True: checkpoint and stop


@dataclass(frozen=True)
class Outcome:
    """How one run ended in this call."""

    seed: int
    directory: Path
    state: str  # "complete", "failed", "interrupted" or "skipped"
    step: int
    message: str = ""


class RunSpec(Protocol):
    """What planning needs of a run's config (``RunConfig``, ``BaselineConfig``)."""

    @property
    def algo(self) -> str: ...
    @property
    def env(self) -> str: ...
    @property
    def variant(self) -> str: ...
    @property
    def seed(self) -> int: ...
    def to_dict(self) -> Mapping[str, Any]: ...


Spec = TypeVar("Spec", bound=RunSpec)


def plan_runs(
    configs: Sequence[Spec], out: Path, *, resume: bool, force: bool
) -> tuple[list[Outcome], list[tuple[Spec, Path]]]:
    """Plan each config's run directory under ``out`` (:func:`tacbench.runs.plan_run`: start,
    resume, skip or refuse with a clear error) before anything is trained. Returns the skipped
    runs' outcomes and the runs to train with their directories; a directory that starts afresh
    (``force``, or nothing worth resuming in it) is emptied here."""
    skipped, active = [], []
    for config in configs:
        directory = runs.run_directory(out, config.algo, config.env, config.variant, config.seed)
        plan = runs.plan_run(
            directory, config.to_dict(), resume=resume, force=force, neutral=RESULT_NEUTRAL_FIELDS
        )
        if plan.action == "skip":
            skipped.append(Outcome(config.seed, directory, "skipped", -1, plan.message))
            continue
        if plan.action == "start" and directory.exists():
            shutil.rmtree(directory)
        active.append((config, directory))
    return skipped, active


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
