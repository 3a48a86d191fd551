"""What a sweep keeps in ``<out>/sweep/``: the failure history, a lock, the summary, worker logs.

::

    <out>/sweep/
      state.json     {"runs": {"<run key>": {"failures": [{"time", "host", "step", "reason"}],
                                             "node": "<Ray node id holding its checkpoint>"}}}
      lock           held (flock) while a sweep writes to <out>; {"pid", "host", "started"}
      summary.json   the last sweep's counts by state, its failures with their reasons and its
                     bill (a sweep that trains nothing keeps the one before: its bill stays)
      summary.txt    the same, as printed at the end of the sweep
      logs/<unit>.log  each unit's output (progress lines, warnings, tracebacks), appended

Every JSON file is written atomically (:func:`tacbench.runs.atomic_write_json`).
"""

from __future__ import annotations

import json
import os
import socket
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tacbench import runs
from tacbench.errors import TacbenchError
from tacbench.runs import locks


def sweep_dir(out: Path) -> Path:
    """``<out>/sweep``."""
    return Path(out) / "sweep"


def log_path(out: Path, unit_key: str) -> Path:
    """``<out>/sweep/logs/<unit key with / as __>.log``."""
    return sweep_dir(out) / "logs" / (unit_key.removeprefix("runs/").replace("/", "__") + ".log")


def prepare_sweep_folder(out: Path) -> None:
    """Create ``<out>/sweep/logs`` before any unit starts; a TacbenchError if it cannot be (a file
    in its place), which would otherwise fail every unit, and give up every run, one by one, or
    if a folder stands where the summary goes (a traceback once every run had trained)."""
    logs = sweep_dir(out) / "logs"
    try:
        logs.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise TacbenchError(
            f"cannot create the sweep's log folder {logs}: a file stands in its place; nothing "
            "was trained. Move it away, then rerun the same command."
        ) from None
    for name in ("summary.json", "summary.txt"):
        if (sweep_dir(out) / name).is_dir():
            raise TacbenchError(
                f"{sweep_dir(out) / name} is a folder, where the sweep writes its summary; "
                "nothing was trained. Move it away, then rerun the same command."
            )


@dataclass(frozen=True)
class Failure:
    """One failed attempt of a run: when, where, at which step and why; ``refused``: its files
    could not resume, so nothing trained (not counted towards ``--max-retries``)."""

    time: str
    host: str
    step: int
    reason: str
    refused: bool = False


class SweepState:
    """The failure history of every run (``state.json``), read at start, saved on each change."""

    def __init__(self, out: Path) -> None:
        self.path = sweep_dir(out) / "state.json"
        advice = "restore it, or delete it (the sweep's failure history is then lost)"
        data = runs.read_json(self.path, advice) if self.path.exists() else {}
        self.runs: dict[str, dict[str, Any]] = data.get("runs", {})
        if not _well_formed(self.runs):
            raise TacbenchError(f"{self.path} is not a sweep's failure history; {advice}.")

    def failures(self, key: str) -> list[Failure]:
        """Every recorded failure of the run ``key``, oldest first."""
        return [Failure(**f) for f in self.runs.get(key, {}).get("failures", [])]

    def failure_counts(self) -> dict[str, int]:
        """How many failures each run has had that count towards ``--max-retries``."""
        return {key: self.attempts_failed(key) for key in self.runs}

    def attempts_failed(self, key: str) -> int:
        """How many of the run's attempts failed, refusals of its files left out: fixing them
        is what a refused run needs, not more retries."""
        return sum(not f.refused for f in self.failures(key))

    def add_failure(
        self, key: str, step: int, reason: str, host: str = "", *, refused: bool = False
    ) -> None:
        """Record a failed attempt (``refused``: its files could not resume) and save."""
        self._append(key, step, reason, host or socket.gethostname(), refused)
        self.save()

    def note_failed_status(self, key: str, step: int, reason: str) -> None:
        """Record (without saving) a failure read from a run's status.json unless one recorded
        already says it (the same step and reason): a run that failed outside a sweep, or before
        the sweep recorded it. Not only the last: a retry whose worker died before it reset
        status.json leaves the earlier failure there, behind the worker's own."""
        if all((f.step, f.reason) != (step, reason) for f in self.failures(key)):
            self._append(key, step, reason, "(from status.json)")

    def _append(self, key: str, step: int, reason: str, host: str, refused: bool = False) -> None:
        failure = Failure(runs.now_iso(), host, step, reason, refused)
        self.runs.setdefault(key, {}).setdefault("failures", []).append(vars(failure))

    def node(self, key: str) -> str | None:
        """The Ray node that holds the run's checkpoint, if known."""
        value = self.runs.get(key, {}).get("node")
        return str(value) if value else None

    def set_node(self, keys: Sequence[str], node: str) -> None:
        """Remember the Ray node holding these runs' checkpoints and save."""
        for key in keys:
            self.runs.setdefault(key, {})["node"] = node
        self.save()

    def save(self) -> None:
        """Write state.json."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        runs.atomic_write_json(self.path, {"runs": self.runs})


def _well_formed(entries: Any) -> bool:
    """Whether ``entries`` is state.json's ``runs``: by run key, failures like :class:`Failure`
    (``refused`` absent from those recorded before it was) and, optionally, a node."""
    fields = set(Failure.__dataclass_fields__)
    return isinstance(entries, dict) and all(
        isinstance(entry, dict)
        and isinstance(entry.get("failures", []), list)
        and all(
            isinstance(f, dict) and set(f) in (fields, fields - {"refused"})
            for f in entry.get("failures", [])
        )
        for entry in entries.values()
    )


class Lock:
    """``<out>/sweep/lock``: one sweep at a time per ``--out``, an exclusive ``flock`` held for
    the sweep's lifetime, as a run directory's (:mod:`tacbench.runs.locks`). The kernel
    releases it however the sweep ends (kill -9, a power cut), so no stale lock survives and
    none is ever taken over; the file records the holder's pid, host and start, for the error
    a second sweep gets, and is never deleted (see :mod:`tacbench.runs.locks` for why)."""

    def __init__(self, out: Path) -> None:
        self.out = Path(out)
        self.path = sweep_dir(out) / "lock"
        self._descriptor: int | None = None

    def __enter__(self) -> Lock:
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except (FileExistsError, NotADirectoryError):
            raise TacbenchError(
                f"cannot create {self.path.parent}: a file stands where the sweep's folder goes; "
                "nothing was changed. Move it away, or write somewhere else with --out."
            ) from None
        me = {"pid": os.getpid(), "host": socket.gethostname(), "started": runs.now_iso()}
        try:
            self._descriptor = locks.hold(self.path, json.dumps(me))
        except locks.Held as held:
            raise TacbenchError(
                f"another sweep ({_holder(held.recorded)}) is writing to {self.out}; wait for "
                "it to end, or stop it (Ctrl-C) first."
            ) from None
        return self

    def __exit__(self, *exc: object) -> None:
        if self._descriptor is not None:
            os.close(self._descriptor)  # releases the lock
            self._descriptor = None


def _holder(recorded: str) -> str:
    """Who holds the lock, as its file records it (nothing yet, while the holder writes it)."""
    try:
        holder = json.loads(recorded)
        return f"pid {holder['pid']} on {holder['host']}, started {holder['started']}"
    except (ValueError, TypeError, KeyError):
        return "holder not recorded yet"
