"""A run's clocks: eval.csv logs the wall and CPU seconds of training so far, a checkpoint keeps
both, so a resumed run counts on from where it stopped; a run begun before eval.csv had
``cpu_s`` resumes in its own columns."""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pandas as pd
import pytest

from tacbench.runs import EVAL_COLUMNS, RunClock, clock, files
from tests.helpers import assert_same_results, tiny_configs, train

pytestmark = pytest.mark.smoke


def test_a_clock_counts_on_from_the_seconds_earlier_sessions_took() -> None:
    fresh, resumed, older = RunClock(), RunClock(100.0, 40.0), RunClock(100.0, None)
    sum(i * i for i in range(200_000))  # some CPU time
    assert 0.0 < fresh.cpu_s < 100.0 and 0.0 < fresh.wall_s < 100.0
    assert resumed.wall_s > 100.0 and 40.0 < resumed.cpu_s < 100.0
    assert older.cpu_s is None and older.wall_s > 100.0


def _fake_cpu(monkeypatch: pytest.MonkeyPatch, seconds: float) -> None:
    """The CPU clock reads 0 when a trainer makes its clock and ``seconds`` ever after: each
    session of a run adds exactly ``seconds``."""
    readings: Iterator[float] = itertools.chain([0.0], itertools.repeat(seconds))
    monkeypatch.setattr(clock, "process_time", lambda: next(readings))


def _run_dir(out: Path, configs: list[Any]) -> Path:
    c = configs[0]
    return out / "runs" / c.algo / "Hopper-v4" / c.variant / "seed0"


@pytest.mark.parametrize("learner", ["tac", "ddpg"])
def test_a_resumed_run_counts_cpu_time_on_from_its_checkpoint(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, learner: str
) -> None:
    configs = tiny_configs(learner)
    _fake_cpu(monkeypatch, 1000.0)
    (stopped,) = train(tmp_path, configs, stop=lambda step: step >= 730)
    assert stopped.state == "interrupted"
    _fake_cpu(monkeypatch, 1000.0)
    (outcome,) = train(tmp_path, configs, resume=True)
    assert outcome.state == "complete"
    evals = pd.read_csv(_run_dir(tmp_path, configs) / "eval.csv")
    assert tuple(evals.columns) == EVAL_COLUMNS
    # step 500 in the first session; 1,000 and 1,500 in the second, on top of the first's
    assert evals["cpu_s"].tolist() == [1000.0, 2000.0, 2000.0]
    assert evals["wall_s"].is_monotonic_increasing


@pytest.mark.parametrize("learner", ["tac", "ddpg"])
def test_a_run_begun_without_cpu_s_resumes_in_its_own_columns(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    uninterrupted: Callable[[str], Path],
    learner: str,
) -> None:
    configs = tiny_configs(learner)
    with monkeypatch.context() as older:  # as tacbench wrote eval.csv before it logged cpu_s
        older.setattr(files, "EVAL_COLUMNS", files.EVAL_COLUMNS_WITHOUT_CPU)
        (stopped,) = train(tmp_path, configs, stop=lambda step: step >= 730)
    assert stopped.state == "interrupted"
    (outcome,) = train(tmp_path, configs, resume=True)
    assert outcome.state == "complete", outcome.message
    run = _run_dir(tmp_path, configs)
    evals = pd.read_csv(run / "eval.csv")
    assert tuple(evals.columns) == files.EVAL_COLUMNS_WITHOUT_CPU
    assert evals["step"].tolist() == [500, 1000, 1500]
    assert_same_results(uninterrupted(learner), run)
