"""The run directory's files: atomic JSON, row-by-row CSVs and the writer of one run
(:class:`RunWriter`: config.json, status.json, eval.csv, train.csv, losses.csv and TensorBoard
events).

JSON files are written durably (a temporary name, synced, renamed:
:func:`tacbench.runs.checkpoints.write_durably`). CSV rows are appended and flushed one at a
time; each checkpoint syncs every CSV to the device and records what it holds, and a resume
first checks every CSV against
it and cuts it back to it (:mod:`tacbench.runs.resume_checks`), so no row is ever duplicated or
missing, and a damaged CSV is refused before anything is written. docs/results-schema.md
describes every file, column and field.
"""

from __future__ import annotations

import contextlib
import csv
import hashlib
import io
import json
import math
import os
import tempfile
from collections.abc import Mapping, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any, Literal

from tacbench.errors import TacbenchError, one_line
from tacbench.runs.checkpoints import DISK_ERRNOS, recorded_logs, write_durably
from tacbench.runs.clock import shares_cpu
from tacbench.runs.resume_checks import (
    START_OVER,
    DamagedRun,
    LogDigest,
    ResumePlan,
    check_event_folder,
    check_log,
)
from tacbench.settings import REROUNDING_FIELDS

if TYPE_CHECKING:
    from tacbench.interrupts import SecondSignal
    from tacbench.runs.clock import RunClock
    from tacbench.runs.tensorboard import TensorBoardLog

EVAL_COLUMNS = ("step", "wall_s", "cpu_s", "return_mean", "return_std", "length_mean")
# eval.csv of a run begun before tacbench logged cpu_s: such a run resumes in its own columns
EVAL_COLUMNS_WITHOUT_CPU = tuple(c for c in EVAL_COLUMNS if c != "cpu_s")
TRAIN_COLUMNS = ("step", "wall_s", "return", "length")
State = Literal["running", "interrupted", "complete", "failed"]
# the start of the reason of a run that an unexpected error ended (RunWriter.crashed): unlike a
# diverged run's, its last checkpoint is worth resuming
CRASHED = "crashed"


def now_iso() -> str:
    """The current UTC time, ISO 8601 with seconds."""
    return datetime.now(UTC).isoformat(timespec="seconds")


def atomic_write_json(path: Path, data: Mapping[str, Any]) -> None:
    """Write ``data`` as JSON so that a reader sees the old file or the new one, never half."""
    payload = (json.dumps(data, indent=2, sort_keys=False) + "\n").encode()
    write_durably(path, lambda handle: handle.write(payload))


def ensure_writable(folder: Path) -> None:
    """Create ``folder`` (with its parents) and check that a file can be written in it, before
    anything is trained; else a TacbenchError that says what to do."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as err:
        raise _unwritable(folder, err, "--out") from None


def check_writable(folder: Path, flag: str = "--out") -> None:
    """:func:`ensure_writable` without creating anything: the nearest existing folder at or
    above ``folder`` must take a file (so that ``folder`` can be made there later), checked
    before minutes of work whose output would have nowhere to go."""
    existing = Path(os.path.abspath(folder))
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    try:  # TemporaryFile refuses a file as its folder (ENOTDIR), as mkdir below it would
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as err:
        raise _unwritable(folder, err, flag) from None


def _unwritable(folder: Path, err: OSError, flag: str) -> TacbenchError:
    reason = os.strerror(err.errno).lower() if err.errno else str(err)
    return TacbenchError(
        f"cannot create or write the output folder {folder} ({reason}); choose one you can "
        f"write with {flag}."
    )


RESTORE_OR_FORCE = f"restore it, or {START_OVER}"


def read_json(path: Path, advice: str = RESTORE_OR_FORCE) -> dict[str, Any]:
    """A JSON object from ``path``; a TacbenchError that ends with ``advice`` when the file is
    unreadable, not JSON (empty, torn, edited) or not an object."""
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        reason = os.strerror(err.errno).lower() if isinstance(err, OSError) and err.errno else ""
        what = reason or (
            "empty"
            if isinstance(err, json.JSONDecodeError) and not err.doc.strip()
            else "not valid JSON"
        )
        said = what if what.startswith("is ") else f"is {what}"  # strerror: "is a directory"
        raise TacbenchError(f"{path} {said}; {advice}.") from None
    if not isinstance(data, dict):
        raise TacbenchError(f"{path} is not a JSON object; {advice}.")
    return data


class CsvLog:
    """An append-only CSV: one row per :meth:`write`, flushed at once (floats at full precision),
    with a running count and SHA-256 of what it holds (:meth:`digest`, which a checkpoint
    records).

    ``kept`` reopens an existing file for resume with exactly those bytes (a checked prefix:
    :func:`tacbench.runs.resume_checks.check_log`), replacing the file atomically first if it
    holds more. Without it the file is started afresh with its header.
    """

    def __init__(self, path: Path, columns: Sequence[str], kept: bytes | None = None):
        self.path = Path(path)
        self.columns = tuple(columns)
        fresh = kept is None
        kept = (",".join(self.columns) + "\n").encode() if kept is None else kept
        if fresh or self.path.stat().st_size != len(kept):
            write_durably(self.path, lambda handle: handle.write(kept))
        self._sha = hashlib.sha256(kept)
        self._size = len(kept)
        self._rows = kept.count(b"\n") - 1
        self._handle: IO[bytes] = self.path.open("ab")

    def write(self, row: Sequence[Any]) -> None:
        """Append one row (same order as the columns) and flush it to the OS."""
        if len(row) != len(self.columns):
            raise ValueError(f"{self.path.name}: {len(row)} values for {len(self.columns)} columns")
        text = io.StringIO()
        csv.writer(text, lineterminator="\n").writerow(row)
        line = text.getvalue().encode()
        try:
            self._handle.write(line)
            self._handle.flush()
        except OSError as err:  # a full disk: name the file (a torn row is cut on resume)
            err.filename = err.filename or str(self.path)
            raise
        self._sha.update(line)
        self._size += len(line)
        self._rows += 1

    def digest(self) -> LogDigest:
        """What the file holds now, synced to the device first: a checkpoint's manifest records
        it, so its rows must survive whatever the manifest survives (a power loss after the
        manifest would otherwise leave rows it records missing, and the resume refused)."""
        os.fsync(self._handle.fileno())
        return LogDigest(self._rows, self._size, self._sha.hexdigest())

    def close(self) -> None:
        """Close the file."""
        self._handle.close()


def rounding_changes(stored: Mapping[str, Any], config: Mapping[str, Any]) -> list[str]:
    """A note for each field of :data:`REROUNDING_FIELDS` (where the networks run, and on how
    many threads) in which a resumed run's ``config`` differs from the ``stored`` one of its
    config.json: it may, so that a run can resume on other hardware, but its numbers from there
    on round as on that hardware, and config.json keeps the first value."""
    return [
        f"{name} {stored.get(name)!r} -> {config.get(name)!r} (config.json keeps "
        f"{stored.get(name)!r}; from here the numbers round as with {config.get(name)!r})"
        for name in REROUNDING_FIELDS
        if name in config and stored.get(name) != config[name]
    ]


def group_changes(recorded: Any, members: Sequence[Mapping[str, Any]]) -> list[str]:
    """A note when a run resumes in another group than config.json records (``recorded``) it
    trained in: a member failed, or the command adds or leaves some out. The maths per member
    is the same, but the members' products are batched together, so from here on the numbers
    round otherwise than in an uninterrupted run. (The note is the same for every member of
    the group, which shares it.)"""
    if not members or not isinstance(recorded, list):
        return []
    if all(isinstance(m, Mapping) for m in recorded):
        key = lambda m: json.dumps([m.get("q"), m.get("alpha"), m.get("seed")])  # noqa: E731
        before, now = sorted(map(key, recorded)), sorted(map(key, members))
    else:  # an older config.json lists the members' seeds alone
        before, now = sorted(map(str, recorded)), sorted(str(m.get("seed")) for m in members)
    if before == now:
        return []
    return [
        "the members resume in another group than they trained in (config.json lists each "
        "one's: a member failed, or this command adds or leaves some out): the same maths, but "
        "from here the numbers round otherwise than in an uninterrupted run"
    ]


def _eval_columns(path: Path) -> tuple[str, ...]:
    """The columns ``eval.csv`` at ``path`` continues in: :data:`EVAL_COLUMNS_WITHOUT_CPU` if it
    begins with their header (an older run), else :data:`EVAL_COLUMNS`."""
    older = (",".join(EVAL_COLUMNS_WITHOUT_CPU) + "\n").encode()
    try:
        with path.open("rb") as handle:
            return EVAL_COLUMNS_WITHOUT_CPU if handle.readline() == older else EVAL_COLUMNS
    except OSError:  # missing or unreadable: the resume check says what is wrong
        return EVAL_COLUMNS


class RunWriter:
    """Writes one run directory: config.json, status.json, the three CSVs and, with
    ``tensorboard``, TensorBoard event files of the same rows under ``<run>/tensorboard/``."""

    def __init__(
        self,
        directory: Path,
        loss_columns: Sequence[str],
        tensorboard: bool = False,
        extra: Mapping[str, Sequence[str]] | None = None,
    ) -> None:
        self.directory = Path(directory)
        self.loss_columns = ("step", *loss_columns)
        self.extra = dict(extra or {})  # more CSVs by name (pbt.csv): columns, step first
        self.tensorboard = tensorboard
        self.note = ""  # the reason status.json gives when no other is: how the run resumed
        self._logs: dict[str, CsvLog] = {}
        self._board: TensorBoardLog | None = None
        self._last_episode: tuple[int, float] | None = None  # (step, wall_s): for steps/s
        self._status_step = 0  # the step status.json holds
        self._eval_columns: tuple[str, ...] = EVAL_COLUMNS  # or, resuming an older run, its own
        self.shares_cpu = True  # cpu_s is the run's share of its process's (runs.clock.CPU_CLOCK)

    @property
    def checkpoint_dir(self) -> Path:
        """``<run>/checkpoint``, created on first use."""
        path = self.directory / "checkpoint"
        path.mkdir(parents=True, exist_ok=True)
        return path

    def _csvs(self) -> dict[str, tuple[str, ...]]:
        """Every CSV of the run by name (``eval`` for ``eval.csv``), with its columns."""
        return {
            "eval": self._eval_columns,
            "train": TRAIN_COLUMNS,
            "losses": self.loss_columns,
            **{name: tuple(columns) for name, columns in self.extra.items()},
        }

    def check_resume(
        self, step: int, config: Mapping[str, Any], members: Sequence[Mapping[str, Any]] = ()
    ) -> ResumePlan:
        """Check every CSV against the (intact) checkpoint generation at ``step``, whose
        manifest records what each held (an older generation records nothing: then the rows up
        to ``step`` are kept), and say what a resume keeps, writing nothing: a
        :class:`~tacbench.runs.resume_checks.DamagedRun` if a CSV cannot continue
        (:func:`~tacbench.runs.resume_checks.check_log`). Its notes also name the hardware
        settings in which ``config`` (the resumed run's settings) differs from config.json's
        (:func:`rounding_changes`), a group of other ``members`` than config.json's
        (:func:`group_changes`), and progress that status.json records beyond ``step`` (a
        newer generation whose manifest was lost)."""
        recorded = recorded_logs(self.directory / "checkpoint", step)
        plan = ResumePlan(step)
        metadata = read_json(self.directory / "config.json")
        stored = metadata.get("config")
        plan.notes += rounding_changes(stored if isinstance(stored, dict) else {}, config)
        plan.notes += group_changes(metadata.get("members"), members)
        status = self.directory / "status.json"
        reached = read_json(status).get("step") if status.exists() else None
        if isinstance(reached, int) and reached > step:  # a newer generation is lost
            plan.notes.append(
                f"status.json records step {reached:,}, but the resume starts from step "
                f"{step:,}, the newest checkpoint intact in every member: the steps after it are "
                "trained again"
            )
        if self.tensorboard:
            check_event_folder(self.directory / "tensorboard")
        self._eval_columns = _eval_columns(self.directory / "eval.csv")
        self.shares_cpu = shares_cpu(metadata)
        for name, columns in self._csvs().items():
            file = f"{name}.csv"
            digest = None if recorded is None else recorded.get(file)
            if recorded is not None and digest is None:
                raise DamagedRun(
                    f"cannot resume: the checkpoint at step {step} of {self.directory} records "
                    f"no {file}; {START_OVER}.",
                    self.directory,
                )
            plan.kept[name], notes = check_log(self.directory / file, columns, step, digest)
            plan.notes += notes
        return plan

    def open(self, metadata: Mapping[str, Any] | None, resume: ResumePlan | None) -> None:
        """Start a fresh run (``metadata`` for config.json) or reopen one as ``resume`` (from
        :meth:`check_resume`) says."""
        self.directory.mkdir(parents=True, exist_ok=True)
        if metadata is not None:
            atomic_write_json(self.directory / "config.json", metadata)
        for name, columns in self._csvs().items():
            kept = None if resume is None else resume.kept[name]
            self._logs[name] = CsvLog(self.directory / f"{name}.csv", columns, kept)
        step = None if resume is None else resume.step
        if self.tensorboard:
            from tacbench.runs.tensorboard import TensorBoardLog  # protobuf: only when used

            self._board = TensorBoardLog(self.directory / "tensorboard", step)
        self.status("running", step or 0)

    def log_digests(self) -> dict[str, LogDigest]:
        """What every CSV holds now, by file name: a checkpoint records it."""
        return {log.path.name: log.digest() for log in self._logs.values()}

    def eval_row(
        self, step: int, clock: RunClock, returns: Sequence[float], lengths: Sequence[float]
    ) -> None:
        """One evaluation: the run's clocks (``cpu_s`` unless the run began without it), mean
        and (population) std of the episode returns, mean length."""
        mean = math.fsum(returns) / len(returns)
        std = math.sqrt(math.fsum((r - mean) ** 2 for r in returns) / len(returns))
        length = math.fsum(lengths) / len(lengths)
        clocks = [round(clock.wall_s, 3)]
        if "cpu_s" in self._eval_columns:
            clocks.append(round(clock.cpu_s, 3))
        self._logs["eval"].write([step, *clocks, mean, std, length])
        if self._board is not None:
            self._board.scalars("eval", step, {"return": mean, "return_std": std, "length": length})

    def train_row(self, step: int, wall_s: float, episode_return: float, length: int) -> None:
        """One finished training episode (ending at ``step``)."""
        wall_s = round(wall_s, 3)
        self._logs["train"].write([step, wall_s, episode_return, length])
        if self._board is not None:
            values = {"episode_return": episode_return, "episode_length": float(length)}
            last = self._last_episode
            if last is not None and wall_s > last[1]:  # the first episode of a process has none
                values["steps_per_s"] = (step - last[0]) / (wall_s - last[1])
            self._board.scalars("train", step, values)
        self._last_episode = (step, wall_s)

    def losses_row(self, step: int, values: Sequence[float]) -> None:
        """Losses and diagnostics at ``step``, in the order of ``loss_columns``."""
        self._logs["losses"].write([step, *values])
        if self._board is not None:
            named = dict(zip(self.loss_columns[1:], values, strict=True))
            self._board.scalars("losses", step, named)

    def extra_row(self, name: str, row: Sequence[Any]) -> None:
        """A row of one of the ``extra`` CSVs (step first)."""
        self._logs[name].write(row)

    def status(self, state: State, step: int, reason: str = "") -> None:
        """Replace status.json (``reason``, or else :attr:`note`)."""
        atomic_write_json(
            self.directory / "status.json",
            {"state": state, "step": step, "reason": reason or self.note, "updated": now_iso()},
        )
        self._status_step = step

    def crashed(self, step: int, error: BaseException) -> None:
        """Record an unexpected error at ``step`` as the run's end: status.json ``failed`` at
        the step it last recorded (the last checkpoint's), the reason starting with
        :data:`CRASHED` and saying that ``--resume`` continues from there. Our own errors and
        the disk's (full, read-only) are not unexpected: they leave the status as it is, to be
        resumed. An error while recording is swallowed, so that it cannot hide ``error``."""
        disk = isinstance(error, OSError) and error.errno in DISK_ERRNOS
        if isinstance(error, TacbenchError) or disk:
            return
        what = one_line(error)
        reason = f"{CRASHED} at step {step}: {what}; --resume continues from the last checkpoint"
        with contextlib.suppress(OSError):
            self.status("failed", self._status_step, reason)

    def stopped_at_once(self, step: int, stopped: SecondSignal) -> None:
        """Record a second stop signal at ``step``: status.json ``interrupted`` at the step it
        last recorded (the last checkpoint's, where ``--resume`` continues from)."""
        reason = (
            f"stopped at once by a second {stopped} at step {step}, before a checkpoint; "
            f"resume with: {stopped.resume} (from step {self._status_step})"
        )
        with contextlib.suppress(OSError):
            self.status("interrupted", self._status_step, reason)

    def close(self) -> None:
        """Close the CSVs and the event file."""
        for log in self._logs.values():
            log.close()
        self._logs.clear()
        if self._board is not None:
            self._board.close()
            self._board = None
