"""A sweep unit's members train as one group; the worker trains them one at a time only when
they share no checkpoint step, leaves out a member whose CSVs cannot continue (its error is
that run's alone), and never splits a group refused for another reason (a run directory held
by another writer, for one: training the others alone would change them)."""

from __future__ import annotations

import os
import signal
import tempfile
from pathlib import Path
from typing import Any

import pytest

from tacbench import trainers
from tacbench.config import RunConfig
from tacbench.errors import TacbenchError
from tacbench.interrupts import SecondSignal
from tacbench.runs import Outcome
from tacbench.runs.checkpoints import NoCommonCheckpoint
from tacbench.runs.resume_checks import DamagedRun
from tacbench.sweep import driver, worker
from tacbench.sweep.plan import Run, Unit

pytestmark = pytest.mark.unit


class _Refusing:
    """A trainer that refuses with ``error`` any group that holds ``refused`` (a seed), or any
    group of more than one member when ``refused`` is None."""

    def __init__(self, error: TacbenchError, refused: int | None) -> None:
        self.error, self.refused, self.calls = error, refused, list[list[int]]()

    def train(self, configs: list[Any], out: Path, **_: Any) -> list[Outcome]:
        seeds = [c.seed for c in configs]
        self.calls.append(seeds)
        if self.refused in seeds or (self.refused is None and len(configs) > 1):
            raise self.error
        return [Outcome(c.seed, out, "complete", c.total_steps) for c in configs]


def _unit(seeds: tuple[int, ...]) -> Unit:
    return Unit(
        tuple(
            Run(RunConfig(env="Hopper-v4", q=1.0, alpha=0.2, seed=s, total_steps=10)) for s in seeds
        )
    )


def _train(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    error: TacbenchError,
    refused: int | None = None,
    seeds: tuple[int, ...] = (0, 10),
    damaged: dict[str, str] | None = None,
) -> tuple[_Refusing, list[Outcome] | TacbenchError]:
    trainer = _Refusing(error, refused)
    monkeypatch.setattr(trainers, "trainer_for", lambda algo: trainer)
    job = worker.Job(_unit(seeds), tmp_path, tmp_path / "log")
    stop = worker.StopHook(lambda step: False, 1.0)
    try:
        return trainer, worker._train(job, stop, {} if damaged is None else damaged)
    except TacbenchError as err:
        return trainer, err


def test_members_without_a_common_checkpoint_train_one_at_a_time(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    trainer, outcomes = _train(tmp_path, monkeypatch, NoCommonCheckpoint("different steps"))
    assert trainer.calls == [[0, 10], [0], [10]]
    assert isinstance(outcomes, list) and [o.seed for o in outcomes] == [0, 10]


def test_a_member_alone_without_a_usable_checkpoint_is_left_out_and_the_others_train(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Trained one at a time, a member whose every checkpoint is damaged ended the unit before
    the others started; the driver then failed them all with its error and gave them up."""
    refusal = NoCommonCheckpoint("no usable checkpoint to resume from: ... damaged")
    damaged: dict[str, str] = {}
    trainer, outcomes = _train(tmp_path, monkeypatch, refusal, 0, (0, 10), damaged)
    assert trainer.calls == [[0, 10], [0], [10]]
    assert isinstance(outcomes, list) and [o.seed for o in outcomes] == [10]
    key = _unit((0,)).runs[0].key
    assert damaged == {key: f"NoCommonCheckpoint: {refusal}"}


def test_a_group_refused_for_another_reason_is_not_split(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    held = TacbenchError("runs/.../seed10 is being written by another tacbench process")
    trainer, outcome = _train(tmp_path, monkeypatch, held)
    assert trainer.calls == [[0, 10]]
    assert outcome is held


def test_a_member_whose_csvs_cannot_continue_is_left_out_and_the_others_train_as_a_group(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The error is that run's alone (by run key), so that the driver records it against the
    damaged run and not against the members that trained on."""
    key = _unit((10,)).runs[0].key
    error = DamagedRun("cannot resume: eval.csv differs", tmp_path / key)
    damaged: dict[str, str] = {}
    trainer, outcomes = _train(tmp_path, monkeypatch, error, 10, (0, 10, 20), damaged)
    assert trainer.calls == [[0, 10, 20], [0, 20]]
    assert isinstance(outcomes, list) and [o.seed for o in outcomes] == [0, 20]
    assert damaged == {key: "DamagedRun: cannot resume: eval.csv differs"}


def test_a_damaged_run_outside_the_unit_is_not_left_out(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    error = DamagedRun("cannot resume", tmp_path / "runs" / "elsewhere")
    damaged: dict[str, str] = {}
    trainer, outcome = _train(tmp_path, monkeypatch, error, damaged=damaged)
    assert (trainer.calls, outcome, damaged) == ([[0, 10]], error, {})


def test_a_unit_whose_only_member_is_damaged_reports_it_as_that_runs_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    unit = _unit((0,))
    error = DamagedRun("cannot resume: train.csv is missing", tmp_path / unit.runs[0].key)
    trainer = _Refusing(error, 0)
    monkeypatch.setattr(trainers, "trainer_for", lambda algo: trainer)
    result = worker.execute(worker.Job(unit, tmp_path, tmp_path / "log"), lambda step: False)
    message = "DamagedRun: cannot resume: train.csv is missing"
    assert (result.outcomes, result.error) == ((), "")
    assert result.run_errors == {unit.runs[0].key: message}


def test_a_unit_whose_only_member_has_no_usable_checkpoint_reports_it_as_that_runs_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Its error used to end the unit like a crash, which the driver retried though every
    attempt meets the same damaged checkpoints."""
    unit = _unit((0,))
    refusal = NoCommonCheckpoint("no usable checkpoint to resume from: ... damaged")
    monkeypatch.setattr(trainers, "trainer_for", lambda algo: _Refusing(refusal, 0))
    result = worker.execute(worker.Job(unit, tmp_path, tmp_path / "log"), lambda step: False)
    assert (result.outcomes, result.error) == ((), "")
    assert result.run_errors == {unit.runs[0].key: f"NoCommonCheckpoint: {refusal}"}


def test_a_damaged_members_error_stays_its_own_when_the_rest_then_fail(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Member 10 left out, members 0 and 20 then crash: each run is charged with its own
    error (the damaged run's reason used to be lost, and the crash charged to it)."""
    unit = _unit((0, 10, 20))
    damaged = DamagedRun("cannot resume: eval.csv differs", tmp_path / unit.runs[1].key)

    class _Crashing:
        def train(self, configs: list[Any], out: Path, **_: Any) -> list[Outcome]:
            if any(c.seed == 10 for c in configs):
                raise damaged
            raise RuntimeError("the simulator crashed")

    monkeypatch.setattr(trainers, "trainer_for", lambda algo: _Crashing())
    result = worker.execute(worker.Job(unit, tmp_path, tmp_path / "log"), lambda step: False)
    assert result.error == "RuntimeError: the simulator crashed"
    assert result.run_errors == {unit.runs[1].key: f"DamagedRun: {damaged}"}
    reasons = [driver._error_of(run, result.error, result) for run in unit.runs]
    assert reasons == [result.error, f"DamagedRun: {damaged}", result.error]


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


def test_a_ray_tasks_default_scratch_is_in_its_own_nodes_temporary_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The driver used to send its own temporary folder's path (a laptop's /var/folders/...,
    through ray://) to every node."""
    unit = _unit((0,))
    relative = Path(worker.NODE_SCRATCH) / "0123456789ab"
    job = worker.Job(unit, relative, relative / "sweep" / "logs" / "u.log")
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    placed = worker.on_node(job)
    assert (placed.root, placed.log) == (tmp_path / relative, tmp_path / job.log)
    given = worker.Job(unit, tmp_path / "scratch", tmp_path / "scratch" / "u.log")
    assert worker.on_node(given) == given  # --scratch: the path given
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    home = worker.Job(unit, Path("~/scratch"), Path("~/scratch/u.log"))
    assert worker.on_node(home).root == tmp_path / "home" / "scratch"  # this node's home


@pytest.mark.parametrize(
    ("signals", "requeued"),
    [((signal.SIGUSR2,), True), ((signal.SIGUSR2, signal.SIGTERM), False), ((), False)],
    ids=["time-limit", "time-limit-then-cancelled", "stopped-otherwise"],
)
def test_a_job_near_its_time_limit_requeues_itself_unless_it_was_cancelled(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    signals: tuple[signal.Signals, ...],
    requeued: bool,
) -> None:
    """A Ctrl-C's scancel (SIGTERM) during the time-limit checkpoint used to be undone by the
    job's own requeue: the cancelled job came back and trained on."""
    unit = _unit((0,))

    def interrupted(job: worker.Job, report: Any, every_s: float = 1.0) -> worker.JobResult:
        for sig in signals:  # while the job runs, outside any trainer's handler
            os.kill(os.getpid(), sig)
        return worker.JobResult((Outcome(0, tmp_path, "interrupted", 5),))

    ran: list[list[str]] = []
    monkeypatch.setattr(worker, "execute", interrupted)
    monkeypatch.setattr(worker.subprocess, "run", lambda args, **_: ran.append(args))
    monkeypatch.setenv("SLURM_JOB_ID", "41_3")
    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGTERM, signal.SIGUSR2)}
    try:
        with pytest.raises(SystemExit, match="checkpointed, resumes when the job is requeued"):
            worker.slurm_main(worker.Job(unit, tmp_path, tmp_path / "log"))
    finally:
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
    assert ran == ([["scontrol", "requeue", "41_3"]] if requeued else [])
