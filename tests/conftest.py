"""Fixtures shared by several test modules."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from tests.helpers import tiny_configs, train


@pytest.fixture(scope="session")
def uninterrupted(tmp_path_factory: pytest.TempPathFactory) -> Callable[[str], Path]:
    """The run directory of one uninterrupted tiny Hopper run per learner, trained once per
    test session (the reference that resumed and faulted runs are compared with)."""
    cache: dict[str, Path] = {}

    def get(learner: str) -> Path:
        if learner not in cache:
            (outcome,) = train(tmp_path_factory.mktemp(learner), tiny_configs(learner))
            assert outcome.state == "complete", outcome.message
            cache[learner] = outcome.directory
        return cache[learner]

    return get
