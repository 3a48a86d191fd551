"""A run's clocks: eval.csv logs the wall and CPU seconds of training so far, a checkpoint keeps
both, so a resumed run counts on from where it stopped; a run begun before eval.csv had
``cpu_s`` resumes in its own columns."""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pandas as pd
import pytest
import torch

from tacbench import runs
from tacbench.report.series import read_series
from tacbench.runs import EVAL_COLUMNS, RunClock, clock, files
from tests.helpers import assert_same_results, checkpoint_state, tiny_configs, train

pytestmark = pytest.mark.smoke


def test_a_clock_counts_on_from_the_seconds_earlier_sessions_took(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    fresh = RunClock()
    time.sleep(0.3)  # wall time, no CPU time
    assert fresh.wall_s >= 0.3 and fresh.cpu_s < 0.15
    monkeypatch.setattr(clock, "perf_counter", iter([10.0, 13.0]).__next__)
    monkeypatch.setattr(clock, "process_time", iter([5.0, 7.5]).__next__)
    resumed = RunClock(100.0, 40.0)
    assert (resumed.wall_s, resumed.cpu_s) == (103.0, 42.5)


def test_members_share_their_process_cpu_time_while_they_train(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Three members split each CPU second three ways; once member 1 stops (its loss no longer
    finite) the other two split what follows, so each run's cpu_s is what it cost."""
    monkeypatch.setattr(clock, "process_time", iter([0.0, 30.0, 30.0, 50.0, 50.0, 50.0]).__next__)
    shares = clock.CpuShares(3)
    runs = [RunClock(0.0, 100.0 * k, shares, k) for k in range(3)]
    assert runs[0].cpu_s == 10.0  # process time 30
    shares.stop(1)  # 30
    assert (runs[1].cpu_s, runs[2].cpu_s) == (110.0, 220.0)  # 50, then 50
    assert runs[0].cpu_s == 20.0


def _fake_clocks(
    monkeypatch: pytest.MonkeyPatch, seconds: float, members: int = 1, cpu_clocks: int = 1
) -> None:
    """Both clocks read 0 when a trainer makes its ``members`` clocks (the CPU clock once: its
    members share it; ``cpu_clocks`` times where they do not) and ``seconds`` ever after: each
    session of a run adds exactly ``seconds`` to the wall clock of each member and ``seconds /
    members`` to its CPU clock (``seconds`` where it logs the whole process's)."""
    for name, first in (("perf_counter", members), ("process_time", cpu_clocks)):
        readings = itertools.chain([0.0] * first, itertools.repeat(seconds))
        monkeypatch.setattr(clock, name, readings.__next__)


def _as_before_the_cpu_clock(monkeypatch: pytest.MonkeyPatch) -> None:
    """Write runs as tacbench did before it kept CPU time: eval.csv without ``cpu_s``, and
    checkpoints without it."""
    monkeypatch.setattr(files, "EVAL_COLUMNS", files.EVAL_COLUMNS_WITHOUT_CPU)
    save = torch.save

    def save_without_cpu(state: Any, *args: Any, **kwargs: Any) -> None:
        if isinstance(state, dict) and "cpu_s" in state:
            state = {key: value for key, value in state.items() if key != "cpu_s"}
        save(state, *args, **kwargs)

    monkeypatch.setattr(torch, "save", save_without_cpu)


@pytest.mark.parametrize("learner", ["tac", "ddpg"])
def test_a_resumed_run_counts_cpu_time_on_from_its_checkpoint(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, learner: str
) -> None:
    configs = tiny_configs(learner)
    _fake_clocks(monkeypatch, 1000.0)
    (stopped,) = train(tmp_path, configs, stop=lambda step: step >= 730)
    assert stopped.state == "interrupted"
    _fake_clocks(monkeypatch, 1000.0)
    (outcome,) = train(tmp_path, configs, resume=True)
    assert outcome.state == "complete"
    evals = pd.read_csv(outcome.directory / "eval.csv")
    assert tuple(evals.columns) == EVAL_COLUMNS
    # step 500 in the first session; 1,000 and 1,500 in the second, on top of the first's
    assert evals["cpu_s"].tolist() == evals["wall_s"].tolist() == [1000.0, 2000.0, 2000.0]


@pytest.mark.parametrize("learner", ["tac", "ddpg"])
def test_a_run_begun_without_cpu_s_resumes_in_its_own_columns(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    uninterrupted: Callable[[str], Path],
    learner: str,
) -> None:
    configs = tiny_configs(learner)
    with monkeypatch.context() as older:
        _as_before_the_cpu_clock(older)
        (stopped,) = train(tmp_path, configs, stop=lambda step: step >= 730)
    assert "cpu_s" not in checkpoint_state(stopped.directory)
    assert stopped.state == "interrupted"
    (outcome,) = train(tmp_path, configs, resume=True)
    assert outcome.state == "complete", outcome.message
    run = outcome.directory
    evals = pd.read_csv(run / "eval.csv")
    assert tuple(evals.columns) == files.EVAL_COLUMNS_WITHOUT_CPU
    assert evals["step"].tolist() == [500, 1000, 1500]
    assert_same_results(uninterrupted(learner), run)


def test_members_resumed_together_keep_their_own_clocks(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Seed 0 trained alone before the CPU clock, seeds 10 and 20 together after it; seeds 0 and
    10 resumed in one group: each goes on from its own checkpoint's clocks (the group took
    member 0's: seed 10's cpu_s fell from 500 to 25, or its cells were left empty, which the
    report cannot read), and seed 0 keeps its five columns. Each member's cpu_s is its half of
    its process's."""
    with monkeypatch.context() as older:
        _as_before_the_cpu_clock(older)
        (old,) = train(tmp_path, tiny_configs("tac", seeds=(0,)), stop=lambda step: step >= 730)
    _fake_clocks(monkeypatch, 1000.0, members=2)
    pair = train(tmp_path, tiny_configs("tac", seeds=(10, 20)), stop=lambda step: step >= 730)
    _fake_clocks(monkeypatch, 50.0, members=2)
    resumed = train(tmp_path, tiny_configs("tac", seeds=(0, 10)), resume=True)
    assert [o.state for o in (old, *pair)] == ["interrupted"] * 3
    assert [o.state for o in resumed] == ["complete"] * 2
    seed0, seed10 = (o.directory for o in resumed)
    assert tuple(pd.read_csv(seed0 / "eval.csv").columns) == files.EVAL_COLUMNS_WITHOUT_CPU
    clocks = pd.read_csv(seed10 / "eval.csv")
    assert clocks["wall_s"].tolist() == [1000.0, 1050.0, 1050.0]
    assert clocks["cpu_s"].tolist() == [500.0, 525.0, 525.0]
    for run in (seed0, seed10):
        assert read_series(run, "eval", "complete", 1500.0, "Hopper-v4").step.tolist() == [
            500.0,
            1000.0,
            1500.0,
        ]


def _updates_cost_a_cpu_second(monkeypatch: pytest.MonkeyPatch, fail_member_0: bool) -> list[int]:
    """Each update costs one CPU second (a fake process clock that counts them); with
    ``fail_member_0``, member 0's loss turns non-finite at its first. Returns the counter."""
    from tacbench.tac import update as tac_update
    from tacbench.training import loop

    updates = [0]

    def counted(agent: Any, sample: Any, c: Any, subset: Any) -> Any:
        metrics = tac_update.update(agent, sample, c, subset)
        if fail_member_0:
            metrics[:1] = float("nan")
        updates[0] += 1
        return metrics

    monkeypatch.setattr(loop, "update", counted)
    monkeypatch.setattr(clock, "process_time", lambda: float(updates[0]))
    return updates


def _as_before_members_split_cpu_s(monkeypatch: pytest.MonkeyPatch) -> None:
    """Start runs as tacbench did before members split their process's CPU seconds: no
    cpu_clock in config.json, and each member's cpu_s the whole process's."""
    from tacbench.training import loop

    metadata = runs.run_metadata

    def without_the_clock(*args: Any, **kwargs: Any) -> dict[str, Any]:
        return {k: v for k, v in metadata(*args, **kwargs).items() if k != "cpu_clock"}

    monkeypatch.setattr(runs, "run_metadata", without_the_clock)
    monkeypatch.setattr(loop, "RunClock", lambda wall_s, cpu_s, *shared: RunClock(wall_s, cpu_s))


def test_a_member_that_fails_leaves_its_cpu_share_to_the_others(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Member 0's loss turns non-finite at the first update: the two split that update's
    second, and member 1 alone is charged every later one."""
    updates = _updates_cost_a_cpu_second(monkeypatch, fail_member_0=True)
    outcomes = train(tmp_path, tiny_configs("tac", seeds=(0, 10)))
    assert [o.state for o in outcomes] == ["failed", "complete"]
    survivor = pd.read_csv(outcomes[1].directory / "eval.csv")["cpu_s"].tolist()
    assert updates[0] > 100 and survivor[-1] == updates[0] - 0.5


def test_a_failed_member_begun_before_the_split_leaves_its_share_too(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Seed 0 begun before members split cpu_s, seed 10 after, resumed as one group: seed 0
    fails at the group's first update, and seed 10 is charged every later second (seed 0 kept
    its slot in the split, and its share went to no one)."""
    with monkeypatch.context() as older:
        _as_before_members_split_cpu_s(older)
        train(tmp_path, tiny_configs("tac", seeds=(0,)), stop=lambda step: step >= 730)
    (alone,) = train(tmp_path, tiny_configs("tac", seeds=(10,)), stop=lambda step: step >= 730)
    before = checkpoint_state(alone.directory)["cpu_s"]  # at step 730
    updates = _updates_cost_a_cpu_second(monkeypatch, fail_member_0=True)
    resumed = train(tmp_path, tiny_configs("tac", seeds=(0, 10)), resume=True)
    assert [o.state for o in resumed] == ["failed", "complete"]
    last = pd.read_csv(resumed[1].directory / "eval.csv")["cpu_s"].tolist()[-1]
    assert updates[0] > 100 and last == pytest.approx(before + updates[0] - 0.5, abs=1e-3)


def test_a_run_begun_before_members_split_cpu_s_goes_on_logging_its_process(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Its config.json has no cpu_clock, and its first session logged the whole process's CPU
    seconds: resumed, it goes on doing so, rather than switch to a share within one column."""
    configs = tiny_configs("tac", seeds=(0, 10))
    with monkeypatch.context() as older:
        _as_before_members_split_cpu_s(older)
        _fake_clocks(older, 1000.0, members=2, cpu_clocks=3)  # the group's, then each member's
        stopped = train(tmp_path, configs, stop=lambda step: step >= 730)
    _fake_clocks(monkeypatch, 50.0, members=2, cpu_clocks=3)
    resumed = train(tmp_path, configs, resume=True)
    assert [o.state for o in (*stopped, *resumed)] == ["interrupted"] * 2 + ["complete"] * 2
    for outcome in resumed:
        evals = pd.read_csv(outcome.directory / "eval.csv")
        assert evals["cpu_s"].tolist() == evals["wall_s"].tolist() == [1000.0, 1050.0, 1050.0]
