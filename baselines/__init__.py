"""Baseline algorithms (DDPG, TD3, SAC, PPO, TRPO) from stable-baselines3 and sb3-contrib.

They train into the same run directories as TAC, under the same evaluation protocol, seeds and
resume semantics (docs/baselines.md). The package imports nothing heavy at import time, so the
CLI can name the algorithms without loading torch.
"""

from baselines.hyperparams import ALGOS, OFF_POLICY

__all__ = ["ALGOS", "OFF_POLICY"]
