"""The process settings every trainer applies (tacbench/hardware.py, configure_process)."""

from __future__ import annotations

import subprocess
import sys

PROBE = """
import torch
from tacbench.hardware import configure_process

def product():  # 1e-20 x 1e-20 = 1e-40: a subnormal float32 result
    return (torch.tensor([1e-20]) * torch.tensor([1e-20])).item()

def moment():  # Adam's second moment of a weight whose gradient stays zero, from a normal 1e-37
    return (torch.tensor([1e-37]) * 0.999**3000).item()

before = (product(), moment())
configure_process(1)
print(before[0], before[1], product(), moment())
"""


def test_configure_process_flushes_subnormal_numbers_to_zero() -> None:
    """A fresh process (another test may have configured this one) computes subnormal float32
    values until configure_process, and zero after it."""
    done = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, check=True)
    before_product, before_moment, after_product, after_moment = map(float, done.stdout.split())
    assert 0 < before_product < 1.2e-38 and 0 < before_moment < 1.2e-38
    assert after_product == 0.0 and after_moment == 0.0
