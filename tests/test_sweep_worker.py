"""A sweep unit's members train as one group; the worker trains them one at a time only when
they share no checkpoint step, never when the group was refused for another reason (a run
directory held by another writer, for one: training the others alone would change them)."""

from __future__ import annotations

import signal
from pathlib import Path
from typing import Any

import pytest

from tacbench import trainers
from tacbench.config import RunConfig
from tacbench.errors import TacbenchError
from tacbench.interrupts import SecondSignal
from tacbench.runs import Outcome
from tacbench.runs.checkpoints import NoCommonCheckpoint
from tacbench.sweep import worker
from tacbench.sweep.plan import Run, Unit

pytestmark = pytest.mark.unit


class _Refusing:
    """A trainer that refuses any group of more than one member with ``error``."""

    def __init__(self, error: TacbenchError) -> None:
        self.error, self.calls = error, list[list[int]]()

    def train(self, configs: list[Any], out: Path, **_: Any) -> list[Outcome]:
        self.calls.append([c.seed for c in configs])
        if len(configs) > 1:
            raise self.error
        return [Outcome(configs[0].seed, out, "complete", configs[0].total_steps)]


def _train(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, error: TacbenchError
) -> tuple[_Refusing, list[Outcome] | TacbenchError]:
    trainer = _Refusing(error)
    monkeypatch.setattr(trainers, "trainer_for", lambda algo: trainer)
    unit = Unit(
        tuple(
            Run(RunConfig(env="Hopper-v4", q=1.0, alpha=0.2, seed=s, total_steps=10))
            for s in (0, 10)
        )
    )
    job = worker.Job(unit, tmp_path, tmp_path / "log")
    try:
        return trainer, worker._train(job, worker.StopHook(lambda step: False, 1.0))
    except TacbenchError as err:
        return trainer, err


def test_members_without_a_common_checkpoint_train_one_at_a_time(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    trainer, outcomes = _train(tmp_path, monkeypatch, NoCommonCheckpoint("different steps"))
    assert trainer.calls == [[0, 10], [0], [10]]
    assert isinstance(outcomes, list) and [o.seed for o in outcomes] == [0, 10]


def test_a_group_refused_for_another_reason_is_not_split(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    held = TacbenchError("runs/.../seed10 is being written by another tacbench process")
    trainer, outcome = _train(tmp_path, monkeypatch, held)
    assert trainer.calls == [[0, 10]]
    assert outcome is held


def test_a_second_signal_in_a_worker_ends_its_unit_quietly(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Two Ctrl-Cs: the trainer stops at once (SecondSignal, a KeyboardInterrupt); the worker
    says so (in its unit's log, where its output goes) instead of dying with a traceback on the
    terminal, and reports no error, so that the runs are not counted as failed."""

    class _Stopped:
        def train(self, configs: list[Any], out: Path, **_: Any) -> list[Outcome]:
            raise SecondSignal(signal.SIGINT)

    monkeypatch.setattr(trainers, "trainer_for", lambda algo: _Stopped())
    unit = Unit((Run(RunConfig(env="Hopper-v4", q=1.0, alpha=0.2, seed=0, total_steps=10)),))
    result = worker.execute(worker.Job(unit, tmp_path, tmp_path / "log"), lambda step: False)
    assert (result.error, result.outcomes) == ("", ())
    assert capsys.readouterr().err == "stopped at once by a second SIGINT\n"
