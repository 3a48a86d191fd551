"""What trustworthy checkpoints cost: a TAC member's checkpoint at the default
interval (50,000 steps: a 50,000-transition replay chunk and the state), written durably
(synced files and folder, SHA-256 of each file, the manifest) and written plainly (a temporary
name and a rename, as before), in turns, against the time the loop takes to train those 50,000
steps, measured in the same process. The durable write's extra time must stay under 2 % of it.

HalfCheetah-v4 (17 observations, 6 actions), the paper's networks, eager update, one thread;
the files go to pytest's temporary folder (a real disk where /tmp is one; tmpfs syncs nothing).
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from pytest_benchmark.fixture import BenchmarkFixture

from tacbench import training
from tacbench.config import RunConfig
from tacbench.tac import ReplayBuffer, TacAgent
from tacbench.training.checkpoint import MemberState, write_checkpoint

pytestmark = pytest.mark.bench

ENV, OBS, ACT = "HalfCheetah-v4", 17, 6
INTERVAL = RunConfig.__dataclass_fields__["checkpoint_every"].default  # 50,000
ROUNDS, TRAIN_STEPS = 5, 1000


def _member() -> tuple[MemberState, ReplayBuffer]:
    """A member's state and a buffer holding one interval of (synthetic) transitions."""
    config = RunConfig(env=ENV, q=1.5, alpha=0.2, compile="off")
    agent = TacAgent(OBS, ACT, config, [0], torch.device("cpu"))
    buffer = ReplayBuffer(1, OBS, ACT, capacity=1_000_000)
    rng = np.random.default_rng(0)
    buffer.start_episodes([0], rng.normal(size=(1, OBS)))
    ends = np.zeros(1)
    for t in range(INTERVAL):
        ends[0] = (t + 1) % 1000 == 0
        action, obs = rng.uniform(-1, 1, (1, ACT)), rng.normal(size=(1, OBS))
        buffer.add(action, rng.normal(size=1), ends, obs)
        if ends[0]:
            buffer.start_episodes([0], rng.normal(size=(1, OBS)))
    state = MemberState(
        step=INTERVAL,
        agent=agent.member_state(0),
        buffer=buffer.counters(0),
        rng=rng.bit_generator.state,
        env=None,
        obs=torch.zeros(OBS),
        episode_return=0.0,
        episode_length=0,
        loss_sum=torch.zeros(8),
        loss_count=0,
        updates_started=True,
        wall_s=0.0,
    )
    return state, buffer


def _plain(folder: Path, state: MemberState, buffer: ReplayBuffer) -> None:
    """The same files written without durability: a temporary name and a rename, no sync and
    no checksum."""
    (folder / "replay").mkdir(parents=True)
    chunk = folder / "replay" / f"000000000000-{INTERVAL:012d}.npz"
    with chunk.with_suffix(".tmp").open("wb") as handle:
        buffer.save_chunk(0, handle, 0, 0)
    chunk.with_suffix(".tmp").replace(chunk)
    torch.save(state.to_dict(), folder / "state.pt.tmp")
    (folder / "state.pt.tmp").replace(folder / "state.pt")


def _seconds_per_step(out: Path) -> float:
    """The training loop's time per step after learning starts (median of rounds)."""
    config = RunConfig(
        env=ENV,
        q=1.5,
        alpha=0.2,
        compile="off",
        learning_starts=1000,
        eval_every=0,
        checkpoint_every=0,
        total_steps=10**6,
    )
    times = []
    with training.stepper([config], out) as advance:
        advance(config.learning_starts + 10)
        for _ in range(ROUNDS):
            t0 = time.perf_counter()
            advance(TRAIN_STEPS // ROUNDS)
            times.append((time.perf_counter() - t0) / (TRAIN_STEPS // ROUNDS))
    return statistics.median(times)


def test_durable_checkpoint_costs_under_2_percent_of_training(
    benchmark: BenchmarkFixture, tmp_path: Path
) -> None:
    state, buffer = _member()
    rounds = iter(range(10**6))

    def fresh() -> tuple[tuple[Any, ...], dict[str, Any]]:
        folder = tmp_path / f"durable{next(rounds)}"
        return (folder, state, buffer, 0, (0, 0), [], {}), {}  # no CSVs to record

    benchmark.pedantic(write_checkpoint, setup=fresh, rounds=ROUNDS, iterations=1)
    if benchmark.disabled:  # --benchmark-disable (CI): the write ran once, untimed
        assert any((tmp_path / "durable0").rglob("state-*.pt"))
        return
    durable = benchmark.stats.stats.median
    plain_times = []
    for r in range(ROUNDS):
        t0 = time.perf_counter()
        _plain(tmp_path / f"plain{r}", state, buffer)
        plain_times.append(time.perf_counter() - t0)
    plain = statistics.median(plain_times)
    with tempfile.TemporaryDirectory() as out:
        training_s = INTERVAL * _seconds_per_step(Path(out))
    extra = (durable - plain) / training_s
    size = sum(p.stat().st_size for p in (tmp_path / "durable0").rglob("*") if p.is_file())
    benchmark.extra_info.update(
        durable_s=durable,
        plain_s=plain,
        interval_training_s=training_s,
        extra_fraction=extra,
        checkpoint_bytes=size,
    )
    print(
        f"\ncheckpoint of {size / 1e6:.1f} MB: durable {durable * 1e3:.1f} ms, plain "
        f"{plain * 1e3:.1f} ms; {INTERVAL:,} steps of training {training_s:.1f} s; "
        f"extra {100 * extra:.3f} % of training"
    )
    assert extra < 0.02
