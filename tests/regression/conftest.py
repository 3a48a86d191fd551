"""Shared by the regression tier: where the committed references are, and planting changes."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from tacbench import trainers
from tacbench.cli import cli
from tacbench.cli.regress import in_process

REFERENCE = Path(__file__).resolve().parents[2] / "results" / "reference"
RUNNER = in_process(
    cli
)  # the recorded commands run in this process, as `tacbench regress` runs them


@pytest.fixture
def plant_tac_setting(monkeypatch: pytest.MonkeyPatch) -> Callable[..., None]:
    """Make every TAC run built by the CLI use the given RunConfig settings (a planted change
    in what tacbench computes, e.g. ``tau=0.01``)."""

    def plant(**settings: Any) -> None:
        original = trainers.make_run_configs

        def planted(*args: Any, **kwargs: Any) -> Any:
            return original(*args, **{**kwargs, **settings})

        monkeypatch.setattr(trainers, "make_run_configs", planted)

    return plant
