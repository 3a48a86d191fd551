"""Tsallis Actor-Critic (paper section 6): networks, losses, agent and replay buffer, no I/O."""

from tacbench.tac.agent import METRICS, TacAgent
from tacbench.tac.buffer import ReplayBuffer
from tacbench.tac.losses import Batch, TacLosses, tac_losses

__all__ = ["METRICS", "Batch", "ReplayBuffer", "TacAgent", "TacLosses", "tac_losses"]
