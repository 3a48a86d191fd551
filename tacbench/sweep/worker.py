"""What runs in a sweep's worker (a local process, a Ray task or a Slurm job): train one unit.

The unit's runs are trained with their trainer's ``train(..., resume=True)`` (TAC's
:func:`tacbench.training.train` or :func:`baselines.trainer.train`), so a new run starts, a
partial one continues from its checkpoint and a complete one is skipped. A failed run that the
sweep retries is first reset to "running", so it continues from its last checkpoint. The
trainer's ``stop`` hook reports the step to the driver about once a second and asks it whether
to stop; stopping checkpoints every run and leaves it resumable.

Everything the unit prints (progress lines, warnings, a traceback) goes to its log file.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import traceback
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from multiprocessing.connection import Connection
from multiprocessing.synchronize import Event
from pathlib import Path
from typing import TYPE_CHECKING, Any

from tacbench import runs, trainers
from tacbench.errors import one_line
from tacbench.interrupts import SecondSignal, received_signals
from tacbench.runs import checkpoints
from tacbench.runs.checkpoints import FULL_ERRNOS, DiskError, NoCommonCheckpoint
from tacbench.runs.resume_checks import DamagedRun
from tacbench.sweep.plan import Run, Unit

if TYPE_CHECKING:
    from tacbench.runs import Outcome

Report = Callable[[int], bool]  # step -> whether to stop
LOG_TAIL_BYTES = 64_000  # how much of an attempt's log a Ray task sends back to the driver


@dataclass(frozen=True)
class Job:
    """A unit and where the worker writes: ``root`` holds ``runs/...`` (``--out`` itself, or a
    Ray node's scratch folder), ``log`` is the unit's log file on the worker."""

    unit: Unit
    root: Path
    log: Path
    command: str = ""
    threads: int = 1
    return_files: bool = False  # Ray without a shared filesystem: send the small files back


@dataclass(frozen=True)
class JobResult:
    """How a unit ended: the trainer's outcomes, or the error that ended it, and the errors of
    runs left out of it (``run_errors``, by run key: theirs instead); with ``return_files``
    each run's small files (run key -> file name -> bytes)."""

    outcomes: tuple[Outcome, ...] = ()
    error: str = ""
    files: dict[str, dict[str, bytes]] = field(default_factory=dict)
    log_tail: str = ""
    node: str = ""
    host: str = ""
    disk_full: bool = False  # the error was a full disk: the driver stops the whole sweep
    run_errors: dict[str, str] = field(default_factory=dict)  # run key -> its own error


class StopHook:
    """The trainers' ``stop(step)``: calls ``report`` at most every ``every_s`` seconds (it may
    be a message to another process or machine) and returns its last answer."""

    def __init__(self, report: Report, every_s: float) -> None:
        self.report, self.every_s = report, every_s
        self._next, self._stop = 0.0, False

    def __call__(self, step: int) -> bool:
        now = time.monotonic()
        if now >= self._next:
            self._next = now + self.every_s
            self._stop = self.report(step)
        return self._stop


def execute(job: Job, report: Report, every_s: float = 1.0) -> JobResult:
    """Train ``job``'s unit; an exception becomes ``JobResult.error`` (its traceback goes to the
    log), so the driver can record it and retry. A member whose CSVs cannot continue is left
    out, the others trained, and its error is reported as that run's alone."""
    host = socket.gethostname()
    damaged: dict[str, str] = {}
    try:
        for key in job.unit.retry:
            reset_failed(job.root / key)
        outcomes = _train(job, StopHook(report, every_s), damaged)
    except SecondSignal as stopped:  # the sweep is stopping at once; said here, in the log
        print(f"stopped at once by a second {stopped}", file=sys.stderr, flush=True)
        return JobResult(host=host)
    except Exception as err:
        traceback.print_exc()
        full = isinstance(err, DiskError) and err.full
        return JobResult(error=one_line(err), run_errors=damaged, host=host, disk_full=full)
    return JobResult(tuple(outcomes), run_errors=damaged, host=host)


def _train(job: Job, stop: StopHook, damaged: dict[str, str]) -> list[Outcome]:
    """Train ``job``'s runs as one group. A member whose CSVs cannot continue is left out
    (its error goes to ``damaged``, by run key) and the group trained without it; members
    that share no checkpoint step are trained one at a time, and one of them whose every
    checkpoint is damaged is left out alike, the others trained."""

    def call(members: list[Run]) -> list[Outcome]:
        try:
            return trainers.trainer_for(members[0].config.algo).train(
                [run.config for run in members],
                job.root,
                resume=True,
                quiet=True,
                command=job.command,
                stop=stop,
            )
        except DamagedRun as err:  # checked before anything is written, for every member
            left_out = [run for run in members if job.root / run.key == err.directory]
            if not left_out:
                raise
            print(f"left out of its unit: {err}", file=sys.stderr, flush=True)
            damaged[left_out[0].key] = one_line(err)
            rest = [run for run in members if run not in left_out]
            return call(rest) if rest else []
        except NoCommonCheckpoint as err:  # one member has none, or only damaged ones
            if len(members) == 1:  # every checkpoint of its own damaged: its error
                print(f"left out of its unit: {err}", file=sys.stderr, flush=True)
                damaged[members[0].key] = one_line(err)
                return []
            print(f"training the members one at a time: {err}", file=sys.stderr, flush=True)
        outcomes: list[Outcome] = []
        for run in members:
            outcomes += call([run])
            if any(outcome.state == "interrupted" for outcome in outcomes):
                break
        return outcomes

    return call(list(job.unit.runs))


def reset_failed(directory: Path) -> None:
    """Set a failed run's status back to "running", at the step of its last checkpoint (0 when it
    has none), so that its trainer resumes it from there (or starts it afresh); the reason names
    the failure retried."""
    path = directory / "status.json"
    if not path.exists():
        return
    status = runs.read_json(path)
    if status.get("state") == "failed":
        resumes_at = checkpoints.newest_step(directory / "checkpoint") or 0
        reason = f"retrying after: {status.get('reason', '')}"
        status.update(state="running", step=resumes_at, reason=reason)
        status["updated"] = runs.now_iso()
        runs.atomic_write_json(path, status)


@contextlib.contextmanager
def output_to(log: Path, title: str) -> Iterator[int]:
    """Send this process's stdout and stderr (Python's and the file descriptors) to ``log``,
    appended after a header line; yields the offset where this attempt's output starts."""
    log.parent.mkdir(parents=True, exist_ok=True)
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    with log.open("a", buffering=1) as handle:
        handle.write(f"=== {runs.now_iso()} {socket.gethostname()} pid {os.getpid()}: {title}\n")
        start = handle.tell()
        os.dup2(handle.fileno(), 1)
        os.dup2(handle.fileno(), 2)
        streams = sys.stdout, sys.stderr
        sys.stdout = sys.stderr = handle
        try:
            yield start
        finally:
            sys.stdout, sys.stderr = streams
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            os.close(saved[0])
            os.close(saved[1])


def limit_threads(threads: int) -> None:
    """One BLAS/OpenMP pool of ``threads`` threads (set before torch or NumPy start theirs)."""
    for name in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ[name] = str(threads)


def local_main(job: Job, conn: Connection, step: Any, stop_event: Event, parent_pid: int) -> None:
    """Entry point of a local worker process: train, then send the :class:`JobResult`.

    Ctrl-C reaches the whole process group; until the trainer installs its handler (which
    checkpoints and stops) it is ignored here, and the driver's stop event does the rest. The
    worker also stops if the driver is gone (its parent changed)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    limit_threads(job.threads)

    def report(at: int) -> bool:
        step.value = at
        return stop_event.is_set() or os.getppid() != parent_pid

    try:
        with output_to(job.log, job.unit.key):
            result = execute(job, report)
    except OSError as err:
        result = _log_failed(job, err)
    conn.send(result)
    conn.close()


NODE_SCRATCH = "tacbench-sweep"  # a Ray node's default scratch, in its temporary folder


def on_node(job: Job) -> Job:
    """``job`` with its ``root`` (and log) resolved on this node: ``~`` as this node's home, a
    relative one (the default scratch) in this node's temporary folder."""
    root, log = job.root.expanduser(), job.log.expanduser()
    if not root.is_absolute():
        base = Path(tempfile.gettempdir())
        root, log = base / root, base / log
    return replace(job, root=root, log=log)


def ray_main(job: Job, board: Any) -> JobResult:
    """Body of a Ray task: train, then (without a shared filesystem) collect the runs' small
    files and the log of this attempt for the driver. Checkpoints stay in ``job.root`` (on
    this node: :func:`on_node`)."""
    import ray

    job = on_node(job)
    limit_threads(job.threads)
    if job.return_files:  # a run new to --out starts afresh, whatever this node kept of it
        for fresh in job.unit.fresh:
            shutil.rmtree(job.root / fresh, ignore_errors=True)
    key = job.unit.key
    node = ray.get_runtime_context().get_node_id()
    # where this attempt runs, known to the driver even if the task dies (out of memory)
    ray.get(board.started.remote(key, node, socket.gethostname()))
    start = 0
    try:
        with output_to(job.log, key) as start:
            result = execute(job, lambda at: bool(ray.get(board.report.remote(key, at))), 2.0)
    except OSError as err:
        result = _log_failed(job, err)
    files = {run.key: small_files(job.root / run.key) for run in job.unit.runs}
    try:
        with job.log.open("rb") as handle:
            handle.seek(max(start, job.log.stat().st_size - LOG_TAIL_BYTES))
            tail = handle.read().decode(errors="replace")
    except OSError:  # the log could not be written (the result says why)
        tail = ""
    return replace(
        result,
        files=files if job.return_files else {},
        log_tail=tail if job.return_files else "",
        node=node,
    )


def slurm_main(job: Job) -> JobResult:
    """Body of a Slurm job (through submitit): train into ``--out`` on the shared file system.

    SIGTERM (preemption, ``scontrol requeue``, ``scancel``; the trainer's own handler) and
    SIGUSR2 (the time limit is near; this function's) make the trainer checkpoint and return
    "interrupted"; the job then exits without a result, so the driver keeps waiting for the
    requeued attempt, which resumes from the checkpoint. After SIGUSR2 the job requeues itself
    (Slurm requeues preempted jobs on its own), unless a SIGTERM came too: a cancel then stays
    cancelled (:func:`requeues_itself`)."""
    near_limit: list[int] = []
    signal.signal(signal.SIGUSR2, lambda signum, _frame: near_limit.append(signum))
    # a SIGTERM outside the trainer's handler (starting up, returning) is recorded here too
    terminated: list[int] = []
    signal.signal(signal.SIGTERM, lambda signum, _frame: terminated.append(signum))
    limit_threads(job.threads)
    try:
        with output_to(job.log, f"{job.unit.key} (Slurm job {_slurm_job_id()})"):
            result = execute(job, lambda _at: bool(near_limit))
    except OSError as err:
        result = _log_failed(job, err)
    if not any(outcome.state == "interrupted" for outcome in result.outcomes):
        return result
    if requeues_itself(bool(near_limit), (*received_signals(), *terminated)):
        subprocess.run(["scontrol", "requeue", _slurm_job_id()], check=False)
    sys.exit("stopped by a signal from Slurm: checkpointed, resumes when the job is requeued")


def requeues_itself(near_limit: bool, received: tuple[int, ...]) -> bool:
    """Whether a stopped Slurm job asks to be requeued: near its time limit (SIGUSR2), unless a
    SIGTERM came too (a cancel, which must stay cancelled, or a preemption or requeue, which
    Slurm requeues itself)."""
    return near_limit and signal.SIGTERM not in received


def _slurm_job_id() -> str:
    """This job's id as scontrol takes it (an array task's own id)."""
    return os.environ.get("SLURM_JOB_ID", "?")


def _log_failed(job: Job, err: OSError) -> JobResult:
    """The unit's result when its log could not be written (a full disk: the driver stops)."""
    return JobResult(
        error=f"cannot write the log {job.log}: {os.strerror(err.errno or 0).lower()}",
        host=socket.gethostname(),
        disk_full=err.errno in FULL_ERRNOS,
    )


def small_files(directory: Path) -> dict[str, bytes]:
    """Every file directly in a run directory (config.json, status.json, the CSVs), not the
    checkpoint folder or temporary files."""
    if not directory.is_dir():
        return {}
    return {
        p.name: p.read_bytes()
        for p in sorted(directory.iterdir())
        if p.is_file() and not p.name.endswith(".tmp")
    }
