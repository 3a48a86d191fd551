"""A member-batched replay buffer that stores each observation once, and saves incrementally.

A transition is ``(obs_row, action, reward, terminated, next_obs_row)``: the two observations
are indices into a per-member ring of observation rows. Within an episode one row is both a
transition's ``s'`` and the next transition's ``s``, so a step adds one row (plus one per
reset), about half of what storing ``s`` and ``s'`` takes. Observations are kept as float32.

Transitions are added for all K members in lockstep (one ring position per step); rows are
per member (episodes end at different steps). With at most two rows per transition, a row
ring of ``2 * capacity + 2`` rows always holds every row the last ``capacity`` transitions use.
Memory is only committed as rows are written (about ``1 + 1/L`` rows per step for episodes of
mean length L): the row ring is an anonymous mapping that reserves nothing (Linux), because the
kernel refuses a plain ``np.zeros`` reservation larger than RAM, e.g. 28 GiB for 10 Humanoid
members of 1M transitions, of which about 15 GiB are ever written.

Each transition's action, reward and terminal flag sit side by side in one float32 array
``(K, capacity, A + 2)`` and its two row indices in one ``(K, capacity, 2)`` array, so
:meth:`sample` gathers a minibatch of all K members with three ``np.take`` calls and returns
views of them (no further copies).

:meth:`save_chunk` writes what member k added since the previous chunk; loading a run's chunks
in order rebuilds its buffer exactly (:meth:`load_chunk`).
"""

from __future__ import annotations

import mmap
import platform
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import IO, Any

import numpy as np
import numpy.typing as npt

IntArray = npt.NDArray[np.int64]
FloatArray = npt.NDArray[np.float32]

# Linux's MAP_NORESERVE (asm-generic/mman.h; Python's mmap module names it from 3.13 only)
_MAP_NORESERVE = getattr(mmap, "MAP_NORESERVE", 0x4000)
_NORESERVE_OK = sys.platform == "linux" and platform.machine() in ("x86_64", "aarch64")


def lazy_zeros(shape: tuple[int, ...], dtype: type[np.generic]) -> npt.NDArray[Any]:
    """Zeros whose memory is committed page by page as it is written and never reserved up
    front (an anonymous ``MAP_NORESERVE`` mapping on Linux x86-64 and aarch64; ``np.zeros``
    elsewhere)."""
    size = int(np.prod(shape)) * np.dtype(dtype).itemsize
    if not _NORESERVE_OK or size == 0:
        return np.zeros(shape, dtype=dtype)
    region = mmap.mmap(-1, size, flags=mmap.MAP_PRIVATE | _MAP_NORESERVE)
    return np.frombuffer(region, dtype=dtype).reshape(shape)


class ReplayBuffer:
    """Replay memory for K members; ``capacity`` transitions each, oldest overwritten first."""

    def __init__(self, n_members: int, obs_dim: int, act_dim: int, capacity: int) -> None:
        self.capacity = capacity
        self.row_capacity = 2 * capacity + 2
        self.rows = lazy_zeros((n_members, self.row_capacity, obs_dim), np.float32)
        self.row_index = np.zeros((n_members, capacity, 2), dtype=np.int64)  # s and s' rows
        self.obs_row, self.next_row = self.row_index[..., 0], self.row_index[..., 1]
        self.transitions = np.zeros((n_members, capacity, act_dim + 2), dtype=np.float32)
        self.action = self.transitions[..., :act_dim]
        self.reward = self.transitions[..., act_dim]
        self.terminated = self.transitions[..., act_dim + 1]
        self.n_added = 0  # transitions ever added (per member; all members alike)
        self.n_rows = np.zeros(n_members, dtype=np.int64)  # rows ever added, per member
        self.current_row = np.full(n_members, -1, dtype=np.int64)  # row of each member's s
        self._members = np.arange(n_members)
        self._first_transition = self._members[:, None] * capacity  # member k's flat offset
        self._first_row = self._members[:, None, None] * self.row_capacity

    @property
    def size(self) -> int:
        """Transitions available for sampling (per member)."""
        return min(self.n_added, self.capacity)

    def _append_rows(self, members: IntArray, obs: npt.ArrayLike) -> IntArray:
        absolute = self.n_rows[members].copy()
        self.rows[members, absolute % self.row_capacity] = obs
        self.n_rows[members] += 1
        return absolute

    def start_episodes(self, members: Sequence[int] | IntArray, obs: npt.ArrayLike) -> None:
        """Record the first observation ``(len(members), obs_dim)`` of new episodes."""
        index = np.asarray(members, dtype=np.int64)
        self.current_row[index] = self._append_rows(index, obs)

    def add(
        self,
        action: npt.ArrayLike,
        reward: npt.ArrayLike,
        terminated: npt.ArrayLike,
        next_obs: npt.ArrayLike,
    ) -> None:
        """Add one transition per member from its current observation: ``(K, act_dim)``,
        ``(K,)``, ``(K,)``, ``(K, obs_dim)``. ``next_obs`` becomes the current observation."""
        pos = self.n_added % self.capacity
        next_absolute = self._append_rows(self._members, next_obs)
        self.obs_row[:, pos] = self.current_row % self.row_capacity
        self.next_row[:, pos] = next_absolute % self.row_capacity
        self.action[:, pos] = action
        self.reward[:, pos] = reward
        self.terminated[:, pos] = terminated
        self.current_row = next_absolute
        self.n_added += 1

    def sample(
        self,
        rngs: Sequence[np.random.Generator],
        batch_size: int,
        members: Sequence[bool] | None = None,
    ) -> dict[str, Any]:
        """``batch_size`` transitions per member, uniformly with replacement, member k's indices
        drawn from ``rngs[k]``; for members that ``members`` leaves out nothing is drawn (their
        rows repeat the first transition). Arrays shaped ``(K, B, ...)`` (views of two gathered
        arrays): obs, action, reward, next_obs, terminated."""
        n_members, capacity, width = self.transitions.shape
        index = np.stack(
            [
                rng.integers(0, self.size, batch_size)
                if members is None or members[k]
                else np.zeros(batch_size, dtype=np.int64)
                for k, rng in enumerate(rngs)
            ]
        )
        index += self._first_transition
        transitions = np.take(self.transitions.reshape(n_members * capacity, width), index, 0)
        rows = np.take(self.row_index.reshape(n_members * capacity, 2), index, 0)
        rows += self._first_row
        obs = np.take(self.rows.reshape(n_members * self.row_capacity, -1), rows, 0)
        act_dim = width - 2
        return {
            "obs": obs[:, :, 0],
            "action": transitions[..., :act_dim],
            "reward": transitions[..., act_dim],
            "next_obs": obs[:, :, 1],
            "terminated": transitions[..., act_dim + 1],
        }

    def counters(self, member: int) -> dict[str, int]:
        """Member ``member``'s counters, for a checkpoint."""
        return {
            "n_added": self.n_added,
            "n_rows": int(self.n_rows[member]),
            "current_row": int(self.current_row[member]),
        }

    def restore_counters(self, member: int, counters: dict[str, int]) -> None:
        """Undo :meth:`counters` (``n_added`` must agree across members)."""
        self.n_added = int(counters["n_added"])
        self.n_rows[member] = counters["n_rows"]
        self.current_row[member] = counters["current_row"]

    def save_chunk(self, member: int, handle: IO[bytes], since_added: int, since_rows: int) -> None:
        """Write member ``member``'s transitions added since ``since_added`` and its rows added
        since ``since_rows`` (only those still in the buffer) to ``handle`` (``.npz``)."""
        t0 = max(since_added, self.n_added - self.capacity)
        r0 = max(since_rows, int(self.n_rows[member]) - self.row_capacity)
        positions = np.arange(t0, self.n_added) % self.capacity
        row_positions = np.arange(r0, self.n_rows[member]) % self.row_capacity
        np.savez(
            handle,
            t0=t0,
            r0=r0,
            rows=self.rows[member, row_positions],
            obs_row=self.obs_row[member, positions],
            next_row=self.next_row[member, positions],
            action=self.action[member, positions],
            reward=self.reward[member, positions],
            terminated=self.terminated[member, positions],
        )

    def load_chunk(self, member: int, path: Path) -> None:
        """Write a chunk from :meth:`save_chunk` back into member ``member``'s storage."""
        with np.load(path) as chunk:
            t0, r0 = int(chunk["t0"]), int(chunk["r0"])
            positions = np.arange(t0, t0 + len(chunk["reward"])) % self.capacity
            row_positions = np.arange(r0, r0 + len(chunk["rows"])) % self.row_capacity
            self.rows[member, row_positions] = chunk["rows"]
            self.obs_row[member, positions] = chunk["obs_row"]
            self.next_row[member, positions] = chunk["next_row"]
            self.action[member, positions] = chunk["action"]
            self.reward[member, positions] = chunk["reward"]
            self.terminated[member, positions] = chunk["terminated"]
