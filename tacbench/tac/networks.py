"""MLPs with a leading member dimension: M independent networks evaluated by batched products.

A stack of M networks is a :class:`Layers`: weights ``(M, in, out)`` and biases ``(M, 1, out)``
per layer, ReLU between layers. Inputs are ``(M, B, in)``. The layers are plain tensors (views of
the flat parameter buffer, :mod:`tacbench.tac.parameters`), and the functions here are pure, so
autograd differentiates them with respect to that buffer.

Initialisation is the reference code's (TensorFlow ``tf.layers.dense``): Glorot-uniform weights
and zero biases, member k's weights drawn from member k's own generator only, so they do not
depend on the other members.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from typing import NamedTuple

import torch

from tacbench.tac.maths import log_std_from_tanh


class Layers(NamedTuple):
    """M stacked MLPs, layer by layer: weights ``(M, in, out)`` and biases ``(M, 1, out)``."""

    weights: list[torch.Tensor]
    biases: list[torch.Tensor]

    def members(self, index: slice) -> Layers:
        """The layers of some members of the stack."""
        return Layers([w[index] for w in self.weights], [b[index] for b in self.biases])


def glorot_uniform(n_in: int, n_out: int, generators: Sequence[torch.Generator]) -> torch.Tensor:
    """``(K, n_in, n_out)`` weights, member k's drawn U(-l, l), l = sqrt(6 / (n_in + n_out)),
    from ``generators[k]``."""
    limit = math.sqrt(6.0 / (n_in + n_out))
    draws = [torch.rand(n_in, n_out, generator=g) for g in generators]
    return (torch.stack(draws) * 2.0 - 1.0) * limit


def init_layers(sizes: Sequence[int], generators: Sequence[torch.Generator]) -> Layers:
    """``sizes[0] -> ... -> sizes[-1]`` for K = ``len(generators)`` members, layer by layer."""
    pairs = list(itertools.pairwise(sizes))
    return Layers(
        [glorot_uniform(n_in, n_out, generators) for n_in, n_out in pairs],
        [torch.zeros(len(generators), 1, n_out) for _, n_out in pairs],
    )


def linear(
    x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor, *, bf16: bool = False
) -> torch.Tensor:
    """``x @ weight + bias`` for stacked layers.

    A layer with one output (the value heads) is a multiply-and-sum: MKL's batched product with a
    single output column is several times slower once M > 1. Under ``torch.compile`` the bias is
    added after the product, where Inductor fuses it into the next elementwise kernel
    (``baddbmm`` first copies the broadcast bias into its whole output).

    ``bf16`` (``--matmul-precision bf16``): the product's inputs are rounded to bfloat16, it
    accumulates in float32 (oneDNN's and cuBLAS's bfloat16 kernels) and its output is rounded to
    bfloat16 and returned as float32; the bias, the value heads and everything around stay
    float32. Autograd's backward products run in bfloat16 alike.
    """
    if weight.shape[-1] == 1:
        return torch.linalg.vecdot(x, weight.transpose(1, 2)).unsqueeze(-1).add_(bias)
    if bf16:
        return torch.bmm(x.to(torch.bfloat16), weight.to(torch.bfloat16)).float() + bias
    if torch.compiler.is_compiling():
        return torch.bmm(x, weight) + bias
    return torch.baddbmm(bias, x, weight)


def mlp(net: Layers, x: torch.Tensor, *, frozen: bool = False, bf16: bool = False) -> torch.Tensor:
    """``(M, B, in) -> (M, B, out)``. ``frozen=True`` uses detached weights, so gradients reach the
    input but not the network's parameters; ``bf16`` rounds the products' inputs to bfloat16
    (:func:`linear`)."""
    last = len(net.weights) - 1
    for i, (weight, bias) in enumerate(zip(net.weights, net.biases, strict=True)):
        if frozen:
            weight, bias = weight.detach(), bias.detach()
        x = linear(x, weight, bias, bf16=bf16)
        if i < last:
            x = torch.relu(x)
    return x


def policy_head(
    out: torch.Tensor, act_dim: int, log_std_min: float, log_std_max: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """The tanh-squashed Gaussian policy's mean ``mu`` and ``log_std`` from its network's output
    ``(M, B, 2A)``: one output layer of width 2A, the second half through the rescaled tanh
    (reference code; :func:`tacbench.tac.maths.log_std_from_tanh`)."""
    raw = out[..., act_dim:]
    return out[..., :act_dim], log_std_from_tanh(torch.tanh(raw), log_std_min, log_std_max)
