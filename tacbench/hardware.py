"""The machine a process runs on: which CPU class it is, as far as float rounding is concerned,
and the process settings every trainer applies once at start-up (:func:`configure_process`).

The same library versions give different last digits on different CPUs: MKL and PyTorch pick
their kernels by vendor, model and instruction set (measured here: TAC's and PPO's CSVs from an
AMD EPYC and an Intel Xeon, both AVX-512, the same wheels, differ from the first update on).
:func:`cpu_class` names the class of CPUs that can be expected to agree to the last digit, for
the exact regression references (``tacbench.regress``) and the saved benchmark baselines
(``tests/bench``), which both belong to one class.
"""

from __future__ import annotations

import ctypes
import math
import os
import platform
import re
import statistics
import sys
import time
from functools import cache
from pathlib import Path

from tacbench.errors import TacbenchError

# /proc/cpuinfo fields that identify a CPU model: x86 (vendor, family, model), then Arm
# (implementer, part)
_IDENTITY_FIELDS = (
    ("vendor_id", "cpu family", "model"),
    ("CPU implementer", "CPU architecture", "CPU part"),
)


def _cpuinfo(text: str | None) -> dict[str, str]:
    """The first processor's fields of a ``/proc/cpuinfo`` text (this machine's when None)."""
    if text is None:
        path = Path("/proc/cpuinfo")
        text = path.read_text() if path.is_file() else ""
    fields: dict[str, str] = {}
    for line in text.splitlines():
        if not line.strip():
            if fields:
                break
            continue
        key, _, value = line.partition(":")
        fields.setdefault(key.strip(), value.strip())
    return fields


def cpu_identity(cpuinfo: str | None = None) -> list[str]:
    """Vendor, family and model (x86) or implementer, architecture and part (Arm), from
    ``/proc/cpuinfo`` (or the text given); ``platform.processor()`` where there is none."""
    fields = _cpuinfo(cpuinfo)
    for names in _IDENTITY_FIELDS:
        if all(name in fields for name in names):
            return [fields[name] for name in names]
    return [platform.processor() or "unknown"]


def cpu_name(cpuinfo: str | None = None) -> str:
    """The CPU's marketing name (``model name``), for people; not part of :func:`cpu_class`."""
    return _cpuinfo(cpuinfo).get("model name") or platform.processor() or "unknown"


@cache
def cpu_class() -> str:
    """``<arch>-<vendor>-<family>-<model>-<torch CPU capability>``, e.g.
    ``x86_64-GenuineIntel-6-207-AVX512``: a file-name-safe key for results that only this class
    of CPU reproduces bit for bit."""
    import torch

    parts = [platform.machine(), *cpu_identity(), torch.backends.cpu.get_cpu_capability()]
    return "-".join(re.sub(r"[^A-Za-z0-9_.]+", "_", part) for part in parts)


def memory_bytes() -> int:
    """This machine's physical memory (POSIX; 8 GiB where it cannot be read)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 8 << 30


class LoadMeter:
    """This machine's mean load over a stretch of time, as :meth:`sample` reads it (at most
    every ``every_s`` seconds): the 1-minute load average of ``os.getloadavg``, which counts the
    processes running or waiting for a core, this program's own included."""

    def __init__(self, every_s: float = 10.0) -> None:
        self.every_s = every_s
        self._samples: list[float] = []
        self._last = -math.inf

    def sample(self) -> None:
        """Read the load average, if ``every_s`` has passed since the last reading."""
        now = time.monotonic()
        if now - self._last >= self.every_s:
            self._samples.append(os.getloadavg()[0])
            self._last = now

    def mean(self) -> float | None:
        """The mean of the readings (None before the first)."""
        return statistics.fmean(self._samples) if self._samples else None


@cache
def cpp_compiler() -> str | None:
    """The C++ compiler torch.compile's Inductor would use on a CPU, or None if there is none."""
    from torch._inductor import cpp_builder

    try:
        return str(cpp_builder.get_cpp_compiler())
    except Exception:  # Inductor raises its own InvalidCxxCompiler (and others) when none works
        return None


# /proc/cpuinfo flags of native bfloat16 products: x86 AVX512-BF16 (Intel from Cooper Lake, AMD
# from Zen 4) and AMX-BF16 (Intel from Sapphire Rapids); Arm's "bf16" feature (Armv8.6)
BF16_FLAGS = ("avx512_bf16", "amx_bf16", "bf16")


def bf16_instructions(cpuinfo: str | None = None) -> list[str]:
    """The native bfloat16 instruction sets this CPU (or the ``/proc/cpuinfo`` text given)
    announces, in :data:`BF16_FLAGS` order; empty where it has none."""
    fields = _cpuinfo(cpuinfo)
    announced = set((fields.get("flags") or fields.get("Features") or "").split())
    return [flag for flag in BF16_FLAGS if flag in announced]


def check_matmul_precision(
    precision: str,
    device: str,
    flag: str = "--matmul-precision bf16",
    instead: str = "use --matmul-precision float32",
) -> None:
    """Refuse ``--matmul-precision bf16`` (``flag``: the option that asked for it, and
    ``instead``: what to do) on a device without native bfloat16 products, where it would be
    emulated: slower than float32 and no cheaper for it."""
    if precision != "bf16":
        return
    import torch

    if device == "cuda":
        if not torch.cuda.is_bf16_supported(including_emulation=False):
            raise TacbenchError(f"{flag}: this GPU has no native bfloat16 products; {instead}.")
        return
    if not bf16_instructions():
        raise TacbenchError(
            f"{flag}: this CPU ({cpu_name()}) has no native bfloat16 instructions (none of "
            f"{', '.join(BF16_FLAGS)} in /proc/cpuinfo), so its bfloat16 products would be "
            f"emulated, slower than float32; {instead}."
        )


def configure_process(threads: int) -> None:
    """What every trainer and benchmark sets once, before its first tensor: ``threads`` torch
    CPU threads (they change rounding, which is why ``threads`` is in every run's config), the
    heap setting of :func:`reuse_freed_memory`, which changes no result, and
    :func:`flush_denormals`, which changes a result only where a number falls below float32's
    smallest normal value."""
    import torch

    torch.set_num_threads(threads)
    flush_denormals()
    reuse_freed_memory()


def flush_denormals() -> bool:
    """Compute with subnormal numbers (below 1.2e-38 in float32) as zero, in inputs and results
    (the CPU's flush-to-zero and denormals-are-zero modes, ``torch.set_flush_denormal``).

    A ReLU unit that stops firing leaves its weights' gradients at zero, and Adam's moments of
    those weights then decay geometrically through the subnormal range (the first moment by 0.9
    per update, within about 800 updates; the second by 0.999, within tens of thousands). On the
    Intel Xeon class every operation on a subnormal takes a microcode assist: Adam's step over
    (400, 300) networks with half their moments subnormal took 20x its normal time, and a TAC
    update from the 100,000-step checkpoint of an authors' profile run 3x
    (docs/performance.md, "Subnormal numbers"). Flushed, such a moment is zero, and the update
    it gives (below 1e-30 of the learning rate) was below every weight's last bit anyway.
    Returns whether the CPU supports the modes (x86 with SSE3, or Arm)."""
    import torch

    return bool(torch.set_flush_denormal(True))


def reuse_freed_memory() -> bool:
    """Let this process reuse the memory its tensors free instead of returning it to the OS.

    With glibc's defaults a temporary over 128 KiB is ``mmap``-ed and unmapped again when freed,
    so every TAC update page-faults its large temporaries back in: at K = 10 members
    (HalfCheetah, batch 100) about 2,900 minor faults per update, several milliseconds on a
    virtual machine. Raising the mmap threshold to 32 MiB and the trim threshold to 64 MiB keeps
    that memory in the heap. Results do not change. Returns whether the setting applied (glibc
    Linux only).
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
