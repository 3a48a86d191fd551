"""The process settings every trainer applies (tacbench/hardware.py, configure_process), and
the load meter of a sweep's bill."""

from __future__ import annotations

import subprocess
import sys

import pytest

from tacbench import hardware
from tacbench.hardware import LoadMeter

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


def test_the_load_meter_averages_readings_at_most_every_interval(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    clock, readings = [0.0], iter([1.0, 3.0, 99.0])
    monkeypatch.setattr(hardware.time, "monotonic", lambda: clock[0])
    monkeypatch.setattr(hardware.os, "getloadavg", lambda: (next(readings), 0.0, 0.0))
    meter = LoadMeter(every_s=10.0)
    assert meter.mean() is None
    meter.sample()  # the first reading: at once
    clock[0] = 9.0
    meter.sample()  # too soon: not read
    clock[0] = 10.0
    meter.sample()
    assert meter.mean() == 2.0
