"""An unexpected error during training ends the run recorded as crashed (status.json
``failed``, with the error), not left ``running``; ``--resume`` continues it from its last
checkpoint to the results of an uninterrupted run, and a plain rerun says so."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from tacbench.runs import run_directory
from tacbench.training import loop
from tests.helpers import assert_same_results, tiny_configs, train

pytestmark = pytest.mark.unit


def test_a_crash_is_recorded_and_resume_continues_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    configs = tiny_configs("tac")
    real, calls = loop.update, {"n": 0}

    def failing(*args: Any, **kwargs: Any) -> Any:
        calls["n"] += 1
        if calls["n"] == 300:  # step 1,299: after the checkpoint at 1,000
            raise RuntimeError("a bug in the update")
        return real(*args, **kwargs)

    monkeypatch.setattr(loop, "update", failing)
    with pytest.raises(RuntimeError, match="a bug in the update"):
        train(tmp_path / "crash", configs)
    directory = run_directory(tmp_path / "crash", "tac", configs[0].env, configs[0].variant, 0)
    status = json.loads((directory / "status.json").read_text())
    assert status["state"] == "failed" and status["step"] == 1000  # the last checkpoint
    assert status["reason"].startswith("crashed at step 1299: RuntimeError: a bug in the update")
    monkeypatch.setattr(loop, "update", real)

    [skipped] = train(tmp_path / "crash", configs)
    assert skipped.state == "failed" and "--resume continues it" in skipped.message
    [resumed] = train(tmp_path / "crash", configs, resume=True)
    assert resumed.state == "complete"
    train(tmp_path / "lone", configs)
    lone = run_directory(tmp_path / "lone", "tac", configs[0].env, configs[0].variant, 0)
    assert_same_results(directory, lone)


def test_a_baselines_crash_is_recorded_too(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from baselines import trainer

    def failing(self: Any, *args: Any, **kwargs: Any) -> Any:
        raise RuntimeError("an evaluation bug")

    monkeypatch.setattr(trainer._Run, "evaluate", failing)
    configs = tiny_configs("ddpg")
    with pytest.raises(RuntimeError, match="an evaluation bug"):
        train(tmp_path, configs)
    directory = run_directory(tmp_path, "ddpg", configs[0].env, configs[0].variant, 0)
    status = json.loads((directory / "status.json").read_text())
    assert status["state"] == "failed" and status["step"] == 0  # no checkpoint yet
    assert status["reason"].startswith("crashed at step 500: RuntimeError: an evaluation bug")
