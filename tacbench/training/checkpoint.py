"""A TAC member's checkpoint on disk: ``checkpoint/state.pt`` and ``checkpoint/replay/*.npz``.

``state.pt`` holds everything the member's continuation depends on but its replay buffer: the
agent's weights, Adam state and generator, the env's exact state, the episode in progress, the
open ``losses.csv`` window and the counters (the trainer composes it, :mod:`loop`). The replay
buffer is written incrementally: each checkpoint adds one ``replay/<t0>-<t1>.npz`` with what
the member added since the previous one (:meth:`ReplayBuffer.save_chunk`), and chunks whose
transitions have all been overwritten are deleted. Files are written to a temporary name and
renamed.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from tacbench.tac.buffer import ReplayBuffer

STATE_FILE = "state.pt"
REPLAY = "replay"


def read_state(directory: Path) -> dict[str, Any] | None:
    """The state saved in run ``directory``'s checkpoint, or None if it has none."""
    path = directory / "checkpoint" / STATE_FILE
    return torch.load(path, weights_only=True) if path.exists() else None


def _chunk_end(chunk: Path) -> int:
    """The step a replay chunk ``<t0>-<t1>.npz`` ends at."""
    return int(chunk.stem.split("-")[1])


def load_replay(directory: Path, buffer: ReplayBuffer, member: int, step: int) -> None:
    """Rebuild member ``member``'s replay buffer from the chunks of run ``directory`` up to
    ``step``; chunks written after it (a crash after the replay but before the state) go."""
    for chunk in sorted((directory / "checkpoint" / REPLAY).glob("*.npz")):
        if _chunk_end(chunk) > step:
            chunk.unlink()
        else:
            buffer.load_chunk(member, chunk)


def write_checkpoint(
    checkpoint_dir: Path,
    state: dict[str, Any],
    buffer: ReplayBuffer,
    member: int,
    since: tuple[int, int],
) -> None:
    """Write member ``member``'s checkpoint at ``state["step"]``: the replay chunk since
    ``since`` (transitions, rows added at the previous checkpoint), then ``state.pt``, then drop
    the chunks the buffer has overwritten since."""
    step = state["step"]
    replay = checkpoint_dir / REPLAY
    replay.mkdir(parents=True, exist_ok=True)
    since_added, since_rows = since
    if step > since_added:
        chunk = replay / f"{since_added:012d}-{step:012d}.npz"
        buffer.save_chunk(member, chunk, since_added, since_rows)
    tmp = checkpoint_dir / (STATE_FILE + ".tmp")
    torch.save(state, tmp)
    tmp.replace(checkpoint_dir / STATE_FILE)
    for old in replay.glob("*.npz"):  # chunks whose transitions have all been overwritten
        if _chunk_end(old) < step - buffer.capacity:
            old.unlink()
