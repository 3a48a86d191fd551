"""The Slurm executor: a sweep's units as one job array per batch, submitted through submitit.

Each unit becomes one task of a Slurm job array (``submitit.SlurmExecutor.batch``) running
:func:`tacbench.sweep.worker.slurm_main` on a compute node; every node sees ``--out`` on the
shared file system, where the runs, their checkpoints and the unit logs are written. A job that
Slurm preempts, requeues (``scontrol requeue``) or cancels gets SIGTERM, and one that nears its
time limit gets SIGUSR2 (``--signal=USR2@``:data:`SIGNAL_DELAY_S`); either way the trainer
checkpoints and the job exits without a result, and a job near its time limit requeues itself
(``--requeue`` is set on every job), so the requeued attempt resumes exactly from the
checkpoint. The driver sees a unit end when its job writes a result (submitit's result file)
or leaves Slurm's queue without one (a job killed, cancelled or failed outside Python: then it
"died", and the driver's retry rules apply as for a worker process that died).

No accounting database is needed: jobs are followed with ``squeue``, not ``sacct``.
"""

from __future__ import annotations

import getpass
import math
import re
import shutil
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tacbench import runs
from tacbench.errors import TacbenchError, listing
from tacbench.sweep import state, worker
from tacbench.sweep.executors import Finished
from tacbench.sweep.plan import Unit

SIGNAL_DELAY_S = 180
"""Seconds before the time limit at which Slurm sends SIGUSR2: time for a checkpoint."""
DEFAULT_TIME = "4:00:00"
"""--time default: a Hopper TAC unit of five members at 100,000 steps with room to spare; a
longer run is requeued at the limit and resumes, so a short limit costs only queue time."""
JOB_NAME = "tacbench-sweep"  # every job's name: squeue lists the sweep's own jobs by it
MAX_UNITS = 1000
"""Units in flight without --workers: Slurm's default MaxArraySize is 1001."""
# --time: the signal comes SIGNAL_DELAY_S before the limit, or up to 60 s earlier (sbatch's
# manual), and a job must start, load its checkpoint and train before it
MIN_TIME_S = 600
# a job missing from squeue without a result for this long has died: its result file may reach
# this machine's view of a network filesystem that late (attribute caches hold up to 60 s)
GONE_AFTER_S = 90.0
SQUEUE_EVERY_S = 10.0  # how often squeue is asked: a sweep's driver runs for days
SQUEUE_DOWN_S = 600.0  # how long squeue may fail before the sweep stops (and cancels its jobs)
# squeue's reasons for a pending job that Slurm will not start until someone acts (squeue's
# manual, "JOB REASON CODES"): a hold, by its user, an administrator or Slurm itself ("launch
# failed requeued held", after MaxBatchRequeue failed launches), or a request beyond what its
# partition, account or QOS allows per job (AssocMax*PerJob*, QOSMax*PerJob*)
HELD = re.compile(r"held", re.IGNORECASE)
BEYOND_LIMITS = re.compile(
    r"PartitionTimeLimit|PartitionConfig|BadConstraints|InvalidAccount|InvalidQOS"
    r"|AccountNotAllowed|QOSNotAllowed|Max\w*PerJob"
)
TIME_FORMATS = "MINUTES, MINUTES:SECONDS, H:MM:SS, D-H, D-H:MM or D-H:MM:SS"
"""sbatch's --time formats (its manual page), which --time takes as sbatch reads them."""


def parse_time(text: str) -> int:
    """Slurm's time limit in whole minutes from any of sbatch's formats (:data:`TIME_FORMATS`;
    seconds round up): ``90`` and ``1:30:00`` are 90 minutes, ``30:00`` is 30 and ``2-0`` two
    days."""
    text = text.strip()
    days, dash, clock = text.rpartition("-")
    fields = clock.split(":")
    if not all(f.isdigit() for f in [*fields, *([days] if dash else [])]) or len(fields) > 3:
        raise TacbenchError(f"--time {text!r}: give one of sbatch's formats, {TIME_FORMATS}.")
    values = [int(f) for f in fields]
    if dash:  # D-H, D-H:MM, D-H:MM:SS
        h, m, s = [*values, 0, 0][:3]
        seconds = ((int(days) * 24 + h) * 60 + m) * 60 + s
    elif len(values) == 3:  # H:MM:SS
        seconds = (values[0] * 60 + values[1]) * 60 + values[2]
    else:  # MINUTES or MINUTES:SECONDS
        seconds = values[0] * 60 + (values[1] if len(values) == 2 else 0)
    if any(v > 59 for v in values[1:]):
        raise TacbenchError(f"--time {text!r}: minutes and seconds after a ':' are below 60.")
    if seconds < MIN_TIME_S:
        raise TacbenchError(
            f"--time {text!r} is below {MIN_TIME_S // 60} minutes: each job is signalled "
            f"{SIGNAL_DELAY_S} s before its limit (or up to a minute earlier) to checkpoint and "
            "requeue, and would have little or no time left to train (it could requeue without "
            "end)."
        )
    return -(-seconds // 60)


OWN_OPTIONS = {
    "time": "--time",
    "partition": "--partition",
    "cpus_per_task": "--cpus-per-run",
    "gpus_per_node": "--gpus-per-run",
    "gpus": "--gpus-per-run",
    "requeue": "",
    "array": "",
    "job_name": "",
    "signal": "",
}
"""sbatch options the sweep sets itself (with the flag that sets each, where there is one):
the array holds the units, and requeueing after the SIGUSR2 checkpoint is how a unit longer
than --time continues."""


def parse_slurm_args(pairs: tuple[str, ...]) -> dict[str, str]:
    """``--slurm-arg KEY=VALUE`` pairs as sbatch options (``mem=8G`` is ``#SBATCH --mem=8G``);
    one that the sweep sets itself (:data:`OWN_OPTIONS`) or given twice is refused."""
    parsed: dict[str, str] = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        key = key.strip().lstrip("-").replace("-", "_")
        if not sep or not key or not value.strip():
            raise TacbenchError(
                f"--slurm-arg {pair!r}: give KEY=VALUE, an sbatch option without its dashes "
                "(e.g. --slurm-arg mem=8G --slurm-arg qos=normal)."
            )
        if key in OWN_OPTIONS:
            flag = OWN_OPTIONS[key]
            raise TacbenchError(
                f"--slurm-arg {pair!r}: the sweep sets --{key.replace('_', '-')} itself"
                + (f"; give {flag} instead." if flag else " (docs/sweep.md, 'Slurm').")
            )
        if key in parsed:
            raise TacbenchError(f"--slurm-arg {key.replace('_', '-')} is given twice.")
        parsed[key] = value
    return parsed


JOB_ID = re.compile(r"\d+(_\d+)?")  # submitit's job folders: a job's id, or an array task's


@dataclass
class _Submitted:
    unit: Unit
    job: Any  # submitit.Job
    missing_since: float | None = None  # when squeue first stopped listing it (monotonic)


class SlurmExecutor:
    """Units as Slurm array tasks; ``cpus`` and ``gpus`` per task, ``threads`` = ``cpus``."""

    def __init__(
        self,
        out: Path,
        *,
        workers: int | None,
        partition: str | None,
        time_limit: str,
        cpus: float,
        gpus: float,
        slurm_args: dict[str, str],
        command: str,
    ) -> None:
        try:
            import submitit
        except ImportError:
            raise TacbenchError(
                "--executor slurm needs submitit: pip install -c constraints.txt -e '.[slurm]'"
            ) from None
        if shutil.which("sbatch") is None or shutil.which("squeue") is None:
            raise TacbenchError(
                "--executor slurm needs Slurm's sbatch and squeue on this machine's PATH: run "
                "the sweep on a login node of the cluster (docs/sweep.md, 'Slurm')."
            )
        self.out, self.command = Path(out).resolve(), command
        self.workers, self.threads = workers, max(1, int(cpus))
        self.folder = self.out / "sweep" / "slurm"
        self._executor = submitit.SlurmExecutor(folder=self.folder / "%j")
        parameters: dict[str, Any] = {
            "job_name": JOB_NAME,
            "time": parse_time(time_limit),
            "cpus_per_task": self.threads,
            "signal_delay_s": SIGNAL_DELAY_S,
            "additional_parameters": {"requeue": True, **slurm_args},
        }
        if partition:
            parameters["partition"] = partition
        if gpus:
            parameters["gpus_per_node"] = int(gpus)
        self._executor.update_parameters(**parameters)
        self._pending: list[Unit] = []
        self._jobs: dict[str, _Submitted] = {}
        self._queued: dict[str, str] = {}  # what squeue listed when last asked: id -> reason
        self._told: dict[str, str] = {}  # the waiting jobs the user has heard of, and why
        self._notices: list[str] = []  # what the user has yet to hear
        self._asked = -math.inf  # when that was (monotonic)
        self._squeue_down_since: float | None = None  # squeue has failed since (monotonic)
        self._cancelled = False  # request_stop cancelled the jobs
        self._check_no_earlier_jobs()

    def _check_no_earlier_jobs(self) -> None:
        """Refuse to start while jobs an earlier driver submitted for this ``--out`` are still
        in Slurm's queue (a driver killed, or gone with its login session under nohup): their
        runs would be submitted again, and each new attempt fail against the running one's
        lock, counted as a failure."""
        earlier = [
            p.name
            for p in self.folder.glob("*")
            if JOB_ID.fullmatch(p.name) and not (p / f"{p.name}_0_result.pkl").exists()
        ]  # a job with a result has ended, though squeue may list it a moment (completing)
        still = sorted(set(earlier) & _queued(earlier).keys()) if earlier else []
        if still:
            raise TacbenchError(
                f"Slurm jobs of an earlier sweep of {self.out} are still queued or running "
                f"({listing(still)}); wait for them to end (squeue), or cancel them (scancel), "
                "then run the same command again."
            )

    def capacity(self) -> int:
        return self.workers or MAX_UNITS

    def running(self) -> int:
        return len(self._jobs) + len(self._pending)

    def submit(self, unit: Unit, node: str | None = None) -> None:
        self._pending.append(unit)  # submitted together, as one array, by the next wait()

    def _flush(self) -> None:
        if not self._pending:
            return
        jobs = [
            worker.Job(
                unit, self.out, state.log_path(self.out, unit.key), self.command, self.threads
            )
            for unit in self._pending
        ]
        try:
            with self._executor.batch():
                handles = [self._executor.submit(worker.slurm_main, job) for job in jobs]
        except Exception as err:  # submitit raises its own errors for sbatch's
            lines = str(err).strip().splitlines()
            raise TacbenchError(
                f"sbatch refused the sweep's jobs: {lines[-1] if lines else err}"
            ) from None
        for unit, handle in zip(self._pending, handles, strict=True):
            self._jobs[handle.job_id] = _Submitted(unit, handle)
        self._pending.clear()

    def wait(self, timeout: float) -> list[Finished]:
        submitted = bool(self._pending)
        self._flush()
        finished: list[Finished] = []
        now = time.monotonic()
        if self._jobs and (submitted or now - self._asked >= SQUEUE_EVERY_S):
            self._ask_squeue(now)
        for job_id, entry in list(self._jobs.items()):
            if entry.job.paths.result_pickle.exists():
                finished.append(self._collect(entry))
            elif job_id in self._queued or self._squeue_down_since is not None:
                entry.missing_since = None  # listed, or squeue cannot say
                continue
            else:
                entry.missing_since = entry.missing_since or now
                if now - entry.missing_since < GONE_AFTER_S and not self._cancelled:
                    continue
                finished.append(
                    Finished(
                        entry.unit,
                        None,
                        f"Slurm job {job_id} ended without a result ({_job_state(job_id)}; "
                        f"see {entry.job.paths.stderr})",
                    )
                )
            del self._jobs[job_id]
        if not finished and self._jobs:
            time.sleep(min(timeout, 5.0))
        return finished

    def _ask_squeue(self, now: float) -> None:
        """Refresh which jobs Slurm holds. A failing squeue (the controller restarting, a
        timeout) is asked again on the next polls, the jobs assumed queued meanwhile; after
        :data:`SQUEUE_DOWN_S` of failures the sweep stops with squeue's error."""
        self._asked = now
        try:
            self._queued = _queued(list(self._jobs))
        except TacbenchError:
            self._squeue_down_since = self._squeue_down_since or now
            if now - self._squeue_down_since >= SQUEUE_DOWN_S:
                raise
            return
        self._squeue_down_since = None
        self._tell_of_waiting_jobs()

    def _tell_of_waiting_jobs(self) -> None:
        """Queue a notice, once per job and reason (one per reason, naming its jobs), for the
        jobs that wait on their user: Slurm would hold them for ever, and the sweep with them."""
        news: dict[str, list[str]] = {}
        for job_id, reason in self._queued.items():
            if job_id not in self._jobs or self._told.get(job_id) == reason:
                continue
            if HELD.search(reason) or BEYOND_LIMITS.search(reason):
                self._told[job_id] = reason
                news.setdefault(reason, []).append(job_id)
            else:
                self._told.pop(job_id, None)
        for reason, ids in news.items():
            shown = listing(ids, sep=" ")
            if HELD.search(reason):
                advice = f"release {'them' if len(ids) > 1 else 'it'} (scontrol release "
                advice += (
                    f"{' '.join(ids[:5])}{' ...' if len(ids) > 5 else ''}) or cancel (scancel)"
                )
            else:
                advice = (
                    "stop the sweep (Ctrl-C) and run it again with a --time, --partition or "
                    "--slurm-arg that Slurm grants"
                )
            what = f"job {shown}" if len(ids) == 1 else f"{len(ids)} jobs ({shown})"
            self._notices.append(
                f"Slurm will not start {what} ({reason}): {advice}; the sweep waits for "
                f"{'them' if len(ids) > 1 else 'it'}"
            )

    def notices(self) -> list[str]:
        told, self._notices = self._notices, []
        return told

    def _collect(self, entry: _Submitted) -> Finished:
        try:
            result: worker.JobResult = entry.job.result()
        except Exception as err:  # the job's own exception, re-raised by submitit
            return Finished(entry.unit, None, f"Slurm job failed: {_last_error_line(str(err))}")
        return Finished(entry.unit, result)

    def steps(self) -> dict[str, int]:
        latest: dict[str, int] = {}
        for entry in self._jobs.values():
            status = self.out / entry.unit.runs[0].key / "status.json"
            if not status.exists():
                continue
            recorded = runs.read_json(status)
            if recorded.get("state") != "failed":  # failed: the retry's last attempt's
                latest[entry.unit.key] = int(recorded.get("step", 0))
        return latest

    def request_stop(self) -> None:
        """Cancel every job: Slurm sends SIGTERM, each trainer checkpoints (within KillWait)."""
        self._pending.clear()
        self._cancelled = True  # a job that leaves the queue now has ended, not vanished
        if self._jobs:
            subprocess.run(["scancel", *self._jobs], check=False, capture_output=True)

    def close(self, force: bool = False) -> None:
        if self._jobs or self._pending:
            self.request_stop()
        self._jobs.clear()


def _last_error_line(text: str) -> str:
    """The exception line of a job's failure as submitit words it: the last line of the trace
    it frames between two lines of dashes (the paths of the job's logs follow); else the
    message's last line."""
    lines = [line.strip() for line in text.strip().splitlines()]
    rules = [i for i, line in enumerate(lines) if line and set(line) == {"-"}]
    trace = [line for line in lines[rules[0] + 1 : rules[1]] if line] if len(rules) > 1 else []
    return (trace or lines or [text])[-1]


def _queued(job_ids: list[str]) -> dict[str, str]:
    """The ids (``<array>_<task>``) of these jobs that Slurm still holds (pending, running,
    completing or requeued), each with squeue's reason if it is pending, else ``""``."""
    arrays = sorted({job_id.split("_")[0] for job_id in job_ids})
    own = [f"--user={getpass.getuser()}", f"--name={JOB_NAME}"]  # not another user's job
    listing = subprocess.run(
        ["squeue", "--noheader", "--array", "--format=%i|%t|%r", *own, "--jobs", ",".join(arrays)],
        capture_output=True,
        text=True,
        check=False,
    )
    if listing.returncode != 0 and "Invalid job id" not in listing.stderr:
        raise TacbenchError(f"squeue failed: {listing.stderr.strip()}")
    queued: dict[str, str] = {}
    for line in listing.stdout.splitlines():
        job_id, _, rest = line.strip().partition("|")
        code, _, reason = rest.partition("|")
        if job_id:
            queued[job_id] = reason if code == "PD" else ""
    return queued


def _job_state(job_id: str) -> str:
    """Slurm's last word on a finished job (kept for MinJobAge), else "state unknown"."""
    shown = subprocess.run(
        ["scontrol", "show", "job", "--oneliner", job_id],
        capture_output=True,
        text=True,
        check=False,
    )
    fields = dict(f.split("=", 1) for f in shown.stdout.split() if "=" in f)
    if "JobState" not in fields:
        return "state unknown"
    reason = fields.get("Reason", "None")
    return fields["JobState"] + ("" if reason == "None" else f", {reason}")
