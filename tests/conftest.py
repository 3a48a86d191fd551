"""Fixtures shared by several test modules."""

from __future__ import annotations

import fcntl
import os
import shutil
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from tests.helpers import tiny_configs, train


@contextmanager
def _locked(path: Path) -> Iterator[None]:
    """Hold an exclusive lock on ``path`` (created if missing) against other processes."""
    with path.open("a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def shared_tmp_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A temporary folder of this test session that every pytest-xdist worker of the session
    sees (each worker's own base folder is inside it); the base folder without xdist."""
    base = tmp_path_factory.getbasetemp()
    return base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base


@pytest.fixture(autouse=True)
def _no_calibrations_of_this_machine(
    tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Every test prices from an empty calibration store: a dry run reads the calibrations of
    the machine's CPU class (~/.cache/tacbench), and one a developer made with --calibrate (the
    smoke preset's TAC unit, say) turned a test's default* price into a calibrated one."""
    monkeypatch.setenv("TACBENCH_CALIBRATION", str(tmp_path_factory.mktemp("calibrations")))


@pytest.fixture(scope="session")
def uninterrupted(tmp_path_factory: pytest.TempPathFactory) -> Callable[[str], Path]:
    """The run directory of one uninterrupted tiny Hopper run per learner, trained once per
    test session (the reference that resumed and faulted runs are compared with; the first run
    of the determinism tests and the Hopper runs whose directories test_run_directory.py reads).

    Under pytest-xdist the workers share it: the first to ask for a learner trains it, under a
    lock, into a folder of the session they all see; the others wait for it and read it. Tests
    only read these directories."""
    shared = shared_tmp_path(tmp_path_factory) / "uninterrupted"
    shared.mkdir(exist_ok=True)

    def get(learner: str) -> Path:
        record = shared / f"{learner}.path"  # written once the run is complete
        with _locked(shared / f"{learner}.lock"):
            if not record.exists():
                shutil.rmtree(shared / learner, ignore_errors=True)  # a failed attempt's
                (outcome,) = train(shared / learner, tiny_configs(learner))
                assert outcome.state == "complete", outcome.message
                record.write_text(str(outcome.directory))
        return Path(record.read_text())

    return get
