"""The executors' options, checked without a cluster or a GPU: Slurm's time limits and sbatch
arguments, which flags go with which executor, how many local workers share a GPU, and clear
errors where Slurm is not installed or no GPU is visible."""

from __future__ import annotations

import getpass
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch
from click.testing import CliRunner

from tacbench import runs
from tacbench.cli import cli
from tacbench.errors import TacbenchError
from tacbench.sweep import driver, dry_run, options, plan, presets, slurm
from tacbench.sweep.plan import Unit

pytestmark = pytest.mark.unit


@pytest.mark.parametrize(
    ("text", "minutes"),
    [
        ("90", 90),
        ("30:00", 30),  # MINUTES:SECONDS, as sbatch reads it
        ("10:30", 11),  # ten minutes and a half, rounded up
        ("1:30:00", 90),
        ("0:10:00", 10),
        ("2-0", 2880),
        ("2-00:00", 2880),
        ("1-2:03:04", 1564),
    ],
)
def test_time_limits_in_slurms_formats(text: str, minutes: int) -> None:
    assert slurm.parse_time(text) == minutes


@pytest.mark.parametrize(
    "text", ["", "abc", "1:2:3:4", "-5", "0", "0:00", "0:99", "1:60:00", "1-2-3", "1-"]
)
def test_bad_time_limits_say_what_to_give(text: str) -> None:
    with pytest.raises(TacbenchError, match="--time"):
        slurm.parse_time(text)


@pytest.mark.parametrize("text", ["3", "0:04:59", "1:30", "9:59"])
def test_a_time_limit_that_leaves_no_training_before_the_signal_is_refused(text: str) -> None:
    """The checkpoint signal comes 180 s before the limit: at 3 minutes a job was signalled as
    it started, requeued itself, and did so without end, never counted as failing."""
    with pytest.raises(TacbenchError, match=r"is below 10 minutes: each job is signalled 180 s"):
        slurm.parse_time(text)


def test_slurm_args_become_sbatch_options() -> None:
    parsed = slurm.parse_slurm_args(("mem=8G", "--qos=normal", "mail-type=END", "comment=a=b"))
    assert parsed == {"mem": "8G", "qos": "normal", "mail_type": "END", "comment": "a=b"}
    for bad in ("mem", "=8G"):
        with pytest.raises(TacbenchError, match="KEY=VALUE"):
            slurm.parse_slurm_args((bad,))


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"partition": "gpu"}, "Slurm options"),
        ({"executor": "ray", "time_limit": "10"}, "Slurm options"),
        ({"executor": "slurm", "shared_fs": True}, "Ray options"),
        ({"executor": "slurm", "address": "auto"}, "Ray options"),
        ({"executor": "slurm", "time_limit": "soon"}, "--time"),
        ({"executor": "slurm", "slurm_args": ("mem",)}, "KEY=VALUE"),
        ({"executor": "slurm", "slurm_args": ("mem=",)}, "KEY=VALUE"),
        ({"executor": "slurm", "slurm_args": ("time=5",)}, "sets --time itself; give --time"),
        ({"executor": "slurm", "slurm_args": ("--cpus-per-task=8",)}, "give --cpus-per-run"),
        ({"executor": "slurm", "slurm_args": ("requeue=false",)}, "sets --requeue itself"),
        ({"executor": "slurm", "slurm_args": ("mem=1G", "mem=2G")}, "mem is given twice"),
        ({"executor": "slurm", "partition": ""}, "--partition needs a partition's name"),
        ({"executor": "pbs"}, "--executor must be one of local, ray, slurm"),
        ({"cpus_per_run": 2.0}, "--cpus-per-run is a Ray or Slurm request"),
        ({"gpus_per_run": 2.0}, "shares one GPU between its workers"),
        ({"gpus_per_run": 0.25, "workers": 5}, "needs 1.25 GPUs.*--workers 4 or less"),
        ({"executor": "ray", "cpus_per_run": float("nan")}, "--cpus-per-run must be > 0"),
        ({"executor": "ray", "gpus_per_run": float("inf")}, "--gpus-per-run >= 0"),
        ({"executor": "slurm", "gpus_per_run": 0.3}, "Slurm allocates whole CPUs and GPUs"),
        ({"executor": "slurm", "cpus_per_run": 1.5}, "Slurm allocates whole CPUs and GPUs"),
        ({"executor": "ray", "scratch": Path("scratch")}, "--scratch scratch: give an absolute"),
        ({"group": "none", "members": 4}, "--members 4 groups runs into units, which --group none"),
    ],
)
def test_options_that_do_not_go_together_are_refused(options: dict, message: str) -> None:
    with pytest.raises(TacbenchError, match=message):
        driver.Options(**options)


def _executor(out: Path) -> slurm.SlurmExecutor:
    """A Slurm executor for ``out`` with the tests' settings (submitit imported)."""
    pytest.importorskip("submitit")
    return slurm.SlurmExecutor(
        out,
        workers=None,
        partition=None,
        time_limit="10",
        cpus=1,
        gpus=0,
        slurm_args={},
        command="",
    )


def _on_a_login_node(monkeypatch: pytest.MonkeyPatch) -> list[float]:
    """sbatch and squeue found, time stood still at 1000 s: the returned clock moves it."""
    monkeypatch.setattr(slurm.shutil, "which", lambda name: f"/usr/bin/{name}")
    clock = [1000.0]
    monkeypatch.setattr(slurm.time, "monotonic", lambda: clock[0])
    monkeypatch.setattr(slurm.time, "sleep", lambda seconds: None)
    return clock


def _smoke_unit() -> Unit:
    return Unit((plan.build_runs(presets.get_preset("smoke"))[0],))


def test_no_slurm_on_the_path_is_a_clear_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(TacbenchError, match="sbatch and squeue"):
        _executor(tmp_path)


def test_jobs_of_an_earlier_driver_still_queued_are_waited_for(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A driver killed (or gone with its session under nohup) leaves its jobs running: a new
    driver used to submit their runs again, and each new attempt failed against the running
    one's lock, counted as a failure, until the runs were given up."""
    _on_a_login_node(monkeypatch)
    asked: list[list[str]] = []

    def queued(job_ids: list[str]) -> dict[str, str]:
        asked.append(sorted(job_ids))
        return {"41_0": "", "41_1": "Priority", "99": ""}

    monkeypatch.setattr(slurm, "_queued", queued)
    jobs = tmp_path / "sweep" / "slurm"
    for name in ("41_0", "41_1", "41_2", "40", "notes", "99"):
        (jobs / name).mkdir(parents=True)
    (jobs / "99" / "99_0_result.pkl").write_bytes(b"")  # ended (squeue may still list it)

    with pytest.raises(TacbenchError, match=r"still queued or running \(41_0, 41_1\); wait"):
        _executor(tmp_path)
    assert asked == [["40", "41_0", "41_1", "41_2"]]
    monkeypatch.setattr(slurm, "_queued", lambda job_ids: {})
    _executor(tmp_path)  # all ended: the sweep goes on


def test_a_job_gone_from_squeue_has_died_only_after_a_grace_period(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Its result file may reach a network filesystem's view late: two polls a second apart
    used to declare a job that had succeeded dead, losing its result; and squeue was asked
    every second for days."""
    clock = _on_a_login_node(monkeypatch)
    asked: list[float] = []
    monkeypatch.setattr(slurm, "_queued", lambda ids: asked.append(clock[0]) or {})
    monkeypatch.setattr(slurm, "_job_state", lambda job_id: "COMPLETED")
    executor = _executor(tmp_path)
    result = tmp_path / "7_0_result.pkl"
    job = SimpleNamespace(paths=SimpleNamespace(result_pickle=result, stderr=tmp_path / "err"))
    unit = _smoke_unit()
    executor._jobs["7"] = slurm._Submitted(unit, job)
    asked.clear()
    for now in (1000.0, 1005.0, 1009.0, 1010.0, 1089.0):
        clock[0] = now
        assert executor.wait(1.0) == []
    assert asked == [1000.0, 1010.0, 1089.0]  # every SQUEUE_EVERY_S at most, not every poll
    clock[0] = 1090.0
    (died,) = executor.wait(1.0)
    assert died.died.startswith("Slurm job 7 ended without a result (COMPLETED")
    # once the sweep has cancelled its jobs, one that leaves the queue has ended at once (a
    # Ctrl-C must not wait out the grace period)
    executor._jobs["8"] = slurm._Submitted(unit, job)
    cancelled: list[list[str]] = []
    monkeypatch.setattr(slurm.subprocess, "run", lambda args, **_: cancelled.append(args))
    executor.request_stop()
    assert cancelled == [["scancel", "8"]]
    clock[0] = 1100.0
    (stopped,) = executor.wait(1.0)
    assert stopped.unit == unit and "Slurm job 8 ended without a result" in stopped.died


def test_a_retried_runs_failed_status_is_not_its_jobs_progress(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Until the retry's job resets it, status.json holds the failed attempt's step, past the
    checkpoint the retry trains from: the progress took it as the new job's."""
    _on_a_login_node(monkeypatch)
    monkeypatch.setattr(slurm, "_queued", lambda ids: {})
    executor, unit = _executor(tmp_path), _smoke_unit()
    executor._jobs["7"] = slurm._Submitted(unit, SimpleNamespace())
    status = tmp_path / unit.runs[0].key / "status.json"
    status.parent.mkdir(parents=True)
    assert executor.steps() == {}  # not started yet
    runs.atomic_write_json(status, {"state": "failed", "step": 700, "reason": "non-finite"})
    assert executor.steps() == {}
    runs.atomic_write_json(status, {"state": "running", "step": 600})  # the job resumed
    assert executor.steps() == {unit.key: 600}


def test_squeue_is_asked_for_the_sweeps_own_jobs(monkeypatch: pytest.MonkeyPatch) -> None:
    """Bare job ids could match another user's job (after a wrap of Slurm's job ids)."""
    asked: list[list[str]] = []

    def squeue(args: list[str], **_: object) -> SimpleNamespace:
        asked.append(args)
        listing = "41_0|R|None\n41_1|PD|launch failed requeued held\n41_2|PD|None\n"
        return SimpleNamespace(returncode=0, stdout=listing, stderr="")

    monkeypatch.setattr(slurm.subprocess, "run", squeue)
    assert slurm._queued(["41_0", "41_3"]) == {
        "41_0": "",
        "41_1": "launch failed requeued held",  # a reason may have spaces
        "41_2": "None",
    }
    (args,) = asked
    assert f"--user={getpass.getuser()}" in args and "--name=tacbench-sweep" in args
    assert args[-2:] == ["--jobs", "41"]


def test_a_job_slurm_will_not_start_is_told_once_with_what_to_do(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A held job, or one asking more than its partition allows, pends for ever: the sweep
    used to wait for it without a word."""
    clock = _on_a_login_node(monkeypatch)
    monkeypatch.setattr(slurm, "_queued", lambda ids: {})
    executor = _executor(tmp_path)
    job = SimpleNamespace(paths=SimpleNamespace(result_pickle=tmp_path / "none.pkl"))
    for job_id in ("7_0", "7_1", "7_2", "7_3", "7_4"):
        executor._jobs[job_id] = slurm._Submitted(_smoke_unit(), job)
    listings = iter(
        [
            {
                "7_0": "JobHeldAdmin",
                "7_1": "PartitionTimeLimit",
                "7_2": "Resources",
                "7_3": "QOSMaxJobsPerUserLimit",  # waits for the user's other jobs: not stuck
                "7_4": "PartitionTimeLimit",  # told with 7_1: one notice per reason
                "8_0": "JobHeldUser",  # not this sweep's job
            },
            {"7_0": "JobHeldAdmin", "7_1": "PartitionTimeLimit", "7_2": "QOSMaxCpuPerJobLimit"},
            {"7_0": "", "7_1": "PartitionTimeLimit", "7_2": "QOSMaxCpuPerJobLimit"},  # released
            {"7_0": "JobHeldAdmin", "7_1": "PartitionTimeLimit", "7_2": ""},  # held again
            {"7_0": "launch failed requeued held", "7_1": "PartitionTimeLimit"},
        ]
    )
    monkeypatch.setattr(slurm, "_queued", lambda ids: next(listings))
    told = []
    for now in (1000.0, 1010.0, 1020.0, 1030.0, 1040.0):
        clock[0] = now
        assert executor.wait(1.0) == []
        told.append(executor.notices())
    assert told[0] == [
        "Slurm will not start job 7_0 (JobHeldAdmin): release it (scontrol release 7_0) or "
        "cancel (scancel); the sweep waits for it",
        "Slurm will not start 2 jobs (7_1 7_4) (PartitionTimeLimit): stop the sweep (Ctrl-C) and "
        "run it again with a --time, --partition or --slurm-arg that Slurm grants; the sweep "
        "waits for them",
    ]
    assert [[n.split(":")[0] for n in notes] for notes in told[1:]] == [
        ["Slurm will not start job 7_2 (QOSMaxCpuPerJobLimit)"],  # news only, once
        [],
        ["Slurm will not start job 7_0 (JobHeldAdmin)"],  # released, then held again
        ["Slurm will not start job 7_0 (launch failed requeued held)"],  # another reason
    ]


def test_a_failing_squeue_is_asked_again_before_the_sweep_stops(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """One failed squeue (a controller restarting) used to end the sweep, whose close then
    cancelled every job; meanwhile no job is taken for gone."""
    clock = _on_a_login_node(monkeypatch)
    down = TacbenchError("squeue failed: slurm_load_jobs error: Socket timed out")

    def failing(ids: list[str]) -> set[str]:
        raise down

    monkeypatch.setattr(slurm, "_queued", lambda ids: {})
    executor = _executor(tmp_path)
    monkeypatch.setattr(slurm, "_queued", failing)
    job = SimpleNamespace(paths=SimpleNamespace(result_pickle=tmp_path / "none.pkl"))
    executor._jobs["7"] = slurm._Submitted(_smoke_unit(), job)
    for now in (1000.0, 1200.0, 1599.0):  # past GONE_AFTER_S, but squeue cannot say
        clock[0] = now
        assert executor.wait(1.0) == []
    clock[0] = 1610.0  # failing for SQUEUE_DOWN_S: the sweep stops, saying why
    with pytest.raises(TacbenchError, match="squeue failed"):
        executor.wait(1.0)


def test_a_failed_jobs_reason_is_its_exception_not_the_path_of_its_log() -> None:
    failed = (
        "Job (task=0) failed during processing with trace:\n"
        "----------------------\n"
        "Traceback (most recent call last):\n"
        '  File "worker.py", line 1, in slurm_main\n'
        "OSError: [Errno 5] Input/output error\n"
        "----------------------\n"
        "You can check full logs with 'job.stderr(0)' and 'job.stdout(0)'or at paths:\n"
        "  - /out/sweep/slurm/7/7_0_log.err\n"
        "  - /out/sweep/slurm/7/7_0_log.out"
    )
    assert slurm._last_error_line(failed) == "OSError: [Errno 5] Input/output error"
    assert slurm._last_error_line("killed\nby the OOM killer") == "by the OOM killer"


def test_the_cli_refuses_a_bad_time_with_status_2(tmp_path: Path) -> None:
    args = ["sweep", "--preset", "smoke", "--executor", "slurm", "--time", "soon"]
    result = CliRunner().invoke(cli, [*args, "--out", str(tmp_path)])
    assert result.exit_code == 2, result.output
    assert "--time 'soon'" in result.output


@pytest.mark.parametrize(("share", "workers"), [(0.2, 5), (0.3, 3), (0.5, 2), (1.0, 1)])
def test_the_local_executor_shares_its_gpu_between_one_over_the_share_workers(
    share: float, workers: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(options.os, "sched_getaffinity", lambda _: set(range(16)), raising=False)
    assert driver.Options(gpus_per_run=share).worker_count() == workers
    assert driver.Options(gpus_per_run=share, workers=1).worker_count() == 1
    monkeypatch.setattr(options.os, "sched_getaffinity", lambda _: {0}, raising=False)
    assert driver.Options(gpus_per_run=share).worker_count() == 1  # never more than the cores


def test_a_gpu_sweep_plans_cuda_runs_and_refuses_to_start_without_a_gpu(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    options = driver.Options(gpus_per_run=0.5)
    work, _ = driver.load_plan(presets.get_preset("smoke"), tmp_path, options, save=False)
    assert {unit.runs[0].config.device for unit in work.units} == {"cuda"}
    assert "every figure above prices CPU cores" in dry_run.describe_plan(work, 2, "task")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(TacbenchError, match="--gpus-per-run trains on a CUDA GPU"):
        driver.run_sweep(presets.get_preset("smoke"), tmp_path, options)
    assert not (tmp_path / "runs").exists()


def test_a_cluster_estimate_says_its_workers_are_this_machines_cores() -> None:
    assert driver.Options().workers_source() == "this machine's cores"
    assert driver.Options(workers=3).workers_source() == "--workers"
    for executor in ("ray", "slurm"):
        source = driver.Options(executor=executor).workers_source()
        assert "not the cluster's: give --workers N" in source
