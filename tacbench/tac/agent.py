"""The TAC agent for K members: five networks, one Adam, act / update / per-member state. No I/O.

Member k has its own ``torch.Generator`` seeded with its seed alone. It draws member k's initial
weights (policy, Q1, Q2, V, in that order; the target V starts as a copy of V), its exploration
noise and its reparameterisation noise, so none of these depend on the other members. The noise
is drawn on the CPU and moved to the device, so a seed draws the same numbers on every device.
"""

from __future__ import annotations

import copy
from collections.abc import Iterator, Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt
import torch

from tacbench.config import RunConfig
from tacbench.tac.losses import DIAGNOSTICS, Batch, tac_losses
from tacbench.tac.networks import Critic, TanhGaussianPolicy

LOSSES = ("loss_q1", "loss_q2", "loss_v", "loss_pi")
METRICS = LOSSES + DIAGNOSTICS  # the columns of TacAgent.update's result


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
        hidden, gens = config.hidden_sizes, self.generators
        self.policy = TanhGaussianPolicy(
            obs_dim, act_dim, hidden, gens, config.log_std_min, config.log_std_max
        ).to(device)
        self.q1 = Critic(obs_dim, act_dim, hidden, gens).to(device)
        self.q2 = Critic(obs_dim, act_dim, hidden, gens).to(device)
        self.v = Critic(obs_dim, 0, hidden, gens).to(device)
        self.v_target = copy.deepcopy(self.v).requires_grad_(False)
        self.optimizer = torch.optim.Adam(
            [p for net in (self.policy, self.q1, self.q2, self.v) for p in net.parameters()],
            lr=config.learning_rate,
        )
        self.alive = torch.ones(len(seeds), dtype=torch.bool, device=device)

    @property
    def n_members(self) -> int:
        """K, the number of members."""
        return len(self.generators)

    def _noise(self, *shape: int) -> torch.Tensor:
        """Standard normal ``(K, *shape)``, member k's slice from member k's generator."""
        draws = [torch.randn(*shape, generator=g) for g in self.generators]
        return torch.stack(draws).to(self.device)

    def _tensor(self, array: npt.ArrayLike) -> torch.Tensor:
        return torch.as_tensor(np.asarray(array, dtype=np.float32), device=self.device)

    @torch.no_grad()
    def act(self, obs: npt.ArrayLike) -> npt.NDArray[np.float32]:
        """Exploration actions in [-1, 1]: ``(K, obs_dim) -> (K, act_dim)``, sampled from pi."""
        mu, log_std = self.policy(self._tensor(obs)[:, None])
        action = torch.tanh(mu + self._noise(1, self.act_dim) * log_std.exp())
        return action[:, 0].cpu().numpy()

    @torch.no_grad()
    def act_deterministic(self, obs: npt.ArrayLike) -> npt.NDArray[np.float32]:
        """Evaluation actions ``tanh(mu)`` in [-1, 1]: ``(K, n, obs_dim) -> (K, n, act_dim)``."""
        mu, _ = self.policy(self._tensor(obs))
        return torch.tanh(mu).cpu().numpy()

    def update(self, batch: Mapping[str, npt.ArrayLike], q: float) -> torch.Tensor:
        """One gradient step for every live member on its own minibatch ``(K, B, ...)``.

        Returns the detached metrics ``(K, len(METRICS))``. A member marked dead (``alive``
        False) contributes nothing to the step of the others.
        """
        tensors = Batch(*(self._tensor(batch[name]) for name in Batch._fields))
        eps = self._noise(tensors.action.shape[1], self.act_dim)
        losses = tac_losses(
            self.policy,
            self.q1,
            self.q2,
            self.v,
            self.v_target,
            tensors,
            eps,
            q=q,
            alpha=self.config.alpha,
            gamma=self.config.gamma,
            lnq=self.config.lnq,
        )
        per_member = torch.stack([losses.q1, losses.q2, losses.v, losses.pi], dim=-1)
        total = torch.where(self.alive, per_member.sum(dim=-1), 0.0).sum()
        self.optimizer.zero_grad(set_to_none=True)
        total.backward()
        self.optimizer.step()
        with torch.no_grad():  # target V: psi- <- (1 - tau) psi- + tau psi (paper appendix)
            for target, source in zip(self.v_target.parameters(), self.v.parameters(), strict=True):
                target.lerp_(source, self.config.tau)
        return torch.cat([per_member.detach(), losses.diagnostics], dim=-1)

    # --- per-member state (checkpoints hold one member each) ----------------------------------

    def _named_parameters(self) -> Iterator[tuple[str, torch.nn.Parameter]]:
        for prefix, net in (
            ("policy", self.policy),
            ("q1", self.q1),
            ("q2", self.q2),
            ("v", self.v),
            ("v_target", self.v_target),
        ):
            for name, param in net.named_parameters():
                yield f"{prefix}.{name}", param

    def member_state(self, k: int) -> dict[str, Any]:
        """Member k's weights, Adam moments and generator, as CPU tensors."""
        params = {name: p[k].detach().cpu().clone() for name, p in self._named_parameters()}
        adam = [
            {
                key: value[k].cpu().clone() if value.ndim > 0 else value.cpu().clone()
                for key, value in self.optimizer.state[p].items()
            }
            for p in self.optimizer.param_groups[0]["params"]
            if p in self.optimizer.state
        ]
        return {"params": params, "adam": adam, "generator": self.generators[k].get_state()}

    def load_member_states(self, states: Sequence[Mapping[str, Any]]) -> None:
        """Load one :meth:`member_state` per member (their Adam step counts must agree)."""
        with torch.no_grad():
            for name, param in self._named_parameters():
                param.copy_(torch.stack([s["params"][name] for s in states]).to(self.device))
        params = self.optimizer.param_groups[0]["params"]
        for i, param in enumerate(params[: len(states[0]["adam"])]):
            entry: dict[str, torch.Tensor] = {}
            for key, first in states[0]["adam"][i].items():
                values = [s["adam"][i][key] for s in states]
                if first.ndim > 0:
                    entry[key] = torch.stack(values).to(self.device)
                else:
                    if any(not torch.equal(v, first) for v in values):
                        raise ValueError("members have different Adam step counts")
                    entry[key] = first.clone()
            self.optimizer.state[param] = entry
        for generator, state in zip(self.generators, states, strict=True):
            generator.set_state(state["generator"])
