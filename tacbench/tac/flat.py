"""Network parameters packed into one contiguous buffer, so one kernel can update all of them.

:class:`FlatParameters` copies groups of same-shaped parameters (a *block*: one layer of one
network, or the same layer of Q1 and Q2 side by side) into one float32 buffer and hands back
views. The agent rebinds its networks' ``nn.Parameter`` objects to those views, so the eager path
(autograd, ``torch.optim.Adam``) runs exactly as before on the same memory, while the fused path
(``tacbench.tac.fused``) writes every gradient into one matching buffer, updates all networks of
all members with a single fused Adam call and moves the target V with a single ``lerp_``. A
critic-pair block viewed as ``(2K, in, out)`` evaluates Q1 and Q2 with one batched product.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import torch

ADAM_BETAS = (0.9, 0.999)  # torch.optim.Adam's defaults, which the eager path uses
ADAM_EPS = 1e-8


class FlatParameters:
    """Blocks of same-shaped tensors in one buffer; with ``trainable``, a gradient buffer and
    Adam moments of the same layout.

    ``blocks[i]`` is a ``(len(group_i), *shape_i)`` view of ``data``; ``grad_blocks[i]`` the
    matching view of ``grad``. ``blocks[i][j]`` replaces the j-th tensor of group i.
    """

    def __init__(
        self,
        groups: Sequence[Sequence[torch.Tensor]],
        device: torch.device,
        *,
        trainable: bool = True,
    ) -> None:
        self.shapes = [(len(group), *group[0].shape) for group in groups]
        sizes = [len(group) * group[0].numel() for group in groups]
        self.offsets = [0, *itertools.accumulate(sizes)]
        self.data = torch.empty(self.offsets[-1], device=device)
        self.blocks = self._views(self.data)
        with torch.no_grad():
            for block, group in zip(self.blocks, groups, strict=True):
                block.copy_(torch.stack([t.detach() for t in group]))
        self.trainable = trainable
        if trainable:
            self.grad = torch.zeros_like(self.data)
            self.grad_blocks = self._views(self.grad)
            self.exp_avg = torch.zeros_like(self.data)
            self.exp_avg_sq = torch.zeros_like(self.data)
            self.step = torch.zeros((), dtype=torch.float32, device=device)

    def _views(self, flat: torch.Tensor) -> list[torch.Tensor]:
        return [
            flat[start:stop].view(shape)
            for start, stop, shape in zip(self.offsets, self.offsets[1:], self.shapes, strict=False)
        ]

    def span(self, first: int, stop: int) -> torch.Tensor:
        """The contiguous range of ``data`` that holds blocks ``first`` to ``stop - 1``."""
        return self.data[self.offsets[first] : self.offsets[stop]]

    def moment_views(self) -> tuple[list[torch.Tensor], list[torch.Tensor]]:
        """Per-block views of the first and second Adam moments."""
        return self._views(self.exp_avg), self._views(self.exp_avg_sq)

    def adam_step(self, lr: float) -> None:
        """One Adam step on the whole buffer from ``grad``: PyTorch's fused kernel with
        ``torch.optim.Adam``'s defaults (betas 0.9, 0.999, eps 1e-8, no weight decay).

        The two calls ``torch.optim.adam(..., fused=True)`` makes for one device and dtype,
        without its per-call grouping of the tensor lists (a tenth of the K = 1 update's time
        went into that wrapper); the same kernel, so the same numbers.
        """
        self.step += 1
        torch._fused_adam_(
            [self.data],
            [self.grad],
            [self.exp_avg],
            [self.exp_avg_sq],
            [],
            [self.step],
            amsgrad=False,
            lr=lr,
            beta1=ADAM_BETAS[0],
            beta2=ADAM_BETAS[1],
            weight_decay=0.0,
            eps=ADAM_EPS,
            maximize=False,
        )
