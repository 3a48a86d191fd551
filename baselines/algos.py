"""Building a stable-baselines3 / sb3-contrib model and its training environment from a config.

The training environment is the task from :func:`tacbench.envs.make_env` (as TAC's), with
float32 observations (what the networks compute in, and half the replay memory) and an
:class:`EpisodeRecorder`, in a one-env ``DummyVecEnv``; with ``normalize`` (on-policy tables) it
is wrapped in SB3's ``VecNormalize``. Nothing in SB3 is patched: every choice goes through the
constructors' arguments.
"""

from __future__ import annotations

from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from sb3_contrib import TRPO
from stable_baselines3 import DDPG, PPO, SAC, TD3
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.noise import NormalActionNoise
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecNormalize
from torch import nn

from baselines import hyperparams
from baselines.config import BaselineConfig
from tacbench import envs
from tacbench.seeding import run_streams

ALGORITHMS: dict[str, type[BaseAlgorithm]] = {
    "ddpg": DDPG,
    "td3": TD3,
    "sac-sb3": SAC,
    "ppo": PPO,
    "trpo": TRPO,
}
DISPLAY_NAMES = {"ddpg": "DDPG", "td3": "TD3", "sac-sb3": "SAC (SB3)", "ppo": "PPO", "trpo": "TRPO"}
ACTIVATIONS: dict[str, type[nn.Module]] = {
    "relu": nn.ReLU,
    "tanh": nn.Tanh,
    "elu": nn.ELU,
    "leaky_relu": nn.LeakyReLU,
}

# losses.csv columns: what each algorithm's train() records under "train/" (SB3 2.9 sources),
# averaged over the updates since the previous row (n_updates: the running total).
_OFF_POLICY_COLUMNS = ("n_updates", "learning_rate", "actor_loss", "critic_loss")
LOSS_COLUMNS: dict[str, tuple[str, ...]] = {
    "ddpg": _OFF_POLICY_COLUMNS,
    "td3": _OFF_POLICY_COLUMNS,
    "sac-sb3": (*_OFF_POLICY_COLUMNS, "ent_coef", "ent_coef_loss"),
    "ppo": (
        "n_updates",
        "learning_rate",
        "entropy_loss",
        "policy_gradient_loss",
        "value_loss",
        "loss",
        "approx_kl",
        "clip_fraction",
        "clip_range",
        "clip_range_vf",
        "explained_variance",
        "std",
    ),
    "trpo": (
        "n_updates",
        "learning_rate",
        "policy_objective",
        "value_loss",
        "kl_divergence_loss",
        "is_line_search_success",
        "explained_variance",
        "std",
    ),
}


class Float32Observation(gym.ObservationWrapper):
    """Observations as float32, the precision SB3's networks use anyway (so learning is
    unchanged) and half the replay buffer's memory."""

    def __init__(self, env: gym.Env[Any, Any]) -> None:
        super().__init__(env)
        space = env.observation_space
        assert isinstance(space, gym.spaces.Box)
        self.observation_space = gym.spaces.Box(
            space.low.astype(np.float32), space.high.astype(np.float32), dtype=np.float32
        )

    def observation(self, observation: Any) -> Any:
        """The observation as float32."""
        return np.asarray(observation, dtype=np.float32)


class EpisodeRecorder(gym.Wrapper):
    """Sums each episode's rewards (float64, before any normalisation) and counts its steps; at
    the episode's end adds them to ``info["episode"]`` as SB3's Monitor does (``r``, ``l``)."""

    def __init__(self, env: gym.Env[Any, Any]) -> None:
        super().__init__(env)
        self.episode_return = 0.0
        self.episode_length = 0

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        """Reset the env and the sums."""
        self.episode_return, self.episode_length = 0.0, 0
        return self.env.reset(**kwargs)

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        """Step the env; report the finished episode in ``info["episode"]``."""
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.episode_return += float(reward)
        self.episode_length += 1
        if terminated or truncated:
            info = {**info, "episode": {"r": self.episode_return, "l": self.episode_length}}
        return obs, reward, terminated, truncated, info


def loss_columns(config: BaselineConfig) -> tuple[str, ...]:
    """losses.csv's columns for ``config``: :data:`LOSS_COLUMNS`, less the ones SB3 only logs for
    settings this config does not use (a learned ent_coef, a value-clipping range)."""
    hp = config.hyperparams
    unused = set()
    if not str(hp.get("ent_coef", "")).startswith("auto"):
        unused.add("ent_coef_loss")
    if hp.get("clip_range_vf") is None:
        unused.add("clip_range_vf")
    return tuple(c for c in LOSS_COLUMNS[config.algo] if c not in unused)


def make_training_env(config: BaselineConfig) -> tuple[DummyVecEnv, VecEnv]:
    """The one-env vectorised training environment: (the DummyVecEnv, the env to train on)."""

    def factory() -> gym.Env[Any, Any]:
        return EpisodeRecorder(Float32Observation(envs.make_env(config.env)))

    dummy = DummyVecEnv([factory])
    if config.hyperparams.get("normalize"):
        # RL Zoo's `normalize: true`; the reward scale follows the algorithm's discount
        return dummy, VecNormalize(dummy, gamma=config.hyperparams["gamma"])
    return dummy, dummy


def recorder(dummy: DummyVecEnv) -> EpisodeRecorder:
    """The :class:`EpisodeRecorder` of the training env."""
    env = dummy.envs[0]
    assert isinstance(env, EpisodeRecorder)
    return env


def _action_noise(config: BaselineConfig, act_dim: int) -> NormalActionNoise | None:
    """Gaussian exploration noise (RL Zoo's MuJoCo choice). Ornstein-Uhlenbeck noise is not
    offered: SB3 resets its state at every ``learn`` call, so a resumed run would differ."""
    if config.hyperparams["noise_type"] == "none":
        return None
    std = config.hyperparams["noise_std"]
    return NormalActionNoise(mean=np.zeros(act_dim), sigma=std * np.ones(act_dim))


def model_arguments(config: BaselineConfig, act_dim: int) -> dict[str, Any]:
    """The SB3 constructor's keyword arguments for ``config`` (all but policy and env)."""
    kwargs: dict[str, Any] = {}
    policy: dict[str, Any] = {}
    for key, value in config.hyperparams.items():
        target = hyperparams.spec(config.algo, key).target
        if target == "model":
            kwargs[key] = tuple(value) if key == "train_freq" and isinstance(value, list) else value
        elif target == "policy":
            policy[key] = ACTIVATIONS[value] if key == "activation_fn" else value
    if config.off_policy:
        # never more than the run's steps, as TAC: the same buffer, less memory reserved
        kwargs["buffer_size"] = min(kwargs["buffer_size"], config.total_steps)
        if config.algo != "sac-sb3":
            kwargs["action_noise"] = _action_noise(config, act_dim)
    seed = run_streams(config.seed).torch_seed % 2**32  # SB3 seeds NumPy's legacy generator too
    return {**kwargs, "policy_kwargs": policy, "seed": seed, "device": config.device}


def build_model(config: BaselineConfig, venv: VecEnv) -> BaseAlgorithm:
    """A fresh SB3 model for ``config`` on ``venv``, with the run's independent random streams
    (:func:`tacbench.seeding.run_streams`): SB3 seeds its global generators, its action space
    (the off-policy warm-up's random actions) and the env's resets from one number, so the
    action space and the env get their own streams afterwards."""
    space = venv.action_space
    assert isinstance(space, gym.spaces.Box)
    model = ALGORITHMS[config.algo]("MlpPolicy", venv, **model_arguments(config, space.shape[0]))
    streams = run_streams(config.seed)
    model.action_space.seed(int(streams.numpy.generate_state(1, dtype=np.uint32)[0]))
    venv.seed(streams.env_seed)
    return model
