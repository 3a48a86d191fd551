"""Baseline algorithms (DDPG, TD3, SAC, PPO, TRPO) from stable-baselines3 and sb3-contrib."""
