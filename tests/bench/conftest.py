"""Saved benchmark baselines are per CPU class (``tacbench.hardware.cpu_class``).

Timings from one CPU say nothing about another, so ``tests/bench/baseline`` holds one folder
per class, and pytest-benchmark's ``--benchmark-storage`` pointing at ``tests/bench/baseline``
(``tox -e bench``) is narrowed to this machine's class before pytest-benchmark reads it. On a
class with no saved baseline there is nothing to compare with: the comparison is left out with
a warning that says so, and ``--benchmark-save=NAME`` saves this class's first baseline
(docs/performance.md).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
import torch

from tacbench.hardware import configure_process, cpu_class

BASELINE = Path(__file__).resolve().parent / "baseline"


@pytest.hookimpl(tryfirst=True)  # before pytest-benchmark's own pytest_configure reads it
def pytest_configure(config: pytest.Config) -> None:
    storage = config.getoption("benchmark_storage", default=None)
    if not isinstance(storage, str) or not storage.startswith("file://"):
        return
    if Path(storage.removeprefix("file://")).resolve() != BASELINE:
        return
    here = BASELINE / cpu_class()
    config.option.benchmark_storage = f"file://{here}"
    if config.getoption("benchmark_compare") and not any(here.glob("*/*.json")):
        config.option.benchmark_compare = False
        config.option.benchmark_compare_fail = None
        config.issue_config_time_warning(
            pytest.PytestConfigWarning(
                f"no saved benchmark baseline for this CPU class ({here.name}) in "
                f"{BASELINE}; nothing is compared. Save one with: tox -e bench -- "
                "--benchmark-save=NAME"
            ),
            stacklevel=2,
        )


@pytest.fixture(scope="module", autouse=True)
def one_thread() -> Iterator[None]:
    """Every benchmark on one torch thread (as a run's default ``--threads 1``)."""
    threads = torch.get_num_threads()
    configure_process(1)
    yield
    torch.set_num_threads(threads)
