"""Which CPU this is, as far as float rounding is concerned.

The same library versions give different last digits on different CPUs: MKL and PyTorch pick
their kernels by vendor, model and instruction set (measured here: TAC's and PPO's CSVs from an
AMD EPYC and an Intel Xeon, both AVX-512, the same wheels, differ from the first update on).
:func:`cpu_class` names the class of CPUs that can be expected to agree to the last digit, for
the exact regression references (``tacbench.regress``) and the saved benchmark baselines
(``tests/bench``), which both belong to one class.
"""

from __future__ import annotations

import platform
import re
from functools import cache
from pathlib import Path

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


@cache
def l2_cache_bytes(default: int = 1 << 20) -> int:
    """The size of one core's level-2 cache (Linux sysfs; ``default``, 1 MiB, where unknown)."""
    for index in sorted(Path("/sys/devices/system/cpu/cpu0/cache").glob("index*")):
        try:
            level = (index / "level").read_text().strip()
            kind = (index / "type").read_text().strip()
            size = (index / "size").read_text().strip()
        except OSError:
            continue
        if level == "2" and kind in ("Unified", "Data"):
            return _parse_cache_size(size) or default
    return default


def _parse_cache_size(text: str) -> int:
    """sysfs cache sizes: ``2048K``, ``1M``, ``512``; 0 if unreadable."""
    match = re.fullmatch(r"(\d+)\s*([KMG]?)", text.strip().upper())
    if not match:
        return 0
    return int(match[1]) << {"": 0, "K": 10, "M": 20, "G": 30}[match[2]]
