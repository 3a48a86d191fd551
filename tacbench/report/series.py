"""One run's returns from its metric CSV: only whole, consistent rows, and a complete run's rows
only when they reach its end (a file cut short would give an early return as its final one)."""

from __future__ import annotations

import io
import math
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pandas as pd

Metric = Literal["eval", "train"]

METRIC_SOURCES: dict[str, tuple[str, str]] = {
    "eval": ("eval.csv", "return_mean"),
    "train": ("train.csv", "return"),
}
"""Per metric: the CSV it is read from and the column that becomes ``return``."""


class Unreadable(Exception):
    """A run directory that cannot be used; the message is the reason shown to the user."""

    def __init__(self, reason: str, identity: dict[str, Any] | None = None) -> None:
        super().__init__(reason)
        self.identity = identity


@dataclass(frozen=True)
class Series:
    """A run's logged returns in order (``step``, ``value``, ``wall_s``), a note on what was
    left out ("" if nothing), and how many rows had a non-finite step or return (``dropped``)."""

    step: np.ndarray
    value: np.ndarray
    wall_s: np.ndarray
    note: str = ""
    dropped: int = 0


def _check_numbers(fields: list[str], filename: str, line: int) -> None:
    for field in fields:
        try:
            float(field)
        except ValueError:
            raise Unreadable(
                f"{filename} line {line} is not numbers: {','.join(fields)!r}"
            ) from None


def read_series(run_dir: Path, metric: Metric, state: str, end: float, env: str) -> Series:
    """The whole rows of ``run_dir``'s ``metric`` CSV in logged order, rows with a non-finite
    step or return left out (and counted, with a note). A run whose rows are not whole numbers
    of the header's width with steps rising throughout is unreadable (the reason says which
    line); a torn last line, which a writer leaves while it appends, is dropped (and noted) only
    while the run is still ``running``. A ``complete`` run's rows must reach ``end``, the step
    its status.json records (:func:`check_rows_reach_the_end`)."""
    filename, column = METRIC_SOURCES[metric]
    path = run_dir / filename
    if not path.exists():
        raise Unreadable(f"{filename} missing")
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as err:
        raise Unreadable(f"{filename} unreadable: {err}") from None
    if not text.strip():
        raise Unreadable(f"{filename} is empty")
    header, *lines = text.split("\n")
    names = header.split(",")
    missing = [name for name in ("step", "wall_s", column) if name not in names]
    if missing:
        raise Unreadable(f"{filename} unreadable: no column {', '.join(missing)}")
    torn = lines.pop() if lines else ""  # "" when the file ends with a newline
    if torn and state != "running":
        raise Unreadable(
            f"{filename} ends in a torn line {torn!r} (a writer was cut off); "
            "`tacbench run ... --resume` repairs an interrupted run"
        )
    for number, line in enumerate(lines, start=2):
        fields = line.split(",")
        if len(fields) != len(names):
            raise Unreadable(f"{filename} line {number} has {len(fields)} fields, not {len(names)}")
        _check_numbers(fields, filename, number)
    if not lines:
        raise Unreadable(
            f"{filename} has no rows (the run made no evaluation: --eval-every 0? report "
            "--metric train)"
            if state == "complete" and metric == "eval"
            else f"{filename} has no rows yet"
        )
    # the checked lines, parsed by pandas as the published reports were (its fast parser can
    # differ from Python's float in the last bit)
    whole = io.StringIO("\n".join([header, *lines]))
    frame = pd.read_csv(whole, usecols=["step", "wall_s", column])
    values = frame[["step", column, "wall_s"]].to_numpy(dtype=np.float64)
    falling = np.flatnonzero(np.diff(values[:, 0]) <= 0)
    if len(falling):
        at = falling[0] + 1
        raise Unreadable(
            f"{filename} line {at + 2}: step {values[at, 0]:g} does not follow step "
            f"{values[at - 1, 0]:g} (a repeated or out-of-order row)"
        )
    logged = values[np.isfinite(values[:, 0]), 0]
    if state == "complete" and len(logged):
        check_rows_reach_the_end(logged, end, metric, env)
    finite = np.isfinite(values[:, 0]) & np.isfinite(values[:, 1])
    kept = values[finite]
    if len(kept) == 0:
        raise Unreadable(f"{filename} has no finite rows")
    notes = [f"{filename}: its torn last line, still being written, left out"] if torn else []
    dropped = int((~finite).sum())
    if dropped:
        last = values[~finite, 0][-1]
        at = f", the last at step {last:,.0f}" if np.isfinite(last) else ""
        notes.append(
            f"{filename}: {dropped} row{'s' if dropped > 1 else ''} with a non-finite step or "
            f"return left out{at}"
        )
    return Series(kept[:, 0], kept[:, 1], kept[:, 2], "; ".join(notes), dropped)


def check_rows_reach_the_end(steps: np.ndarray, end: float, metric: Metric, env: str) -> None:
    """A complete run's rows reach the ``end`` its status.json records: evaluations to within
    one interval (the widest gap between them, or the first one's step when there is one),
    training episodes to within twice the task's time limit (the last episode, unfinished at
    the end, is never logged, and no episode runs longer; a run resumed where the env's state is
    not saved drops one more unfinished episode). Rows that stop earlier were lost (a file cut
    short), and the run's final return would be an early one."""
    if math.isnan(end):
        return
    filename = METRIC_SOURCES[metric][0]
    if metric == "eval":
        within = float(np.diff(steps).max()) if len(steps) > 1 else float(steps[0])
        what = f"evaluates every {within:,.0f} at most"
    else:
        limit = episode_limit(env)
        if limit is None:  # a task without a known time limit: no bound on the last episode
            return
        within = 2.0 * limit
        what = f"its episodes last at most {limit:,} steps (the time limit; twice that allowed)"
    if end - steps[-1] > within:
        raise Unreadable(
            f"{filename} ends at step {steps[-1]:,.0f}, though the run completed {end:,.0f} "
            f"steps and {what}: its last rows were lost; restore the file"
        )


@cache
def episode_limit(env: str) -> int | None:
    """The time limit (``max_episode_steps``) gymnasium registers for ``env``; None for an
    unregistered task or one without a limit."""
    import gymnasium as gym

    try:
        limit = gym.spec(env).max_episode_steps
    except gym.error.Error:
        return None
    return int(limit) if limit else None
