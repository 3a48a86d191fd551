"""The TAC agent for K members: five networks, one Adam, act / update / per-member state. No I/O.

Member k has its own ``torch.Generator`` seeded with its seed alone. It draws member k's initial
weights (policy, Q1, Q2, V, in that order; the target V starts as a copy of V), its exploration
noise and its reparameterisation noise, so none of these depend on the other members. The noise
is drawn on the CPU and moved to the device, so a seed draws the same numbers on every device.

The parameters live in one flat buffer (``tacbench.tac.flat``); ``config.impl`` picks the update:
``eager`` (autograd over ``losses.tac_losses`` and ``torch.optim.Adam``: the reference) or
``fused`` (``tacbench.tac.fused``: the same maths with hand-written gradients and one fused Adam
step), optionally under ``torch.compile`` (``config.compile``). Checkpoints
(:meth:`TacAgent.member_state`) have the same format for both.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt
import torch
from torch import nn

from tacbench.config import RunConfig
from tacbench.machine import l2_cache_bytes
from tacbench.tac.flat import FlatParameters
from tacbench.tac.fused import FusedNets, Layers, TacScalars, forward, fused_gradients, tac_scalars
from tacbench.tac.losses import DIAGNOSTICS, Batch, tac_losses
from tacbench.tac.networks import BatchedMLP, Critic, TanhGaussianPolicy
from tacbench.tac.speed import compile_gradients, members_fitting_l2

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
        )
        self.q1 = Critic(obs_dim, act_dim, hidden, gens)
        self.q2 = Critic(obs_dim, act_dim, hidden, gens)
        self.v = Critic(obs_dim, 0, hidden, gens)
        self.v_target = copy.deepcopy(self.v).requires_grad_(False)
        # critic_target twin-q (SAC v2): target copies of Q1 and Q2 replace the target V
        self.critic_targets = (
            (
                copy.deepcopy(self.q1).requires_grad_(False),
                copy.deepcopy(self.q2).requires_grad_(False),
            )
            if config.critic_target == "twin-q"
            else None
        )
        self._flatten(device)
        self.optimizer = torch.optim.Adam(
            [p for net in (self.policy, self.q1, self.q2, self.v) for p in net.parameters()],
            lr=config.learning_rate,
        )
        self.alive = torch.ones(len(seeds), dtype=torch.bool, device=device)
        self._scalars: TacScalars | None = None  # made for the q of the previous update
        self._scalars_q = 0.0
        self._gradients: Callable[..., torch.Tensor] = fused_gradients
        if config.compile:
            persistent = [t for nets in (self._nets, self._grads) for t in _tensors(nets)]
            persistent += _tensors(self._target_layers)
            if self._critic_target_layers is not None:
                persistent += _tensors(self._critic_target_layers)
            chunk = members_fitting_l2(config.batch_size, config.hidden_sizes, l2_cache_bytes())
            self._gradients = compile_gradients(device, persistent, chunk)

    def _flatten(self, device: torch.device) -> None:
        """Move every parameter into flat buffers and rebind the networks to views of them.

        Trainable blocks, in order: the policy's layers, Q1's and Q2's layers side by side (one
        block per layer, so the pair is one (2K, ...) stack), V's layers; each layer a weight
        block then a bias block. The target V gets a buffer of V's layout.
        """
        policy, q1, q2, v = self.policy.net, self.q1.net, self.q2.net, self.v.net
        n_layers = len(policy.weights)
        owners: list[list[tuple[nn.ParameterList, int]]] = []  # each block's parameters
        for nets in ((policy,), (q1, q2), (v,)):
            for i in range(n_layers):
                owners.append([(net.weights, i) for net in nets])
                owners.append([(net.biases, i) for net in nets])
        self.params = FlatParameters([[plist[i] for plist, i in o] for o in owners], device)
        self._slots: dict[torch.Tensor, tuple[int, int]] = {}  # parameter -> (block, index)
        for b, (block, block_owners) in enumerate(zip(self.params.blocks, owners, strict=True)):
            for j, (plist, i) in enumerate(block_owners):
                plist[i] = nn.Parameter(block[j])
                self._slots[plist[i]] = (b, j)
        target = self.v_target.net
        self.target = FlatParameters(_layer_groups(target), device, trainable=False)
        for b, block in enumerate(self.target.blocks):
            plist = target.weights if b % 2 == 0 else target.biases
            plist[b // 2] = nn.Parameter(block[0], requires_grad=False)
        self._v_blocks = (4 * n_layers, 6 * n_layers)  # V's range of trainable blocks
        self._nets = _fused_nets(self.params.blocks, n_layers)
        self._grads = _fused_nets(self.params.grad_blocks, n_layers)
        self._target_layers = _layers(self.target.blocks, 0, n_layers)
        self._critic_blocks = (2 * n_layers, 4 * n_layers)  # Q1 and Q2's range of blocks
        self._critic_target_layers: Layers | None = None
        if self.critic_targets is not None:  # the critic pair's layout, so one lerp_ updates it
            pair = [t.net for t in self.critic_targets]
            groups = [
                [getattr(net, kind)[i] for net in pair]
                for i in range(n_layers)
                for kind in ("weights", "biases")
            ]
            self.critic_target = FlatParameters(groups, device, trainable=False)
            for b, block in enumerate(self.critic_target.blocks):
                for j, net in enumerate(pair):
                    plist = net.weights if b % 2 == 0 else net.biases
                    plist[b // 2] = nn.Parameter(block[j], requires_grad=False)
            self._critic_target_layers = _layers(self.critic_target.blocks, 0, n_layers)
        self._flat_state_registered = False

    def _register_flat_adam_state(self) -> None:
        """Point ``optimizer.state`` at the flat Adam moments (views), so checkpoints see the
        fused path's moments in the eager path's format."""
        if self._flat_state_registered:
            return
        moments, squares = self.params.moment_views()
        for param in self.optimizer.param_groups[0]["params"]:
            i, j = self._slots[param]
            self.optimizer.state[param] = {
                "step": self.params.step,
                "exp_avg": moments[i][j],
                "exp_avg_sq": squares[i][j],
            }
        self._flat_state_registered = True

    @property
    def n_members(self) -> int:
        """K, the number of members."""
        return len(self.generators)

    def _noise(self, *shape: int) -> torch.Tensor:
        """Standard normal ``(K, *shape)``, member k's slice from member k's generator."""
        draws = [torch.randn(*shape, generator=g) for g in self.generators]
        return torch.stack(draws).to(self.device, non_blocking=True)

    def _tensor(self, array: npt.ArrayLike) -> torch.Tensor:
        """float32 on the device. The upload does not wait for the device (a blocking one
        synchronises the stream); from pageable memory it is staged before the call returns."""
        host = torch.as_tensor(np.asarray(array, dtype=np.float32))
        return host.to(self.device, non_blocking=True)

    def _policy_head(self, obs: npt.ArrayLike) -> tuple[torch.Tensor, torch.Tensor]:
        """The policy's ``mu`` and ``log_std`` (``TanhGaussianPolicy.forward``, the same
        operations) without module dispatch: ``(K, n, obs_dim) -> 2 x (K, n, act_dim)``."""
        out = forward(self._nets.policy, self._tensor(obs))[0]
        mu, raw = out[..., : self.act_dim], out[..., self.act_dim :]
        low, high = self.config.log_std_min, self.config.log_std_max
        return mu, low + 0.5 * (high - low) * (torch.tanh(raw) + 1.0)

    @torch.no_grad()
    def act(self, obs: npt.ArrayLike) -> npt.NDArray[np.float32]:
        """Exploration actions in [-1, 1]: ``(K, obs_dim) -> (K, act_dim)``, sampled from pi."""
        mu, log_std = self._policy_head(np.asarray(obs)[:, None])
        action = torch.tanh(mu + self._noise(1, self.act_dim) * log_std.exp())
        return action[:, 0].cpu().numpy()

    @torch.no_grad()
    def act_deterministic(self, obs: npt.ArrayLike) -> npt.NDArray[np.float32]:
        """Evaluation actions ``tanh(mu)`` in [-1, 1]: ``(K, n, obs_dim) -> (K, n, act_dim)``."""
        return torch.tanh(self._policy_head(obs)[0]).cpu().numpy()

    def update(self, batch: Mapping[str, npt.ArrayLike], q: float) -> torch.Tensor:
        """One gradient step for every live member on its own minibatch ``(K, B, ...)``.

        Returns the detached metrics ``(K, len(METRICS))``. A member marked dead (``alive``
        False) contributes nothing to the step of the others.
        """
        tensors = Batch(*(self._tensor(batch[name]) for name in Batch._fields))
        eps = self._noise(tensors.action.shape[1], self.act_dim)
        eps_next = None
        if self.critic_targets is not None:  # the noise of a' ~ pi(.|s'), after eps
            eps_next = self._noise(tensors.action.shape[1], self.act_dim)
        tau = self.config.tau
        if self.config.impl == "fused":
            with torch.no_grad():
                metrics = self._fused_gradients(tensors, eps, q, eps_next)
                self.params.adam_step(self.config.learning_rate)
                if self.critic_targets is None:
                    # target V: psi- <- (1 - tau) psi- + tau psi (paper appendix), all at once
                    self.target.data.lerp_(self.params.span(*self._v_blocks), tau)
                else:
                    self.critic_target.data.lerp_(self.params.span(*self._critic_blocks), tau)
            return metrics
        metrics = self._eager_gradients(tensors, eps, q, eps_next)
        self.optimizer.step()
        with torch.no_grad():
            if self.critic_targets is None:  # target V: psi- <- (1 - tau) psi- + tau psi
                for target, source in zip(
                    self.v_target.parameters(), self.v.parameters(), strict=True
                ):
                    target.lerp_(source, tau)
            else:  # target critics, the same Polyak average (SAC v2)
                self.critic_target.data.lerp_(self.params.span(*self._critic_blocks), tau)
        return metrics

    def gradients(
        self, batch: Batch, eps: torch.Tensor, q: float, eps_next: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """The metrics of :meth:`update` and the gradient of every trained parameter (named as
        in :meth:`member_state`) for one minibatch and reparameterisation noise ``eps`` (and,
        with twin-q, ``eps_next``), by this agent's ``impl``, without changing any weight. For
        comparing the paths."""
        if self.config.impl == "fused":
            with torch.no_grad():
                metrics = self._fused_gradients(batch, eps, q, eps_next)
            blocks = self.params.grad_blocks
            grads = {
                name: blocks[self._slots[param][0]][self._slots[param][1]].clone()
                for name, param in self._named_parameters()
                if param in self._slots
            }
        else:
            metrics = self._eager_gradients(batch, eps, q, eps_next)
            grads = {
                name: param.grad.clone()
                for name, param in self._named_parameters()
                if param.grad is not None
            }
        return metrics, grads

    def _eager_gradients(
        self, batch: Batch, eps: torch.Tensor, q: float, eps_next: torch.Tensor | None
    ) -> torch.Tensor:
        """The reference path: ``losses.tac_losses`` and autograd, gradients in ``.grad``."""
        losses = tac_losses(
            self.policy,
            self.q1,
            self.q2,
            self.v,
            self.v_target,
            batch,
            eps,
            q=q,
            alpha=self.config.alpha,
            gamma=self.config.gamma,
            lnq=self.config.lnq,
            target_critics=self.critic_targets,
            eps_next=eps_next,
        )
        per_member = torch.stack([losses.q1, losses.q2, losses.v, losses.pi], dim=-1)
        total = torch.where(self.alive, per_member.sum(dim=-1), 0.0).sum()
        self.optimizer.zero_grad(set_to_none=True)
        total.backward()
        return torch.cat([per_member.detach(), losses.diagnostics], dim=-1)

    def _fused_gradients(
        self, batch: Batch, eps: torch.Tensor, q: float, eps_next: torch.Tensor | None
    ) -> torch.Tensor:
        """The fused path: ``fused.fused_gradients``, gradients in the flat buffer."""
        self._register_flat_adam_state()
        if self._scalars is None or self._scalars_q != q:  # made again only when q changes
            c = self.config
            self._scalars_q = q
            self._scalars = tac_scalars(
                q, c.alpha, c.gamma, c.lnq, c.log_std_min, c.log_std_max, self.device
            )
        return self._gradients(
            self._nets,
            self._grads,
            self._target_layers,
            batch,
            eps,
            self.alive,
            self._scalars,
            self._critic_target_layers,
            eps_next,
        )

    # --- per-member state (checkpoints hold one member each) ----------------------------------

    def _named_parameters(self) -> Iterator[tuple[str, torch.nn.Parameter]]:
        for prefix, net in (
            ("policy", self.policy),
            ("q1", self.q1),
            ("q2", self.q2),
            ("v", self.v),
            ("v_target", self.v_target),
            *(
                zip(("q1_target", "q2_target"), self.critic_targets, strict=True)
                if self.critic_targets is not None
                else ()
            ),
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
        if states[0]["adam"] and self.config.impl == "fused":
            self._register_flat_adam_state()  # loaded moments go into the flat buffers
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
            current = self.optimizer.state.get(param)
            if current:
                for key, value in entry.items():
                    current[key].copy_(value)
            else:
                self.optimizer.state[param] = entry
        for generator, state in zip(self.generators, states, strict=True):
            generator.set_state(state["generator"])


def _tensors(nets: FusedNets | Layers) -> list[torch.Tensor]:
    """Every weight and bias view of ``nets``."""
    layers = [nets] if isinstance(nets, Layers) else list(nets)
    return [t for layer in layers for t in (*layer.weights, *layer.biases)]


def _layer_groups(net: BatchedMLP) -> list[list[torch.Tensor]]:
    """One single-tensor group per weight and bias, layer by layer."""
    return [[t] for pair in zip(net.weights, net.biases, strict=True) for t in pair]


def _layers(blocks: Sequence[torch.Tensor], first: int, n_layers: int) -> Layers:
    """The layers whose (weight, bias) blocks start at ``first``, members of a block stacked."""
    pairs = range(first, first + 2 * n_layers, 2)
    return Layers(
        [blocks[i].flatten(0, 1) for i in pairs], [blocks[i + 1].flatten(0, 1) for i in pairs]
    )


def _fused_nets(blocks: Sequence[torch.Tensor], n_layers: int) -> FusedNets:
    """Policy, critic pair and V views of the trainable blocks (see TacAgent._flatten)."""
    return FusedNets(
        _layers(blocks, 0, n_layers),
        _layers(blocks, 2 * n_layers, n_layers),
        _layers(blocks, 4 * n_layers, n_layers),
    )
