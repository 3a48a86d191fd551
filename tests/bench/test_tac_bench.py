"""TAC microbenchmarks: one update, one act, one replay sample, one evaluation round.

HalfCheetah-v4 sizes (17 observations, 6 actions), the paper's networks (one hidden layer of
300), batch 100, at K = 1 and K = 10 members; the update eager and under torch.compile. Run
with ``tox -e bench``, which compares them with the saved baseline in ``tests/bench/baseline``
(docs/performance.md says how to save a new one).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch
from pytest_benchmark.fixture import BenchmarkFixture

from tacbench import envs
from tacbench.config import RunConfig
from tacbench.paper import Q_GRID, SEEDS
from tacbench.tac import METRICS, ReplayBuffer, TacAgent, coefficients
from tacbench.tac.update import update
from tests.helpers import tac_agent

pytestmark = pytest.mark.bench

ENV = "HalfCheetah-v4"
OBS, ACT, BATCH = 17, 6, 100
FILLED = 5000  # transitions in the buffer


def _agent(k: int, compile: bool = False) -> TacAgent:
    """K members (seeds 0, 10, ...) with the paper's networks."""
    mode = "on" if compile else "off"
    return tac_agent(OBS, ACT, range(0, 10 * k, 10), env=ENV, hidden_sizes=None, compile=mode)


def _buffer(k: int) -> tuple[ReplayBuffer, list[np.random.Generator]]:
    buffer = ReplayBuffer(k, OBS, ACT, capacity=100_000)
    rng = np.random.default_rng(0)
    buffer.start_episodes(range(k), rng.normal(size=(k, OBS)))
    for _ in range(FILLED):
        buffer.add(
            rng.uniform(-1, 1, (k, ACT)), rng.normal(size=k), np.zeros(k), rng.normal(size=(k, OBS))
        )
    return buffer, [np.random.default_rng(seed) for seed in range(k)]


@pytest.mark.parametrize("k", [1, 10])
@pytest.mark.parametrize("path", ["eager", "compiled"])
def test_update(benchmark: BenchmarkFixture, path: str, k: int) -> None:
    agent = _agent(k, compile=path == "compiled")
    buffer, rngs = _buffer(k)
    batch = buffer.sample(rngs, BATCH)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # torch.compile's notes while compiling
        c = coefficients([1.5] * k, [0.2] * k, torch.device("cpu"))
        for _ in range(3):  # compile, allocate
            update(agent, batch, c)
    metrics = benchmark(update, agent, batch, c)
    assert metrics.shape == (k, len(METRICS))
    assert torch.isfinite(metrics).all()


@pytest.mark.parametrize("k", [1, 10])
def test_act(benchmark: BenchmarkFixture, k: int) -> None:
    agent = _agent(k)
    obs = np.random.default_rng(0).normal(size=(k, OBS))
    action = benchmark(agent.act, obs)
    assert action.shape == (k, ACT)
    assert np.abs(action).max() <= 1.0


@pytest.mark.parametrize("k", [1, 10])
def test_sample(benchmark: BenchmarkFixture, k: int) -> None:
    buffer, rngs = _buffer(k)
    batch = benchmark(buffer.sample, rngs, BATCH)
    assert batch["obs"].shape == batch["next_obs"].shape == (k, BATCH, OBS)
    assert batch["action"].shape == (k, BATCH, ACT)
    assert np.isin(batch["obs"][0], buffer.rows[0]).all()


def test_evaluation_round(benchmark: BenchmarkFixture) -> None:
    """The reference protocol at K = 1: 10 deterministic 1,000-step episodes, stepped in
    lockstep with one batched policy call per step."""
    agent, info = _agent(1), envs.env_info(ENV)
    eval_envs = [envs.make_env(ENV) for _ in range(10)]

    def policy(obs: np.ndarray) -> np.ndarray:
        return envs.to_env_action(agent.act_deterministic(obs[None])[0], info)

    try:
        returns, lengths = benchmark.pedantic(
            envs.evaluate,
            args=(policy, eval_envs, envs.eval_seeds(0, 5000, 10)),
            rounds=3,
            iterations=1,
        )
    finally:
        for env in eval_envs:
            env.close()
    assert (lengths == info.max_episode_steps).all()
    assert np.isfinite(returns).all()


def test_q_grid_update(benchmark: BenchmarkFixture) -> None:
    """One compiled update of the paper's q grid of one task as one process: 9 q x 10 seeds,
    90 members in chunks of 10 (docs/performance.md, "Grid members")."""
    qs = [q for q in Q_GRID for _ in SEEDS]
    k = len(qs)
    agent = _agent(k, compile=True)
    buffer, rngs = _buffer(k)
    batch = buffer.sample(rngs, BATCH)
    c = coefficients(qs, [0.2] * k, torch.device("cpu"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # torch.compile's notes while compiling
        for _ in range(3):
            update(agent, batch, c)
    metrics = benchmark(update, agent, batch, c)
    assert metrics.shape == (k, len(METRICS)) and torch.isfinite(metrics).all()


@pytest.mark.parametrize("due", ["one", "all"])
def test_episode_schedule_round(benchmark: BenchmarkFixture, due: str) -> None:
    """One update round of the reference profile's episode schedule ((400, 300) networks),
    5 members, with one member due (Hopper: the members' episodes end at different steps) or
    all five (HalfCheetah: every episode is 1,000 steps). A round trains only the chunks of
    the members that are due, so the first costs about a fifth of the second."""
    k = 5
    config = RunConfig(env=ENV, q=1.0, alpha=0.2, compile="off", profile="reference")
    agent = TacAgent(OBS, ACT, config, list(range(0, 10 * k, 10)), torch.device("cpu"))
    buffer, rngs = _buffer(k)
    batch = buffer.sample(rngs, BATCH)
    c = coefficients([1.0] * k, [0.2] * k, torch.device("cpu"))
    members = [True] * k if due == "all" else [True] + [False] * (k - 1)
    update(agent, batch, c, members)
    metrics = benchmark(update, agent, batch, c, members)
    assert torch.isfinite(metrics).all()
    assert (metrics[~torch.as_tensor(members)] == 0).all()
