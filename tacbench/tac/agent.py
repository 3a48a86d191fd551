"""The TAC agent for K members: act, update, per-member state. No I/O.

Member k has its own ``torch.Generator`` seeded with its seed alone. It draws member k's initial
weights (:mod:`tacbench.tac.parameters`), its exploration noise and its reparameterisation noise,
so none of these depend on the other members. The noise is drawn on the CPU and moved to the
device, so a seed draws the same numbers on every device. The update itself is
:class:`tacbench.tac.update.TacUpdate` (``config.compile``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt
import torch

from tacbench.config import RunConfig
from tacbench.tac.losses import LossSettings
from tacbench.tac.maths import Batch, Coefficients
from tacbench.tac.networks import mlp, policy_head
from tacbench.tac.parameters import TacParameters
from tacbench.tac.update import TacUpdate


class TacAgent:
    """K independent TAC learners sharing one config (all but the seed) and one set of kernels."""

    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        config: RunConfig,
        seeds: Sequence[int],
        device: torch.device,
    ) -> None:
        self.config = config
        self.device = device
        self.act_dim = act_dim
        self.generators = [torch.Generator().manual_seed(int(seed)) for seed in seeds]
        self.params = TacParameters(
            obs_dim,
            act_dim,
            config.hidden_sizes,
            self.generators,
            twin_q_targets=config.critic_target == "twin-q",
            device=device,
        )
        settings = LossSettings(config.gamma, config.lnq, config.log_std_min, config.log_std_max)
        self._update = TacUpdate(
            self.params,
            settings,
            compile=config.compile == "on",
            learning_rate=config.learning_rate,
            tau=config.tau,
        )
        self.alive = torch.ones(len(seeds), dtype=torch.bool, device=device)

    def _noise(self, *shape: int) -> torch.Tensor:
        """Standard normal ``(K, *shape)``, member k's slice from member k's generator."""
        draws = [torch.randn(*shape, generator=g) for g in self.generators]
        return torch.stack(draws).to(self.device, non_blocking=True)

    def _tensor(self, array: npt.ArrayLike) -> torch.Tensor:
        """float32 on the device. The upload does not wait for the device (a blocking one
        synchronises the stream); from pageable memory it is staged before the call returns."""
        host = torch.as_tensor(np.asarray(array, dtype=np.float32))
        return host.to(self.device, non_blocking=True)

    def _policy(self, obs: npt.ArrayLike) -> tuple[torch.Tensor, torch.Tensor]:
        """The policy's ``mu`` and ``log_std``: ``(K, n, obs_dim) -> 2 x (K, n, act_dim)``."""
        out = mlp(self.params.networks.policy, self._tensor(obs))
        c = self.config
        return policy_head(out, self.act_dim, c.log_std_min, c.log_std_max)

    @torch.no_grad()
    def act(self, obs: npt.ArrayLike) -> npt.NDArray[np.float32]:
        """Exploration actions in [-1, 1]: ``(K, obs_dim) -> (K, act_dim)``, sampled from pi."""
        mu, log_std = self._policy(np.asarray(obs)[:, None])
        action = torch.tanh(mu + self._noise(1, self.act_dim) * log_std.exp())
        return action[:, 0].cpu().numpy()

    @torch.no_grad()
    def act_deterministic(self, obs: npt.ArrayLike) -> npt.NDArray[np.float32]:
        """Evaluation actions ``tanh(mu)`` in [-1, 1]: ``(K, n, obs_dim) -> (K, n, act_dim)``."""
        return torch.tanh(self._policy(obs)[0]).cpu().numpy()

    def draw_noise(self, batch_size: int) -> tuple[torch.Tensor, torch.Tensor | None]:
        """One update's reparameterisation noise ``(K, B, A)`` and, with twin-q, the noise of
        a' ~ pi(.|s') drawn after it."""
        eps = self._noise(batch_size, self.act_dim)
        twin_q = self.config.critic_target == "twin-q"
        return eps, self._noise(batch_size, self.act_dim) if twin_q else None

    def update(self, batch: Mapping[str, npt.ArrayLike], c: Coefficients) -> torch.Tensor:
        """One gradient step for every live member on its own minibatch ``(K, B, ...)``, with
        each member's q and alpha from ``c``.

        Returns the detached metrics ``(K, len(METRICS))``. A member marked dead (``alive``
        False) contributes nothing to the step of the others.
        """
        tensors = Batch(*(self._tensor(batch[name]) for name in Batch._fields))
        eps, eps_next = self.draw_noise(tensors.action.shape[1])
        return self._update(tensors, eps, self.alive, c, eps_next)

    def gradients(
        self, batch: Batch, eps: torch.Tensor, c: Coefficients, eps_next: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """The metrics of :meth:`update` and the gradient of every trained parameter (named as
        in :meth:`member_state`) for one minibatch and noise, compiled if this agent's
        update is, without changing any weight. For comparing the paths."""
        metrics = self._update.gradients(batch, eps, self.alive, c, eps_next)
        return metrics, {k: v.clone() for k, v in self.params.named_gradients().items()}

    def member_state(self, k: int) -> dict[str, Any]:
        """Member k's weights, Adam state and generator, as CPU tensors."""
        return {**self.params.member_state(k), "generator": self.generators[k].get_state()}

    def load_member_states(self, states: Sequence[Mapping[str, Any]]) -> None:
        """Load one :meth:`member_state` per member (their Adam step counts must agree)."""
        self.params.load_member_states(states)
        for generator, state in zip(self.generators, states, strict=True):
            generator.set_state(state["generator"])
