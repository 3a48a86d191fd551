"""The TAC agent for K members: act, update, per-member state. No I/O.

Member k has its own ``torch.Generator`` seeded with its seed alone. It draws member k's initial
weights (:mod:`tacbench.tac.parameters`), its exploration noise and its reparameterisation noise,
so none of these depend on the other members. The noise is drawn on the CPU and moved to the
device, so a seed draws the same numbers on every device. The update itself is
:func:`tacbench.tac.update.update`; the agent holds what it needs (the chunks, the gradient,
eager or compiled by ``config.compile``, the losses' constants, the learning rate and tau).

On a CPU the members are held in chunks of at most :data:`CPU_MEMBERS_PER_CHUNK`, each with its
own parameter buffers, updated one after the other through one shared (compiled) gradient: a
large group's activations then stay in the caches (docs/performance.md, "Grid members").
Members never interact, so this is the same computation in another order. On a GPU all members
are one chunk.

An update round skips the chunks with no member due. In the episode schedule a CPU agent holds
each member in its own chunk: on Hopper, whose members' episodes end at different steps, a
burst then costs one member's updates instead of the whole group's. Otherwise (the step
schedule, where all members are due at every step after the warm-up) the members stay grouped,
which is cheaper when all are due (docs/performance.md). Every member's numbers are the same
either way.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt
import torch

from tacbench.config import RunConfig
from tacbench.tac.gradient import Gradient, compiled_gradient, eager_gradient
from tacbench.tac.losses import LossSettings
from tacbench.tac.maths import ALPHA_METRICS, METRICS
from tacbench.tac.networks import mlp, policy_head
from tacbench.tac.parameters import TacParameters

# larger stacks cost more per member: their activations leave the caches (docs/performance.md,
# "Grid members")
CPU_MEMBERS_PER_CHUNK = 10


class Chunk(NamedTuple):
    """Some members: which ones, and their parameters."""

    members: slice
    params: TacParameters


class TacAgent:
    """K independent TAC learners sharing one config (all but q, alpha and the seed); with
    ``initial_alphas`` (--alpha auto) each learns its alpha from its initial value."""

    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        config: RunConfig,
        seeds: Sequence[int],
        device: torch.device,
        action_scale: float = 1.0,
        initial_alphas: Sequence[float] | None = None,
    ) -> None:
        self.config = config
        self.device = device
        self.act_dim = act_dim
        self.generators = [torch.Generator().manual_seed(int(seed)) for seed in seeds]
        c = config
        self.settings = loss_settings(c, action_scale)
        self.learning_rate, self.tau = c.learning_rate, c.tau
        k = len(seeds)
        most = k if device.type == "cuda" else CPU_MEMBERS_PER_CHUNK
        if device.type == "cpu" and config.update_schedule == "episode":
            most = 1  # a burst trains only the chunks of the members whose episode ended
        size = math.ceil(k / math.ceil(k / most))  # near-equal chunks: 45 members are 5 x 9
        chunks = [slice(first, min(first + size, k)) for first in range(0, k, size)]
        params = [
            TacParameters(
                obs_dim,
                act_dim,
                config.hidden_sizes,
                self.generators[members],
                twin_q_targets=config.critic_target == "twin-q",
                device=device,
                per_member_steps=config.per_member_updates,
                initial_alphas=None if initial_alphas is None else initial_alphas[members],
            )
            for members in chunks
        ]
        self.gradient: Gradient = eager_gradient  # one (compiled) gradient for every chunk
        if config.compile == "on":
            static = [t for p in params for t in (p.data, p.target)]
            self.gradient = compiled_gradient(device, static)
        self.chunks = [Chunk(members, p) for members, p in zip(chunks, params, strict=True)]
        self.alive = torch.ones(k, dtype=torch.bool, device=device)
        learns_alpha = initial_alphas is not None
        self.metric_names = METRICS + ALPHA_METRICS if learns_alpha else METRICS

    def _noise(self, *shape: int, members: Sequence[bool] | None = None) -> torch.Tensor:
        """Standard normal ``(K, *shape)``, member k's slice from member k's generator; zeros,
        drawn from no generator, for members that ``members`` leaves out."""
        draws = [
            torch.randn(*shape, generator=g)
            if members is None or members[k]
            else torch.zeros(shape)
            for k, g in enumerate(self.generators)
        ]
        return torch.stack(draws).to(self.device, non_blocking=True)

    def tensor(self, array: npt.ArrayLike) -> torch.Tensor:
        """float32 on the device. The upload does not wait for the device (a blocking one
        synchronises the stream); from pageable memory it is staged before the call returns."""
        host = torch.as_tensor(np.asarray(array, dtype=np.float32))
        return host.to(self.device, non_blocking=True)

    def _policy(self, obs: npt.ArrayLike) -> tuple[torch.Tensor, torch.Tensor]:
        """The policy's ``mu`` and ``log_std``: ``(K, n, obs_dim) -> 2 x (K, n, act_dim)``."""
        x, c = self.tensor(obs), self.config
        heads = [
            policy_head(
                mlp(chunk.params.networks.policy, x[chunk.members]),
                self.act_dim,
                c.log_std_min,
                c.log_std_max,
            )
            for chunk in self.chunks
        ]
        return torch.cat([h[0] for h in heads]), torch.cat([h[1] for h in heads])

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

    def draw_noise(
        self, batch_size: int, members: Sequence[bool] | None = None
    ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """One update's reparameterisation noise ``(K, B, A)`` and, with twin-q, the noise of
        a' ~ pi(.|s') drawn after it, for ``members`` (all if None)."""
        eps = self._noise(batch_size, self.act_dim, members=members)
        twin_q = self.config.critic_target == "twin-q"
        return eps, self._noise(batch_size, self.act_dim, members=members) if twin_q else None

    def _chunk_of(self, k: int) -> tuple[Chunk, int]:
        chunk = self.chunks[k // self.chunks[0].params.n_members]
        return chunk, k - chunk.members.start

    def member_state(self, k: int) -> dict[str, Any]:
        """Member k's weights, Adam state and generator, as CPU tensors."""
        chunk, index = self._chunk_of(k)
        return {**chunk.params.member_state(index), "generator": self.generators[k].get_state()}

    def copy_member(self, source: int, member: int) -> None:
        """Give ``member`` exactly ``source``'s weights, targets, Adam state and (with
        --alpha auto) log alpha; its own generator stays (--q auto, training/pbt.py)."""
        state = self.member_state(source)
        chunk, index = self._chunk_of(member)
        chunk.params.load_member_state(index, state)

    def load_member_states(self, states: Sequence[Mapping[str, Any]]) -> None:
        """Load one :meth:`member_state` per member (their Adam step counts must agree)."""
        for chunk in self.chunks:
            chunk.params.load_member_states(states[chunk.members])
        for generator, state in zip(self.generators, states, strict=True):
            generator.set_state(state["generator"])


def loss_settings(config: RunConfig, action_scale: float = 1.0) -> LossSettings:
    """The losses' constants from ``config``: each :class:`LossSettings` field named like a
    config setting takes its value (a new loss option is a setting and a field of one name),
    the others are derived here."""
    derived: dict[str, Any] = {
        "action_scale": action_scale,
        "log_density_floor": math.log(config.density_floor),
        "bf16_products": config.matmul_precision == "bf16",
    }
    same_name = {f: getattr(config, f) for f in LossSettings._fields if f not in derived}
    return LossSettings(**same_name, **derived)
