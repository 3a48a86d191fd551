"""The replay buffer: observations stored once, episode boundaries, wrap-around, member
independence and incremental save/load."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from tacbench.tac.buffer import ReplayBuffer

pytestmark = pytest.mark.unit


def _fill(buffer: ReplayBuffer, steps: int, episode_lengths: list[int]) -> None:
    """Member k's observation at time t of episode e is [k, e, t]; actions/rewards encode t."""
    k_all = len(episode_lengths)
    episode = np.zeros(k_all, dtype=int)
    t = np.zeros(k_all, dtype=int)
    members = np.arange(k_all)
    buffer.start_episodes(members, np.stack([members, episode, t], axis=1))
    for _ in range(steps):
        t += 1
        next_obs = np.stack([members, episode, t], axis=1)
        terminated = (t % np.array(episode_lengths) == 0) & (members == 0)
        buffer.add(np.stack([t, -t], axis=1), t * 1.0, terminated, next_obs)
        for k in np.flatnonzero(t % np.array(episode_lengths) == 0):
            episode[k] += 1
            t[k] = 0
            buffer.start_episodes([k], [[k, episode[k], 0]])


def _all_transitions(buffer: ReplayBuffer) -> dict[str, np.ndarray]:
    """Every stored transition, via sample() with rigged generators that enumerate indices."""

    class Enumerate:
        def integers(self, low: int, high: int, size: int) -> np.ndarray:
            return np.arange(high)

    k_all = buffer.obs_row.shape[0]
    return buffer.sample([Enumerate()] * k_all, buffer.size)  # type: ignore[list-item]


def test_next_obs_follows_obs_within_episodes_and_is_the_last_obs_at_their_end() -> None:
    buffer = ReplayBuffer(2, 3, 2, capacity=50)
    _fill(buffer, 20, episode_lengths=[7, 5])
    batch = _all_transitions(buffer)
    obs, next_obs = batch["obs"], batch["next_obs"]
    assert obs.shape == (2, 20, 3)
    np.testing.assert_array_equal(next_obs[..., 0], obs[..., 0])  # member id
    np.testing.assert_array_equal(next_obs[..., 1], obs[..., 1])  # same episode: never the reset
    np.testing.assert_array_equal(next_obs[..., 2], obs[..., 2] + 1)
    np.testing.assert_array_equal(batch["action"][..., 0], next_obs[..., 2])
    np.testing.assert_array_equal(batch["reward"], next_obs[..., 2])
    # member 0's episodes end (terminated) at t = 7, 14; member 1 never terminates
    np.testing.assert_array_equal(np.flatnonzero(batch["terminated"][0]), [6, 13])
    assert not batch["terminated"][1].any()


def test_each_observation_is_stored_once() -> None:
    buffer = ReplayBuffer(2, 3, 2, capacity=50)
    _fill(buffer, 20, episode_lengths=[7, 5])
    # one row per step plus one per episode start: 20 + 3 (member 0), 20 + 5 (member 1)
    np.testing.assert_array_equal(buffer.n_rows, [23, 25])


def test_wrap_around_keeps_the_latest_transitions_consistent() -> None:
    buffer = ReplayBuffer(2, 3, 2, capacity=16)
    _fill(buffer, 100, episode_lengths=[3, 11])
    batch = _all_transitions(buffer)
    assert buffer.size == 16
    np.testing.assert_array_equal(batch["next_obs"][..., 2], batch["obs"][..., 2] + 1)
    np.testing.assert_array_equal(batch["next_obs"][..., 1], batch["obs"][..., 1])
    # the stored transitions are the 16 latest: member 1's episode index spans 100 // 11
    assert batch["obs"][1, :, 1].max() == 100 // 11


def test_sample_uses_each_members_own_generator() -> None:
    buffer = ReplayBuffer(2, 3, 2, capacity=50)
    _fill(buffer, 30, episode_lengths=[7, 5])
    one = buffer.sample([np.random.default_rng(1), np.random.default_rng(2)], 10)
    two = buffer.sample([np.random.default_rng(9), np.random.default_rng(2)], 10)
    np.testing.assert_array_equal(one["action"][1], two["action"][1])
    assert not np.array_equal(one["action"][0], two["action"][0])


@pytest.mark.parametrize("capacity", [64, 10])
def test_incremental_chunks_rebuild_the_buffer_exactly(tmp_path: Path, capacity: int) -> None:
    original = ReplayBuffer(2, 3, 2, capacity=capacity)
    chunks: list[list[Path]] = [[], []]
    since_added, since_rows = 0, original.n_rows.copy()
    for part in range(3):
        _fill_more(original, 13)
        for k in range(2):
            path = tmp_path / f"m{k}-{part}.npz"
            with path.open("wb") as handle:
                original.save_chunk(k, handle, since_added, int(since_rows[k]))
            chunks[k].append(path)
        since_added, since_rows = original.n_added, original.n_rows.copy()

    rebuilt = ReplayBuffer(2, 3, 2, capacity=capacity)
    for k in range(2):
        rebuilt.restore_counters(k, original.counters(k))
        for path in chunks[k]:
            rebuilt.load_chunk(k, path)
    rngs = [np.random.default_rng(0), np.random.default_rng(1)]
    expected = original.sample(rngs, 200)
    got = rebuilt.sample([np.random.default_rng(0), np.random.default_rng(1)], 200)
    for key, value in expected.items():
        np.testing.assert_array_equal(got[key], value, err_msg=key)


def _fill_more(buffer: ReplayBuffer, steps: int) -> None:
    rng = np.random.default_rng(buffer.n_added)
    k_all = len(buffer.n_rows)
    if buffer.n_added == 0:
        buffer.start_episodes(range(k_all), rng.normal(size=(k_all, 3)))
    for _ in range(steps):
        done = rng.random(k_all) < 0.2
        buffer.add(
            rng.normal(size=(k_all, 2)), rng.normal(size=k_all), done, rng.normal(size=(k_all, 3))
        )
        for k in np.flatnonzero(done):
            buffer.start_episodes([k], rng.normal(size=(1, 3)))


def test_chunks_store_only_what_was_added(tmp_path: Path) -> None:
    buffer = ReplayBuffer(1, 3, 2, capacity=1000)
    _fill(buffer, 100, episode_lengths=[1000])
    with (tmp_path / "a.npz").open("wb") as handle:
        buffer.save_chunk(0, handle, 0, 0)
    _fill_more(buffer, 20)
    with (tmp_path / "b.npz").open("wb") as handle:
        buffer.save_chunk(0, handle, 100, 101)
    with np.load(tmp_path / "b.npz") as chunk:
        assert len(chunk["reward"]) == 20
        assert len(chunk["rows"]) == buffer.n_rows[0] - 101


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/self/statm")
def test_rows_commit_memory_only_as_they_are_written() -> None:
    """A 1M-transition buffer reserves 2M + 2 rows; only the rows written take memory."""

    def resident_bytes() -> int:
        return int(Path("/proc/self/statm").read_text().split()[1]) * 4096

    before = resident_bytes()
    buffer = ReplayBuffer(2, 376, 17, capacity=1_000_000)  # 6 GB of rows reserved
    assert buffer.rows.nbytes > 6e9
    buffer.start_episodes([0, 1], np.ones((2, 376)))
    for _ in range(1000):
        buffer.add(np.zeros((2, 17)), np.zeros(2), np.zeros(2), np.ones((2, 376)))
    assert buffer.rows[:, :1001].all() and not buffer.rows[:, 1001:1100].any()
    assert resident_bytes() - before < 200e6  # 2 x 1001 rows of 1.5 kB, not 6 GB
