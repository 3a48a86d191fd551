"""TensorBoard event files beside a run's CSVs, written from the same rows.

The CSVs stay the contract that reports read (docs/results-schema.md); the event files are a
view of the same numbers for ``tensorboard --logdir results/runs``, which names each run by its
path. A resumed run opens a new event file whose purge step hides every point the interrupted
process logged after the checkpoint it resumes from (the rows its CSVs lost), so the stream
continues without duplicated steps.

Events are written in the calling thread and flushed with each row, like the CSVs, with
TensorBoard's own record format and protocol buffers: an error (a full disk) reaches the
trainer, which stops with one clear message, instead of a background writer thread's traceback
(``torch.utils.tensorboard.SummaryWriter`` writes from such a thread).
"""

from __future__ import annotations

import os
import socket
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from tensorboard.compat.proto.event_pb2 import Event, SessionLog
from tensorboard.compat.proto.summary_pb2 import Summary
from tensorboard.summary.writer.record_writer import RecordWriter

FILE_VERSION = "brain.Event:2"  # what TensorBoard's own writers put first in a file


class TensorBoardLog:
    """Scalars of one run under ``directory``, tagged ``<group>/<name>`` against env steps."""

    def __init__(self, directory: Path, resume_step: int | None) -> None:
        directory.mkdir(parents=True, exist_ok=True)
        name = f"events.out.tfevents.{time.time():.6f}.{socket.gethostname()}.{os.getpid()}"
        self.path = directory / name
        self._file: Any = self.path.open("ab")
        self._records = RecordWriter(self._file)
        self._write(Event(wall_time=time.time(), file_version=FILE_VERSION))
        if resume_step is not None:
            # TensorBoard drops earlier points at steps >= a START's step; the CSVs keep the
            # rows at steps <= resume_step
            start = SessionLog(status=SessionLog.START)
            self._write(Event(wall_time=time.time(), step=resume_step + 1, session_log=start))
        self.flush()

    def _write(self, event: Event) -> None:
        self._named(lambda: self._records.write(event.SerializeToString()))

    def scalars(self, group: str, step: int, values: Mapping[str, float]) -> None:
        """One point per value at ``step``, flushed to the OS."""
        summary = Summary(
            value=[Summary.Value(tag=f"{group}/{k}", simple_value=v) for k, v in values.items()]
        )
        self._write(Event(wall_time=time.time(), step=step, summary=summary))
        self.flush()

    def flush(self) -> None:
        """Hand what was written to the OS (a live run shows it)."""
        self._named(self._records.flush)

    def close(self) -> None:
        """Close the event file."""
        self._named(self._file.close)

    def _named(self, operation: Callable[[], object]) -> None:
        """``operation()``; an OS error from it names the event file, as the CSVs' do."""
        try:
            operation()
        except OSError as err:
            err.filename = err.filename or str(self.path)
            raise
