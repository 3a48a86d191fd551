"""TensorBoard event files beside a run's CSVs, written from the same rows (issue 20).

The CSVs stay the contract that reports read (docs/results-schema.md); the event files are a
view of the same numbers for ``tensorboard --logdir results/runs``, which names each run by its
path. A resumed run opens a new event file whose purge step hides every point the interrupted
process logged after the checkpoint it resumes from (the rows its CSVs lost), so the stream
continues without duplicated steps.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any


class TensorBoardLog:
    """Scalars of one run under ``directory``, tagged ``<group>/<name>`` against env steps."""

    def __init__(self, directory: Path, resume_step: int | None) -> None:
        from torch.utils.tensorboard import SummaryWriter  # imports tensorboard: only when used

        # purge_step: TensorBoard drops earlier points at steps >= it; the CSVs keep <= resume_step
        purge = None if resume_step is None else resume_step + 1
        self._writer: Any = SummaryWriter(str(directory), purge_step=purge, flush_secs=30)

    def scalars(self, group: str, step: int, values: Mapping[str, float]) -> None:
        """One point per value at ``step``."""
        for name, value in values.items():
            self._writer.add_scalar(f"{group}/{name}", value, step)

    def flush(self) -> None:
        """Hand the buffered points to the event file (a live run shows them)."""
        self._writer.flush()

    def close(self) -> None:
        """Flush and close the event file."""
        self._writer.close()
