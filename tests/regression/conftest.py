"""Shared by the regression tier: where the committed references are, and planting changes."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from tacbench import config

REFERENCE = Path(__file__).resolve().parents[2] / "results" / "reference"


@pytest.fixture
def plant_tac_setting(monkeypatch: pytest.MonkeyPatch) -> Callable[..., None]:
    """Make every TAC run built by the CLI use the given RunConfig settings (a planted change
    in what tacbench computes, e.g. ``tau=0.01``)."""

    def plant(**settings: Any) -> None:
        original = config.make_run_configs

        def planted(*args: Any, **kwargs: Any) -> Any:
            return original(*args, **{**kwargs, **settings})

        monkeypatch.setattr(config, "make_run_configs", planted)

    return plant
