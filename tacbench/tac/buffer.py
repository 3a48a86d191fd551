"""A member-batched replay buffer that stores each observation once, and saves incrementally.

A transition is ``(obs_row, action, reward, terminated, next_obs_row)``: the two observations
are indices into a per-member ring of observation rows. Within an episode one row is both a
transition's ``s'`` and the next transition's ``s``, so a step adds one row (plus one per
reset), about half of what storing ``s`` and ``s'`` takes. Observations are kept as float32.

Transitions are added for all K members in lockstep (one ring position per step); rows are
per member (episodes end at different steps). With at most two rows per transition, a row
ring of ``2 * capacity + 2`` rows always holds every row the last ``capacity`` transitions use.
Arrays are ``np.zeros``, so memory is only committed as rows are written.

:meth:`save_chunk` writes what member k added since the previous chunk; loading a run's chunks
in order rebuilds its buffer exactly (:meth:`load_chunk`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

IntArray = npt.NDArray[np.int64]
FloatArray = npt.NDArray[np.float32]


class ReplayBuffer:
    """Replay memory for K members; ``capacity`` transitions each, oldest overwritten first."""

    def __init__(self, n_members: int, obs_dim: int, act_dim: int, capacity: int) -> None:
        self.capacity = capacity
        self.row_capacity = 2 * capacity + 2
        self.rows = np.zeros((n_members, self.row_capacity, obs_dim), dtype=np.float32)
        self.obs_row = np.zeros((n_members, capacity), dtype=np.int64)
        self.next_row = np.zeros((n_members, capacity), dtype=np.int64)
        self.action = np.zeros((n_members, capacity, act_dim), dtype=np.float32)
        self.reward = np.zeros((n_members, capacity), dtype=np.float32)
        self.terminated = np.zeros((n_members, capacity), dtype=np.float32)
        self.n_added = 0  # transitions ever added (per member; all members alike)
        self.n_rows = np.zeros(n_members, dtype=np.int64)  # rows ever added, per member
        self.current_row = np.full(n_members, -1, dtype=np.int64)  # row of each member's s
        self._members = np.arange(n_members)

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

    def sample(self, rngs: Sequence[np.random.Generator], batch_size: int) -> dict[str, Any]:
        """``batch_size`` transitions per member, uniformly with replacement, member k's indices
        drawn from ``rngs[k]``. Arrays shaped ``(K, B, ...)``: obs, action, reward,
        next_obs, terminated."""
        index = np.stack([rng.integers(0, self.size, batch_size) for rng in rngs])
        k = self._members[:, None]
        return {
            "obs": self.rows[k, self.obs_row[k, index]],
            "action": self.action[k, index],
            "reward": self.reward[k, index],
            "next_obs": self.rows[k, self.next_row[k, index]],
            "terminated": self.terminated[k, index],
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

    def save_chunk(self, member: int, path: Path, since_added: int, since_rows: int) -> None:
        """Write member ``member``'s transitions added since ``since_added`` and its rows added
        since ``since_rows`` (only those still in the buffer) to ``path`` (``.npz``)."""
        t0 = max(since_added, self.n_added - self.capacity)
        r0 = max(since_rows, int(self.n_rows[member]) - self.row_capacity)
        positions = np.arange(t0, self.n_added) % self.capacity
        row_positions = np.arange(r0, self.n_rows[member]) % self.row_capacity
        tmp = path.with_name(path.name + ".tmp")
        with tmp.open("wb") as handle:
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
        tmp.replace(path)

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
