"""Speed switches that leave every result unchanged, or within rounding of the fused update.

:func:`compile_gradients`: ``torch.compile`` of the fused update, falling back to the uncompiled
one where compilation is unsupported. On a CPU, Inductor turns the fused update's elementwise
chains into a few C++ loops and, with its C++ wrapper, calls them from C++ rather than from a
generated Python function (it needs a C++ compiler; the first update of each of at most three
variants, q = 1, 1 < q < 2 and q >= 2, compiles for seconds to tens of seconds, cached on disk
afterwards). On a GPU it uses mode ``reduce-overhead``, which records CUDA graphs (one launch
per update) where the graph allows it. Where compilation fails, a warning says so and the
uncompiled fused update, the same function, runs instead.

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

from tacbench.tac.fused import fused_gradients


def compile_gradients(
    device: torch.device, persistent: Sequence[torch.Tensor]
) -> Callable[..., torch.Tensor]:
    """:func:`fused_gradients`, compiled for ``device`` on first use (or, failing that, as is).

    ``persistent``: the tensors every call passes again (weights, gradient buffers); on a GPU
    they are marked as static addresses, which CUDA graphs need for the buffers they write.
    """
    if device.type == "cuda":
        for tensor in persistent:
            torch._dynamo.mark_static_address(tensor)
        compiled = [torch.compile(fused_gradients, mode="reduce-overhead")]
    else:  # the C++ wrapper: 7% off the K = 1 update (HalfCheetah, Intel Xeon, in-process A/B)
        compiled = [torch.compile(fused_gradients, options={"cpp_wrapper": True})]

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
