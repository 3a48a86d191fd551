"""What the adapters build (networks, noise, buffer, env wrappers) and the losses logger."""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch
from stable_baselines3.common.noise import NormalActionNoise
from stable_baselines3.common.vec_env import VecNormalize
from torch import nn

from baselines import algos
from baselines.callbacks import LossLogger
from baselines.config import BaselineConfig, make_configs

pytestmark = pytest.mark.unit


def _config(algo: str, *hp: str, env: str = "Hopper-v4", **settings: Any) -> BaselineConfig:
    return make_configs(algo, env, "Hopper", [3], list(hp), **settings)[0][0]


def _layers(module: nn.Module) -> list[tuple[int, int]]:
    return [(m.in_features, m.out_features) for m in module.modules() if isinstance(m, nn.Linear)]


def _activations(module: nn.Module) -> set[type[nn.Module]]:
    return {type(m) for m in module.modules() if isinstance(m, nn.ReLU | nn.Tanh)}


@pytest.fixture(scope="module")
def models() -> dict[str, Any]:
    torch.set_num_threads(1)
    built = {}
    for algo in algos.ALGORITHMS:
        config = _config(algo, total_steps=5000)
        _, venv = algos.make_training_env(config)
        built[algo] = (config, algos.build_model(config, venv), venv)
    return built


def test_networks_have_the_tables_sizes(models: dict[str, Any]) -> None:
    obs, act = 11, 3  # Hopper
    ddpg = models["ddpg"][1]
    assert _layers(ddpg.actor.mu) == [(obs, 300), (300, act)]
    assert _layers(ddpg.critic) == [(obs + act, 300), (300, 1)]  # one critic
    assert _activations(ddpg.actor.mu) == {nn.ReLU, nn.Tanh}  # tanh: the output squashing
    td3 = models["td3"][1]
    assert _layers(td3.actor.mu) == [(obs, 400), (400, 300), (300, act)]
    assert _layers(td3.critic) == [(obs + act, 400), (400, 300), (300, 1)] * 2
    sac = models["sac-sb3"][1]
    assert _layers(sac.actor.latent_pi) == [(obs, 300)]
    assert _layers(sac.critic) == [(obs + act, 300), (300, 1)] * 2
    for algo in ("ppo", "trpo"):
        extractor = models[algo][1].policy.mlp_extractor
        assert _layers(extractor.policy_net) == [(obs, 64), (64, 64)]
        assert _layers(extractor.value_net) == [(obs, 64), (64, 64)]
        assert _activations(extractor) == {nn.Tanh}


def test_model_arguments_follow_the_table(models: dict[str, Any]) -> None:
    td3 = models["td3"][1]
    assert td3.learning_rate == 1e-3  # the default section (RL Zoo's MuJoCo v4 value)
    assert td3.learning_starts == 10_000 and td3.batch_size == 256
    assert td3.replay_buffer.buffer_size == 5000  # capped at the run's steps, as TAC
    assert isinstance(td3.action_noise, NormalActionNoise)
    assert td3.action_noise._sigma.tolist() == [0.1] * 3
    sac = models["sac-sb3"][1]
    assert float(sac.ent_coef_tensor) == pytest.approx(0.2) and sac.ent_coef_optimizer is None
    assert sac.batch_size == 100 and sac.learning_rate == 1e-3
    ppo = models["ppo"][1]
    assert (ppo.n_steps, ppo.batch_size, ppo.n_epochs, ppo.gamma) == (2048, 64, 10, 0.99)
    assert models["ppo"][2].__class__ is VecNormalize and models["ppo"][2].gamma == 0.99
    assert models["trpo"][1].n_critic_updates == 20
    quiet = algos.build_model(*_env_model(_config("ddpg", "noise_type=none")))
    assert quiet.action_noise is None


def _env_model(config: BaselineConfig) -> tuple[BaselineConfig, Any]:
    return config, algos.make_training_env(config)[1]


def test_training_env_records_episodes_in_float64_and_observes_float32() -> None:
    config = _config("td3")
    dummy, venv = algos.make_training_env(config)
    assert venv is dummy  # no VecNormalize off-policy
    assert venv.observation_space.dtype == np.float32
    venv.seed(0)
    obs = venv.reset()
    assert obs.dtype == np.float32
    rewards: list[float] = []
    done, info = False, {}
    while not done:
        obs, reward, dones, infos = venv.step(np.zeros((1, 3)))
        rewards.append(float(reward[0]))  # float32 in the VecEnv
        done, info = bool(dones[0]), infos[0]
    assert info["episode"]["l"] == len(rewards) > 1
    assert isinstance(info["episode"]["r"], float)
    assert info["episode"]["r"] == pytest.approx(sum(rewards), rel=1e-6)
    assert algos.recorder(dummy).episode_length == 0  # reset by the auto-reset


def test_loss_columns_leave_out_what_the_config_never_logs() -> None:
    assert "ent_coef_loss" not in algos.loss_columns(_config("sac-sb3"))
    assert "ent_coef_loss" in algos.loss_columns(_config("sac-sb3", "ent_coef=auto"))
    assert "clip_range_vf" not in algos.loss_columns(_config("ppo"))
    assert "clip_range_vf" in algos.loss_columns(_config("ppo", "clip_range_vf=0.2"))
    assert algos.loss_columns(_config("td3")) == algos.LOSS_COLUMNS["td3"]


def test_loss_logger_averages_train_values_between_rows() -> None:
    logger = LossLogger(("n_updates", "actor_loss", "critic_loss"))
    assert logger.pop_row() is None
    for n, (actor, critic) in enumerate([(1.0, 4.0), (3.0, 8.0)], start=1):
        logger.record("train/n_updates", n)
        logger.record("train/critic_loss", critic)
        logger.record("train/actor_loss", actor)
        logger.record("rollout/ep_rew_mean", 99.0)  # not a train/ value: ignored
    saved = logger.state()
    assert logger.pop_row() == [2.0, 2.0, 6.0]  # n_updates: the running total, not a mean
    assert logger.pop_row() is None
    logger.load_state(saved)
    assert logger.pop_row() == [2.0, 2.0, 6.0]
    logger.record("train/critic_loss", 1.0)
    row = logger.pop_row()
    assert row is not None and math.isnan(row[0]) and math.isnan(row[1]) and row[2] == 1.0
    logger.record("train/something_new", 1.0)
    assert logger.unknown == {"something_new"}
    logger.record("train/critic_loss", float("inf"))
    logger.record("train/n_updates", float("nan"))  # only losses count as divergence
    assert logger.non_finite == ["critic_loss"]


class _Rewards(gym.Env[np.ndarray, np.ndarray]):
    """An episode of the given rewards, one per step."""

    observation_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)

    def __init__(self, rewards: list[float]) -> None:
        self.rewards, self.t = rewards, 0

    def reset(self, *, seed: int | None = None, options: Any = None) -> tuple[np.ndarray, dict]:
        self.t = 0
        return np.zeros(1, np.float32), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        self.t += 1
        return (
            np.zeros(1, np.float32),
            self.rewards[self.t - 1],
            self.t == len(self.rewards),
            False,
            {},
        )


def test_the_recorder_sums_the_raw_rewards_in_float64() -> None:
    """Exactly Python's float64 sum of the env's own rewards: values that float32 would round
    (0.1, 1 + 1e-7, 1e-9), and a sum past 2**24, where float32 accumulation loses a 1."""
    rewards = [0.1, 1.0000001, 1e-9, 2.3, 0.3, 2.0**24, 1.0]
    recorder = algos.EpisodeRecorder(_Rewards(rewards))
    recorder.reset()
    for _ in rewards:
        *_, info = recorder.step(np.zeros(1, np.float32))
    assert info["episode"] == {"r": sum(rewards), "l": len(rewards)}
    float32_sum = np.float32(0.0)
    for reward in rewards:
        float32_sum += np.float32(reward)
    assert info["episode"]["r"] != float(float32_sum)
