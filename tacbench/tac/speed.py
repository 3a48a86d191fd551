"""Speed switches that leave every result unchanged, or within rounding of the fused update.

:func:`compile_gradients`: ``torch.compile`` of the fused update, falling back to the uncompiled
one where compilation is unsupported. On a CPU, Inductor turns the fused update's elementwise
chains into a few C++ loops and, with its C++ wrapper, calls them from C++ rather than from a
generated Python function (it needs a C++ compiler; the first update of each of at most three
variants, q = 1, 1 < q < 2 and q >= 2, compiles for seconds to tens of seconds, cached on disk
afterwards). On a CPU the compiled update also runs the members in chunks that fit the L2 cache
(:func:`fused_gradients_in_chunks`). On a GPU it uses mode ``reduce-overhead``, which records
CUDA graphs (one launch per update) where the graph allows it. Where compilation fails, a
warning says so and the uncompiled fused update, the same function, runs instead.

:func:`reuse_freed_memory`: a glibc heap setting that stops large temporaries from being
returned to the OS and page-faulted back in at every update.
"""

from __future__ import annotations

import ctypes
import sys
import warnings
from collections.abc import Callable, Sequence
from typing import Any

import torch

from tacbench.tac.fused import FusedNets, Layers, TacScalars, fused_gradients
from tacbench.tac.losses import Batch

CPU_OPTIONS: dict[str, str | int | bool | Callable[..., Any]] = {
    # the C++ wrapper: 7% off the K = 1 update (HalfCheetah, Intel Xeon, in-process A/B)
    "cpp_wrapper": True,
    # Inductor unrolls reductions over at most 8 elements into scalar code by default; the sums
    # over the action dimensions (ln_q pi, log pi) then ran libm's scalar expm1 element by
    # element. Vectorised instead: 7% off the K = 10 compiled update, K = 1 unchanged (Intel
    # Xeon, in-process A/B, median of 40 paired rounds)
    "unroll_reductions_threshold": 1,
    # one planned pool for the intermediate buffers instead of an allocation for each (reused
    # from chunk to chunk, so still in cache), and no re-check of the input sizes and strides,
    # which Dynamo's guards have checked already: 13% off the K = 1 compiled update, 11% off
    # K = 10 (Intel Xeon, in-process A/B, median of 30 paired rounds)
    "memory_planning": True,
    "size_asserts": False,
    "alignment_asserts": False,
}


def members_fitting_l2(batch_size: int, hidden_sizes: Sequence[int], l2_bytes: int) -> int:
    """How many members' critic activations fit one core's L2 cache: each member's Q1 and Q2
    hidden layers hold ``2 x 2B x width`` float32 (buffer and reparameterised actions)."""
    per_member = 2 * 2 * batch_size * max(hidden_sizes) * 4
    return max(1, l2_bytes // per_member)


def fused_gradients_in_chunks(
    nets: FusedNets,
    grads: FusedNets,
    v_target: Layers,
    batch: Batch,
    eps: torch.Tensor,
    alive: torch.Tensor,
    c: TacScalars,
    target_critics: Layers | None = None,
    eps_next: torch.Tensor | None = None,
    *,
    members_per_chunk: int,
) -> torch.Tensor:
    """:func:`fused_gradients`, members ``members_per_chunk`` at a time.

    Members never interact, so this is the same computation in another order: one chunk's
    whole update runs while its activations (at K = 10 the critics' hidden layer is 4.8 MB)
    are still in the L2 cache, instead of each pass streaming all members' from memory. Under
    ``torch.compile`` the chunks become one graph; uncompiled it would only add calls. The
    critic pair (Q1's members, then Q2's) is gathered per chunk and its gradients copied back.
    """
    n_members = eps.shape[0]
    if members_per_chunk >= n_members:  # one chunk: the whole stack as it is
        return fused_gradients(
            nets, grads, v_target, batch, eps, alive, c, target_critics, eps_next
        )
    chunk_metrics = []
    for first in range(0, n_members, members_per_chunk):
        members = slice(first, min(first + members_per_chunk, n_members))
        pair = slice(n_members + members.start, n_members + members.stop)  # their Q2s
        critics = _critic_pairs(nets.critics, members, pair)
        critic_grads = Layers(*([torch.empty_like(t) for t in ts] for ts in critics))
        chunk_metrics.append(
            fused_gradients(
                FusedNets(_members(nets.policy, members), critics, _members(nets.v, members)),
                FusedNets(
                    _members(grads.policy, members), critic_grads, _members(grads.v, members)
                ),
                _members(v_target, members),
                Batch(*(t[members] for t in batch)),
                eps[members],
                alive[members],
                c,
                None if target_critics is None else _critic_pairs(target_critics, members, pair),
                None if eps_next is None else eps_next[members],
            )
        )
        n = members.stop - members.start
        for full, part in zip(
            (*grads.critics.weights, *grads.critics.biases),
            (*critic_grads.weights, *critic_grads.biases),
            strict=True,
        ):
            full[members].copy_(part[:n])
            full[pair].copy_(part[n:])
    return torch.cat(chunk_metrics)


def _members(layers: Layers, members: slice) -> Layers:
    """The layers of some members of a stack."""
    return Layers([w[members] for w in layers.weights], [b[members] for b in layers.biases])


def _critic_pairs(layers: Layers, members: slice, pair: slice) -> Layers:
    """Some members' Q1s then the same members' Q2s, from a (2K)-member critic-pair stack."""
    return Layers(
        [torch.cat([w[members], w[pair]]) for w in layers.weights],
        [torch.cat([b[members], b[pair]]) for b in layers.biases],
    )


def compile_gradients(
    device: torch.device, persistent: Sequence[torch.Tensor], members_per_chunk: int
) -> Callable[..., torch.Tensor]:
    """:func:`fused_gradients`, compiled for ``device`` on first use (or, failing that, as is).

    ``persistent``: the tensors every call passes again (weights, gradient buffers); on a GPU
    they are marked as static addresses, which CUDA graphs need for the buffers they write.
    ``members_per_chunk`` (CPU only; :func:`members_fitting_l2`): see
    :func:`fused_gradients_in_chunks`; a GPU takes all members at once.
    """
    compiled: list[Callable[..., torch.Tensor]]
    if device.type == "cuda":
        for tensor in persistent:
            torch._dynamo.mark_static_address(tensor)
        compiled = [torch.compile(fused_gradients, mode="reduce-overhead")]
    else:

        def in_chunks(*args: Any) -> torch.Tensor:
            return fused_gradients_in_chunks(*args, members_per_chunk=members_per_chunk)

        compiled = [torch.compile(in_chunks, options=CPU_OPTIONS)]

    def gradients(*args: Any) -> torch.Tensor:
        try:
            return compiled[0](*args)
        except Exception as err:  # compilation failed: the same function, uncompiled
            if compiled[0] is fused_gradients:
                raise
            warnings.warn(
                f"torch.compile of the fused update failed ({type(err).__name__}: {err}); "
                "continuing without it",
                RuntimeWarning,
                stacklevel=2,
            )
            compiled[0] = fused_gradients
            return fused_gradients(*args)

    return gradients


def reuse_freed_memory() -> bool:
    """Let this process reuse the memory its tensors free instead of returning it to the OS.

    With glibc's defaults a temporary over 128 KiB is ``mmap``-ed and unmapped again when freed,
    so every update page-faults its large temporaries back in: at K = 10 members (HalfCheetah,
    batch 100) about 2,900 minor faults per update, several milliseconds on a virtual machine.
    Raising the mmap threshold to 32 MiB and the trim threshold to 64 MiB keeps that memory in
    the heap. Results do not change. Returns whether the setting applied (glibc Linux only).
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL("libc.so.6")
    except OSError:  # not glibc
        return False
    m_trim_threshold, m_mmap_threshold = -1, -3  # mallopt parameters (malloc.h)
    return bool(
        libc.mallopt(m_mmap_threshold, 32 << 20) and libc.mallopt(m_trim_threshold, 64 << 20)
    )
