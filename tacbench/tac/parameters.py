"""TAC's parameters for K members in one flat buffer: layout, initial weights, Adam, targets, per-
member state.

Every weight and bias of every trained network of every member lives in one contiguous float32
buffer (``data``), with a gradient buffer, Adam's two moments and a step count of the same
layout, so one fused Adam kernel updates everything. The blocks, in order: the policy's layers,
then the critic pair's layers (Q1's K members then Q2's, side by side, so the pair is one
(2K)-member stack), then V's layers; each layer a weight block then a bias block. The target
networks (the target V, or with ``critic_target`` twin-q the target critic pair) have a buffer
of their source's layout, so the Polyak average is one ``lerp_``.

Member k's initial weights are drawn from its own generator, network by network (policy, Q1, Q2,
V, layer by layer; the target starts as a copy), so they do not depend on the other members."""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt
import torch
from torch.optim.adam import adam

from tacbench.tac.networks import Layers, init_layers

ADAM_BETAS = (0.9, 0.999)  # torch.optim.Adam's defaults
ADAM_EPS = 1e-8


class Networks(NamedTuple):
    """Views of the trained networks (or of a gradient of them): K, 2K and K members, and with
    a learned alpha (--alpha auto) each member's log alpha ``(K,)``."""

    policy: Layers
    critics: Layers  # the K members of Q1, then the K members of Q2
    v: Layers
    log_alpha: torch.Tensor | None = None


class FlatLayout(NamedTuple):
    """The shapes of the blocks of a flat buffer, in order, and of TAC's networks in it: policy
    blocks, then the critic pair's, then V's (``n_layers`` weight-and-bias pairs each), or for a
    target buffer one network. A tuple of ints, so ``torch.compile`` guards it by value and
    every buffer of the same layout shares one compiled graph."""

    shapes: tuple[tuple[int, ...], ...]
    n_layers: int

    @property
    def size(self) -> int:
        """The number of floats in the buffer."""
        return sum(math.prod(shape) for shape in self.shapes)

    def views(self, flat: torch.Tensor) -> list[torch.Tensor]:
        """Each block as a view of ``flat``."""
        blocks, start = [], 0
        for shape in self.shapes:
            stop = start + math.prod(shape)
            blocks.append(flat[start:stop].view(shape))
            start = stop
        return blocks

    def offset(self, block: int) -> int:
        """Where block ``block`` starts."""
        return sum(math.prod(shape) for shape in self.shapes[:block])

    def networks(self, flat: torch.Tensor) -> Networks:
        """Policy, critic pair and V views of a flat tensor of this layout (the parameters or a
        gradient), and log alpha if it has it."""
        return self.networks_of(self.views(flat))

    def networks_of(self, blocks: Sequence[torch.Tensor]) -> Networks:
        """:meth:`networks` from the blocks themselves, in order (the tensors that autograd
        differentiates)."""
        n = 2 * self.n_layers
        log_alpha = blocks[3 * n] if len(blocks) > 3 * n else None
        return Networks(
            _layers(blocks[:n]),
            _layers(blocks[n : 2 * n]),
            _layers(blocks[2 * n : 3 * n]),
            log_alpha,
        )

    def layers(self, flat: torch.Tensor) -> Layers:
        """A one-network buffer (a target) as layers."""
        return _layers(self.views(flat))


def _pack(
    groups: Sequence[Sequence[Layers]],
    device: torch.device,
    tail: Sequence[torch.Tensor] = (),
) -> tuple[FlatLayout, torch.Tensor]:
    """One flat buffer holding, per group of same-shaped stacks (one network, or Q1 and Q2), each
    layer's weight block then its bias block, the group's stacks side by side; then the
    ``tail`` blocks."""
    blocks = []
    for group in groups:
        for i in range(len(group[0].weights)):
            blocks.append(torch.cat([layers.weights[i] for layers in group]))
            blocks.append(torch.cat([layers.biases[i] for layers in group]))
    blocks += list(tail)
    layout = FlatLayout(tuple(tuple(block.shape) for block in blocks), len(group[0].weights))
    data = torch.empty(layout.size, device=device)
    for view, block in zip(layout.views(data), blocks, strict=True):
        view.copy_(block)
    return layout, data


def _layers(blocks: Sequence[torch.Tensor]) -> Layers:
    """Alternating weight and bias blocks as layers."""
    return Layers(list(blocks[0::2]), list(blocks[1::2]))


class TacParameters:
    """The flat buffers of K members' TAC networks (see the module docstring)."""

    def __init__(
        self,
        obs_dim: int,
        act_dim: int,
        hidden_sizes: Sequence[int],
        generators: Sequence[torch.Generator],
        *,
        twin_q_targets: bool,
        device: torch.device,
        per_member_steps: bool = False,
        initial_alphas: Sequence[float] | None = None,
    ) -> None:
        self.n_members = len(generators)
        policy = init_layers([obs_dim, *hidden_sizes, 2 * act_dim], generators)
        q1, q2 = (init_layers([obs_dim + act_dim, *hidden_sizes, 1], generators) for _ in "12")
        v = init_layers([obs_dim, *hidden_sizes, 1], generators)
        self.n_layers = len(hidden_sizes) + 1
        # --alpha auto: each member's log alpha is one more trained parameter, after V's
        tail = [] if initial_alphas is None else [torch.tensor(initial_alphas).log()]
        self.layout, self.data = _pack([[policy], [q1, q2], [v]], device, tail)
        self.grad = torch.zeros_like(self.data)
        self.exp_avg = torch.zeros_like(self.data)
        self.exp_avg_sq = torch.zeros_like(self.data)
        self.steps = torch.zeros(self.n_members, dtype=torch.float32, device=device)  # Adam's
        self._host_steps = np.zeros(self.n_members, dtype=np.int64)  # the same, on the host
        # members update at their own times (the episode schedule, updates during warm-up)
        self.per_member_steps = per_member_steps
        self.twin_q_targets = twin_q_targets
        self.target_layout, self.target = _pack([[q1, q2]] if twin_q_targets else [[v]], device)
        n = 2 * self.n_layers
        self._target_source = slice(
            self.layout.offset(n if twin_q_targets else 2 * n),
            self.layout.offset(2 * n if twin_q_targets else 3 * n),
        )
        self.networks = self.layout.networks(self.data)
        self.target_networks = self.target_layout.layers(self.target)
        # the member of each row of each block: 0..K-1, and twice over for the critic pair
        members = torch.arange(self.n_members, device=device)
        self._host_rows = [
            np.tile(np.arange(self.n_members), shape[0] // self.n_members)
            for shape in self.layout.shapes
        ]
        self._target_rows = [
            members.repeat(shape[0] // self.n_members) for shape in self.target_layout.shapes
        ]

    def adam_step(self, lr: float, active: npt.NDArray[np.bool_] | None = None) -> None:
        """One Adam step from ``grad`` with ``torch.optim.Adam``'s defaults (betas 0.9, 0.999,
        eps 1e-8, no weight decay) for every member, or, with ``per_member_steps``, only for
        the members where ``active`` is True (the others, their moments and step counts are left
        exactly as they are).

        Both run PyTorch's fused Adam (:func:`torch.optim.adam.adam`). When every member steps
        and all have made the same number of steps, one call updates the whole buffer;
        otherwise one call updates each stepping member's rows of every block, each with its own
        step count. A member's numbers are the same either way, and as if it trained alone, to
        float32 rounding."""
        if active is not None and not self.per_member_steps:
            raise ValueError("an update of some members needs per_member_steps")
        stepping = np.ones(self.n_members, dtype=bool) if active is None else active
        buffers = (self.data, self.grad, self.exp_avg, self.exp_avg_sq)
        whole = bool(stepping.all()) and self._host_steps.min() == self._host_steps.max()
        if whole:
            params, grads, exp_avgs, exp_avg_sqs = ([t] for t in buffers)
            steps = [self.steps[0].clone()]
        else:  # each stepping member's row of every block (a critic block has two per member)
            rows = [
                (block, row, k)
                for block, block_rows in enumerate(self._host_rows)
                for row, k in enumerate(block_rows)
                if stepping[k]
            ]
            views = [self.layout.views(t) for t in buffers]
            params, grads, exp_avgs, exp_avg_sqs = (
                [v[block][row] for block, row, _ in rows] for v in views
            )
            owners = torch.as_tensor([k for _, _, k in rows], device=self.steps.device)
            steps = list(self.steps[owners].unbind())
        adam(
            params,
            grads,
            exp_avgs,
            exp_avg_sqs,
            [],
            steps,
            fused=True,
            amsgrad=False,
            beta1=ADAM_BETAS[0],
            beta2=ADAM_BETAS[1],
            lr=lr,
            weight_decay=0.0,
            eps=ADAM_EPS,
            maximize=False,
        )
        if whole:
            self.steps += 1
        else:
            self.steps += torch.as_tensor(stepping, device=self.steps.device)
        self._host_steps += stepping

    def update_target(self, tau: float, members: npt.NDArray[np.bool_] | None = None) -> None:
        """Polyak average of the target networks: ``target <- (1 - tau) target + tau source``
        (paper appendix: the target V; twin-q: the target critics, SAC v2), for every member or
        only the ``active`` ones."""
        source = self.data[self._target_source]
        if members is None or members.all():
            self.target.lerp_(source, tau)
            return
        active = torch.as_tensor(members, device=self.target.device)
        for rows, target, block in zip(
            self._target_rows,
            self.target_layout.views(self.target),
            self.target_layout.views(source),
            strict=True,
        ):
            weight = (tau * active[rows]).view((-1,) + (1,) * (target.dim() - 1))
            target.lerp_(block, weight.to(target.dtype))

    # --- per-member state (checkpoints hold one member each) ----------------------------------

    def _named(
        self, flat: torch.Tensor, target: torch.Tensor | None
    ) -> Iterator[tuple[str, torch.Tensor]]:
        """``(name, (K, ...) tensor)`` for every parameter of ``flat`` (and of the target)."""
        k = self.n_members
        nets = self.layout.networks(flat)
        named = [
            ("policy", nets.policy),
            ("q1", nets.critics.members(slice(0, k))),
            ("q2", nets.critics.members(slice(k, 2 * k))),
            ("v", nets.v),
        ]
        if target is not None:
            layers = self.target_layout.layers(target)
            if self.twin_q_targets:
                named += [
                    ("q1_target", layers.members(slice(0, k))),
                    ("q2_target", layers.members(slice(k, 2 * k))),
                ]
            else:
                named.append(("v_target", layers))
        for prefix, layers in named:
            for i, (weight, bias) in enumerate(zip(layers.weights, layers.biases, strict=True)):
                yield f"{prefix}.weights.{i}", weight
                yield f"{prefix}.biases.{i}", bias
        if nets.log_alpha is not None:
            yield "log_alpha", nets.log_alpha

    def named_gradients(self) -> dict[str, torch.Tensor]:
        """Every trained parameter's gradient ``(K, ...)``, named as in :meth:`member_state`."""
        return dict(self._named(self.grad, None))

    def member_state(self, k: int) -> dict[str, Any]:
        """Member k's weights (targets included) and Adam state, as CPU tensors."""

        def member(flat: torch.Tensor, target: torch.Tensor | None) -> dict[str, torch.Tensor]:
            return {name: t[k].detach().cpu().clone() for name, t in self._named(flat, target)}

        return {
            "params": member(self.data, self.target),
            "adam": {
                "step": self.steps[k].cpu().clone(),
                "exp_avg": member(self.exp_avg, None),
                "exp_avg_sq": member(self.exp_avg_sq, None),
            },
        }

    def load_member_state(self, k: int, state: Mapping[str, Any]) -> None:
        """Load a :meth:`member_state` (maybe another member's) into member k alone."""
        with torch.no_grad():
            for flat, target, key in (
                (self.data, self.target, None),
                (self.exp_avg, None, "exp_avg"),
                (self.exp_avg_sq, None, "exp_avg_sq"),
            ):
                values = state["params"] if key is None else state["adam"][key]
                for name, tensor in self._named(flat, target):
                    tensor[k].copy_(values[name])
            self.steps[k] = state["adam"]["step"].reshape(())
        self._host_steps[k] = int(state["adam"]["step"].reshape(()).item())

    def load_member_states(self, states: Sequence[Mapping[str, Any]]) -> None:
        """Load one :meth:`member_state` per member."""
        with torch.no_grad():
            for flat, target, key in (
                (self.data, self.target, None),
                (self.exp_avg, None, "exp_avg"),
                (self.exp_avg_sq, None, "exp_avg_sq"),
            ):
                values = [s["params"] if key is None else s["adam"][key] for s in states]
                for name, tensor in self._named(flat, target):
                    tensor.copy_(torch.stack([v[name] for v in values]))
            steps = torch.stack([s["adam"]["step"].reshape(()) for s in states])
            self.steps.copy_(steps)
        self._host_steps[:] = steps.cpu().numpy()
