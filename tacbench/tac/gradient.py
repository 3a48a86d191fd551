"""The gradient of :func:`tacbench.tac.losses.tac_losses` by autograd, eager or under
``torch.compile``: the step of an update (:mod:`tacbench.tac.update`) that turns the losses into
each parameter's gradient.

The losses are written once, with the paper's equation labels, and differentiated by autograd
on every path: adding a loss term is one edit in ``losses.py``. Eager, the gradient is
``torch.autograd.grad``; compiled, it is ``torch.func.grad`` of the same function, which
``torch.compile`` traces into one graph of the forward and backward pass (Dynamo cannot trace
``torch.autograd.grad``; eagerly, ``torch.func.grad`` is the slower of the two). On a CPU,
Inductor turns the elementwise chains into a few C++ loops and, with its C++ wrapper, calls them
from C++ (it needs a C++ compiler; the first update compiles for seconds to tens of seconds,
cached on disk afterwards). q and alpha enter as per-member tensors, so one graph serves every
q, a group of members with different q, and a q schedule, without recompiling. On a GPU it uses
mode ``reduce-overhead`` (CUDA graphs) with the persistent buffers marked static. Where
compilation fails, a warning says so and the eager gradient runs instead.

Adam and the target average stay outside the compiled graph: inside it they made the update
slower (docs/performance.md, "One source for the maths").
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from typing import Any

import torch

from tacbench.tac.losses import LossSettings, tac_losses
from tacbench.tac.maths import Batch, Coefficients
from tacbench.tac.parameters import FlatLayout

# What each option buys: docs/notes/performance-history.md, "Adam, Inductor's options and the
# private fused-Adam call"
CPU_COMPILE_OPTIONS: dict[str, str | int | bool | Callable[..., Any]] = {
    # the compiled kernels called from C++, not from a Python wrapper
    "cpp_wrapper": True,
    # by default Inductor unrolls reductions over at most 8 elements into scalar code, so the
    # sums over the action dimensions (ln_q pi, log pi) called libm's scalar expm1 per element
    "unroll_reductions_threshold": 1,
    # one planned pool for the intermediate buffers instead of an allocation for each, and no
    # re-check of the input sizes and strides, which Dynamo's guards have checked already
    "memory_planning": True,
    "size_asserts": False,
    "alignment_asserts": False,
}

Gradient = Callable[..., tuple[torch.Tensor, torch.Tensor]]  # -> (gradient, metrics)


def total_loss(
    blocks: Sequence[torch.Tensor],
    target: torch.Tensor,
    layout: FlatLayout,
    target_layout: FlatLayout,
    batch: Batch,
    eps: torch.Tensor,
    alive: torch.Tensor,
    c: Coefficients,
    s: LossSettings,
    eps_next: torch.Tensor | None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The sum of the live members' four losses (five with a learned alpha) at parameters
    ``blocks`` (the blocks of ``layout``, in order; the target networks' flat ``target`` of
    ``target_layout``), which autograd differentiates, and the detached metrics
    ``(K, len(METRICS))`` (plus ``ALPHA_METRICS`` with a learned alpha). Members never mix, so
    each member's gradient is its own losses'."""
    nets, target_net = layout.networks_of(blocks), target_layout.layers(target)
    losses = tac_losses(nets, target_net, batch, eps, c, s, eps_next)
    per_member = torch.stack([losses.q1, losses.q2, losses.v, losses.pi], dim=-1)
    metrics = [per_member.detach(), losses.diagnostics]
    if losses.alpha is not None:  # --alpha auto: the temperature loss joins the sum
        assert losses.alpha_in_force is not None
        per_member = torch.cat([per_member, losses.alpha[:, None]], dim=-1)
        metrics.append(torch.stack([losses.alpha_in_force, losses.alpha.detach()], dim=-1))
    total = torch.where(alive, per_member.sum(dim=-1), 0.0).sum()
    return total, torch.cat(metrics, dim=-1)


def _flat(grads: Sequence[torch.Tensor]) -> torch.Tensor:
    """The blocks' gradients as one flat tensor of their layout."""
    return torch.cat([g.reshape(-1) for g in grads])


# The gradient is taken with respect to the blocks, not the flat buffer they are views of: the
# gradient of a view of the flat tensor is a zero-padded copy of the whole buffer, and summing
# one per block cost a pass over the buffer per block (measured in docs/performance.md, "The
# authors' (400, 300) networks").


def eager_gradient(
    theta: torch.Tensor, target: torch.Tensor, layout: FlatLayout, *args: Any
) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`total_loss`'s gradient with respect to the flat parameters ``theta`` (of
    ``layout``) by ``torch.autograd.grad``, and the metrics."""
    with torch.enable_grad():
        blocks = [block.detach().requires_grad_() for block in layout.views(theta)]
        total, metrics = total_loss(blocks, target, layout, *args)
        # with twin-q targets V trains on nothing: its blocks' gradient is zero, as by func.grad
        grads = torch.autograd.grad(total, blocks, allow_unused=True, materialize_grads=True)
    return _flat(grads), metrics


_block_gradient = torch.func.grad(total_loss, has_aux=True)


def traceable_gradient(
    theta: torch.Tensor, target: torch.Tensor, layout: FlatLayout, *args: Any
) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`eager_gradient` by ``torch.func.grad``, which ``torch.compile`` can trace."""
    grads, metrics = _block_gradient(layout.views(theta), target, layout, *args)
    return _flat(grads), metrics


def _mark_static_addresses(tensors: Sequence[torch.Tensor]) -> None:
    """Tell the compiler that ``tensors`` keep their storage for the run: a CUDA graph replays
    fixed addresses and would otherwise copy each one in on every call. torch 2.13 offers this
    only as ``torch._dynamo.mark_static_address`` (``torch.compiler`` has no public spelling),
    and only the GPU path calls it, once per graph."""
    for tensor in tensors:
        torch._dynamo.mark_static_address(tensor)


def compiled_gradient(device: torch.device, static: Sequence[torch.Tensor] = ()) -> Gradient:
    """:data:`traceable_gradient` compiled for ``device`` on first use, or, where compilation
    fails, :func:`eager_gradient` (with one warning). One compiled graph serves every call with
    the same shapes and layouts, whatever the parameter tensors. On a GPU the ``static``
    tensors are marked as static addresses, which CUDA graphs need."""
    if device.type == "cuda":
        _mark_static_addresses(static)
        current = [torch.compile(traceable_gradient, dynamic=False, mode="reduce-overhead")]
    else:
        current = [torch.compile(traceable_gradient, dynamic=False, options=CPU_COMPILE_OPTIONS)]

    def gradient(*args: Any) -> tuple[torch.Tensor, torch.Tensor]:
        try:
            return current[0](*args)
        except Exception as err:  # compilation failed: the same gradient, uncompiled
            if current[0] is eager_gradient:
                raise
            warnings.warn(
                f"torch.compile of TAC's update failed ({type(err).__name__}: {err}); "
                "continuing without it",
                RuntimeWarning,
                stacklevel=2,
            )
            current[0] = eager_gradient
            return eager_gradient(*args)

    return gradient
