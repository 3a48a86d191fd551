"""MLPs with a leading member dimension K: K independent networks evaluated by batched products.

Every weight is shaped ``(K, in, out)`` and every bias ``(K, 1, out)``; inputs are ``(K, B, in)``
and one ``torch.baddbmm`` per layer computes all members at once. Member k's initial weights
are drawn from member k's own generator only, so they do not depend on the other members.
Initialisation is the reference code's (TensorFlow ``tf.layers.dense``): Glorot-uniform
weights and zero biases.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

import torch
from torch import nn


def glorot_uniform(n_in: int, n_out: int, generators: Sequence[torch.Generator]) -> torch.Tensor:
    """``(K, n_in, n_out)`` weights, member k's drawn U(-l, l), l = sqrt(6 / (n_in + n_out)),
    from ``generators[k]``."""
    limit = math.sqrt(6.0 / (n_in + n_out))
    draws = [torch.rand(n_in, n_out, generator=g) for g in generators]
    return (torch.stack(draws) * 2.0 - 1.0) * limit


class BatchedMLP(nn.Module):
    """``sizes[0] -> ... -> sizes[-1]`` with ReLU between layers, for K members at once."""

    def __init__(self, sizes: Sequence[int], generators: Sequence[torch.Generator]) -> None:
        super().__init__()
        n_members = len(generators)
        self.weights = nn.ParameterList(
            nn.Parameter(glorot_uniform(n_in, n_out, generators))
            for n_in, n_out in itertools.pairwise(sizes)
        )
        self.biases = nn.ParameterList(
            nn.Parameter(torch.zeros(n_members, 1, n_out)) for n_out in sizes[1:]
        )

    def forward(self, x: torch.Tensor, *, frozen: bool = False) -> torch.Tensor:
        """``(K, B, in) -> (K, B, out)``. ``frozen=True`` uses detached weights, so gradients
        reach the input but not this network's parameters."""
        last = len(self.weights) - 1
        for i, (weight, bias) in enumerate(zip(self.weights, self.biases, strict=True)):
            if frozen:
                weight, bias = weight.detach(), bias.detach()
            x = torch.baddbmm(bias, x, weight)
            if i < last:
                x = torch.relu(x)
        return x


class Critic(nn.Module):
    """A state value V(s) (``act_dim = 0``) or an action value Q(s, a), per member."""

    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        hidden: Sequence[int],
        generators: Sequence[torch.Generator],
    ) -> None:
        super().__init__()
        self.net = BatchedMLP([obs_dim + act_dim, *hidden, 1], generators)

    def forward(
        self, obs: torch.Tensor, action: torch.Tensor | None = None, *, frozen: bool = False
    ) -> torch.Tensor:
        """``(K, B, obs_dim)`` [and ``(K, B, act_dim)``] -> ``(K, B)``."""
        x = obs if action is None else torch.cat([obs, action], dim=-1)
        return self.net(x, frozen=frozen).squeeze(-1)


class TanhGaussianPolicy(nn.Module):
    """The mean and log standard deviation of a Gaussian that a tanh squashes into [-1, 1]^A.

    log_std comes from a tanh head rescaled to ``[log_std_min, log_std_max]`` (reference code).
    """

    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        hidden: Sequence[int],
        generators: Sequence[torch.Generator],
        log_std_min: float,
        log_std_max: float,
    ) -> None:
        super().__init__()
        self.net = BatchedMLP([obs_dim, *hidden, 2 * act_dim], generators)
        self.log_std_min = log_std_min
        self.log_std_max = log_std_max

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(K, B, obs_dim)`` -> mean ``mu`` and ``log_std``, each ``(K, B, act_dim)``."""
        mu, raw = self.net(obs).chunk(2, dim=-1)
        span = self.log_std_max - self.log_std_min
        log_std = self.log_std_min + 0.5 * span * (torch.tanh(raw) + 1.0)
        return mu, log_std
