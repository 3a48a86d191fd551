"""What a resume checks before it writes anything: each CSV of the run directory against the
checkpoint generation it continues from.

A generation's manifest records, for each CSV, what the file held when the generation was
written (its rows, bytes and SHA-256: :meth:`tacbench.runs.files.CsvLog.digest`). A resume keeps
exactly those bytes and drops what was appended after them (rows past the checkpoint, a torn last
line). It refuses, with what is wrong and what to do, a CSV that is missing, has a row that is not
a number, width or order, or whose rows up to the checkpoint are not the ones recorded (a row
lost, added or changed). A generation written before manifests recorded the CSVs is checked for
the same faults row by row, keeping the rows up to its step.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tacbench.errors import TacbenchError

START_OVER = "rerun with --force to start the run over (tacbench sweep: delete the run's directory)"
"""How to start a run over, in ``tacbench run`` and in a sweep (which has no ``--force``)."""


class DamagedRun(TacbenchError):
    """A run whose CSVs cannot continue from its checkpoint (nothing was changed): the run in
    ``directory`` cannot resume, while the other members of its group still can."""

    def __init__(self, message: str, directory: Path) -> None:
        super().__init__(message)
        self.directory = directory


@dataclass(frozen=True)
class LogDigest:
    """What a CSV held when a checkpoint was written: its rows (header excluded), bytes and
    SHA-256 (as the manifest's ``logs`` entry records it)."""

    rows: int
    size: int
    sha256: str

    def to_dict(self) -> dict[str, Any]:
        """The manifest's entry."""
        return {"rows": self.rows, "size": self.size, "sha256": self.sha256}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> LogDigest:
        """From a manifest's entry."""
        return cls(int(data["rows"]), int(data["size"]), str(data["sha256"]))


@dataclass
class ResumePlan:
    """How a run's CSVs continue: the bytes each keeps (by file name) and what was repaired."""

    step: int
    kept: dict[str, bytes] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


def _refuse(path: Path, what: str) -> DamagedRun:
    return DamagedRun(
        f"cannot resume: {path} {what}; nothing was changed; fix the file, or {START_OVER}.",
        path.parent,
    )


def _rows(path: Path, columns: Sequence[str]) -> tuple[list[bytes], list[int], bool]:
    """The complete lines of ``path`` (header first, each with its newline), the step of each
    row, and whether a torn last line followed them; a :class:`DamagedRun` on the first faulty
    row."""
    if not path.is_file():
        raise _refuse(path, "is missing (the checkpoint continues from its rows)")
    data = path.read_bytes()
    lines = data.splitlines(keepends=True)
    torn = bool(lines) and not lines[-1].endswith(b"\n")
    if torn:
        lines = lines[:-1]
    header = ",".join(columns).encode() + b"\n"
    if not lines or lines[0] != header:
        found = lines[0].decode(errors="replace").strip() if lines else "nothing"
        raise _refuse(path, f"has the header {found!r}, expected {header.decode().strip()!r}")
    steps: list[int] = []
    for number, line in enumerate(lines[1:], start=2):
        values = line.rstrip(b"\n").split(b",")
        if len(values) != len(columns):
            raise _refuse(
                path, f"line {number} has {len(values)} values for {len(columns)} columns"
            )
        try:
            step = int(values[0])
        except ValueError:
            raise _refuse(path, f"line {number} has the step {values[0].decode()!r}") from None
        if steps and step <= steps[-1]:
            again = "repeats" if step == steps[-1] else "goes back from"
            raise _refuse(path, f"line {number}: step {step} {again} step {steps[-1]}")
        steps.append(step)
    return lines, steps, torn


def check_log(
    path: Path, columns: Sequence[str], step: int, recorded: LogDigest | None
) -> tuple[bytes, list[str]]:
    """The bytes of ``path`` a resume from ``step`` keeps, and notes on what it repaired; a
    :class:`DamagedRun` (nothing written) when the file cannot continue. ``recorded``: what the
    checkpoint's manifest says the file held (None for an older generation: keep the rows up
    to ``step``)."""
    lines, steps, torn = _rows(path, columns)
    notes = [f"{path.name}: cut a torn last line"] if torn else []
    if recorded is None:
        count = sum(1 for s in steps if s <= step)
    else:
        count = recorded.rows
        if len(steps) < count:
            raise _refuse(
                path,
                f"holds {len(steps)} row{'' if len(steps) == 1 else 's'}, but the checkpoint at "
                f"step {step} recorded {count}: rows are missing",
            )
    kept = b"".join(lines[: 1 + count])
    if recorded is not None and (
        len(kept) != recorded.size or hashlib.sha256(kept).hexdigest() != recorded.sha256
    ):
        raise _refuse(
            path, f"differs from what the checkpoint at step {step} recorded (rows were changed)"
        )
    return kept, notes


def check_event_folder(folder: Path) -> None:
    """A :class:`DamagedRun` (nothing written) when ``folder``, where a resumed run with
    TensorBoard logging writes its event files, exists but is not a folder."""
    if folder.exists() and not folder.is_dir():
        raise DamagedRun(
            f"cannot resume: {folder} is a file where the run's TensorBoard event files go; "
            "nothing was changed; move it away, or resume with --no-tensorboard.",
            folder.parent,
        )
