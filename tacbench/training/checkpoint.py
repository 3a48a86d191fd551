"""A TAC member's checkpoint on disk: generations of ``checkpoint/state-<step>.pt`` and
``checkpoint/replay/*.npz``, each recorded by a manifest (:mod:`tacbench.runs.checkpoints`).

``state-<step>.pt`` holds everything the member's continuation depends on but its replay
buffer: the agent's weights, Adam state and generator, the env's exact state, the episode in
progress, the open ``losses.csv`` window and the counters (the trainer composes it,
:mod:`loop`). The replay buffer is written incrementally: each checkpoint adds one
``replay/<t0>-<t1>.npz`` with what the member added since the previous one
(:meth:`ReplayBuffer.save_chunk`); a generation lists the chunks it needs, and chunks whose
transitions have all been overwritten leave the list (and, once no kept generation lists them,
the disk).
"""

from __future__ import annotations

import io
from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import torch

from tacbench.runs import checkpoints
from tacbench.runs.resume_checks import LogDigest
from tacbench.tac.buffer import ReplayBuffer

REPLAY = "replay"


@dataclass
class MemberState:
    """One member's ``state-<step>.pt``: its fields are the file's keys (``pbt`` only with --q
    auto). The agent's part is :meth:`TacAgent.member_state`, the buffer's
    :meth:`ReplayBuffer.counters`; the rest is the loop's."""

    step: int
    agent: dict[str, Any]  # weights, targets, Adam state, generator
    buffer: dict[str, Any]  # where the member's replay buffer stands (its rows: replay/*.npz)
    rng: Mapping[str, Any]  # the loop's NumPy generator (warm-up actions, minibatches)
    env: dict[str, Any] | None  # the env's exact state (MuJoCo), None where there is none
    obs: torch.Tensor  # the observation the next step acts on
    episode_return: float  # the episode in progress
    episode_length: int
    loss_sum: torch.Tensor  # the open losses.csv window
    loss_count: int
    updates_started: bool  # training.schedule
    wall_s: float
    cpu_s: float = 0.0  # absent from checkpoints older than the CPU clock (runs.RunClock)
    pbt: dict[str, Any] | None = None  # --q auto: the member's part of the population

    def to_dict(self) -> dict[str, Any]:
        """The keys and values ``state-<step>.pt`` holds."""
        data = {f.name: getattr(self, f.name) for f in fields(self)}
        if self.pbt is None:
            del data["pbt"]
        return data


def state_file(checkpoint_dir: Path, step: int) -> Path:
    """Where the generation at ``step`` keeps the member's state."""
    return checkpoint_dir / f"state-{step:012d}.pt"


def _chunk_end(chunk: Path) -> int:
    """The step a replay chunk ``<t0>-<t1>.npz`` ends at."""
    return int(chunk.stem.split("-")[1])


def read(checkpoint_dir: Path, step: int) -> tuple[MemberState, list[Path]]:
    """The member's state at the (intact) generation ``step`` and the replay chunks it lists."""
    state = MemberState(**torch.load(state_file(checkpoint_dir, step), weights_only=True))
    chunks = [p for p in checkpoints.files_of(checkpoint_dir, step) if p.parent.name == REPLAY]
    return state, sorted(chunks)


def load_replay(buffer: ReplayBuffer, member: int, chunks: list[Path]) -> None:
    """Rebuild member ``member``'s replay buffer from a generation's chunks, in order."""
    for chunk in chunks:
        buffer.load_chunk(member, chunk)


def write_checkpoint(
    checkpoint_dir: Path,
    state: MemberState,
    buffer: ReplayBuffer,
    member: int,
    since: tuple[int, int],
    chunks: list[Path],
    logs: Mapping[str, LogDigest],
) -> list[Path]:
    """Write member ``member``'s generation at ``state.step``: the replay chunk since ``since``
    (transitions, rows added at the previous checkpoint), ``state-<step>.pt``, then the
    manifest, which records what the run's CSVs hold (``logs``); returns the chunks the
    generation lists (``chunks``, the previous generation's, plus the new one, less those the
    buffer has overwritten)."""
    step = state.step
    replay = checkpoint_dir / REPLAY
    replay.mkdir(parents=True, exist_ok=True)
    since_added, since_rows = since
    listed = [c for c in chunks if _chunk_end(c) >= step - buffer.capacity]
    if step > since_added:
        chunk = replay / f"{since_added:012d}-{step:012d}.npz"
        checkpoints.write_durably(
            chunk, lambda handle: buffer.save_chunk(member, handle, since_added, since_rows)
        )
        listed.append(chunk)
    data = io.BytesIO()
    torch.save(state.to_dict(), data)
    path = state_file(checkpoint_dir, step)
    checkpoints.write_durably(path, lambda handle: handle.write(data.getbuffer()))
    checkpoints.commit(checkpoint_dir, step, [path, *listed], logs)
    return listed
