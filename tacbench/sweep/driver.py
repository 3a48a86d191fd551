"""The sweep driver: plan, hand units to an executor, record failures, retry, summarize.

Idempotent: every decision is made from the run directories under ``--out`` and the failure
history in ``<out>/sweep/state.json``, so running the same command again continues whatever
was left (complete runs are skipped, partial ones resume from their checkpoints, failed ones
are retried until they have failed ``max_retries + 1`` times).

Ctrl-C or SIGTERM: the first asks every running unit to checkpoint and return (and starts no
new one), then the summary is written; a second one stops the workers at once (they keep their
last checkpoints). A unit that finds the disk full stops the sweep the same way (its runs are
not counted as failed) and the sweep ends with a clear error; any other error of a unit is
recorded against its runs, which are retried.
"""

from __future__ import annotations

import functools
import os
import time
from collections import deque
from collections.abc import Collection, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from tacbench import envs, hardware, runs
from tacbench.errors import TacbenchError
from tacbench.interrupts import exit_status, stop_signals
from tacbench.runs.checkpoints import DiskError, disk_errors
from tacbench.sweep import cost, dry_run, executors, plan, preflight, slurm, state, summary, worker
from tacbench.sweep.options import Options
from tacbench.sweep.presets import Preset
from tacbench.sweep.progress import SweepProgress


@dataclass(frozen=True)
class SweepResult:
    """How a sweep ended: the summary (also written to ``<out>/sweep/``) and its text."""

    summary: dict[str, Any]
    text: str
    interrupted: bool
    warnings: tuple[str, ...] = ()  # the plan's warnings of its runs' settings (plan.RunWarning)
    kept: bool = False  # an earlier sweep's summary kept (this one trained nothing), not written

    @property
    def exit_code(self) -> int:
        """128 + the stop signal's number when interrupted (130 for Ctrl-C,
        :func:`tacbench.interrupts.exit_status`), 1 a run failed for good, else 0."""
        if self.interrupted:
            return exit_status()
        counts = self.summary["counts"]
        return 1 if counts["given_up"] or counts["failed"] or counts["cannot_resume"] else 0


def load_plan(
    preset: Preset,
    out: Path,
    options: Options,
    *,
    save: bool = True,
) -> tuple[plan.SweepPlan, state.SweepState]:
    """The plan from the run directories and failure history under ``out``. A failure found in
    a status.json but not in the history (a run that failed outside a sweep) is added to the
    history, which is saved if ``save`` (not for a dry run)."""
    device = "cuda" if options.gpus_per_run else "cpu"
    threads = max(1, int(options.cpus_per_run)) if options.executor != "local" else 1
    warnings: list[str] = []
    all_runs = plan.build_runs(preset, device=device, threads=threads, warnings=warnings)
    history = state.SweepState(out)
    statuses = {run.key: plan.read_status(out, run) for run in all_runs}
    # Ray without a shared filesystem keeps the checkpoints on its nodes, not under --out
    checkpoints_here = options.executor != "ray" or options.shared_fs
    for key, status in statuses.items():
        if status.state == "partial" and checkpoints_here:  # else every attempt would fail
            runs.check_checkpoint(out / key, status.step)
        elif status.state == "failed":
            history.note_failed_status(key, status.step, status.reason)
    if save:
        history.save()
    built = plan.make_plan(
        preset,
        out,
        all_runs,
        statuses,
        history.failure_counts(),
        max_retries=options.max_retries,
        group=options.group,
        unit_size=unit_size(options),
        # members resume together only where their checkpoints are: on one node
        nodes={} if checkpoints_here else {k: n for k in statuses if (n := history.node(k))},
    )
    built.warnings = warnings
    return built, history


def unit_size(options: Options) -> plan.UnitSize:
    """How many runs of a group one unit trains (:func:`cost.members_per_unit`): at most
    ``--members``, what fits this machine's memory with every worker busy, and few enough that
    every worker gets a unit."""
    bytes_per_member = functools.cache(_member_bytes)

    def size(group: Sequence[plan.Run], n_groups: int) -> int:
        config = group[0].config
        transitions = min(getattr(config, "buffer_size", config.total_steps), config.total_steps)
        return cost.members_per_unit(
            len(group),
            bytes_per_member(config.env, transitions),
            workers=options.worker_count(),
            groups=n_groups,
            memory=hardware.memory_bytes(),
            limit=options.members,
        )

    return size


def _member_bytes(env: str, transitions: int) -> int:
    info = envs.env_info(env)
    return cost.member_bytes(info.obs_dim, info.act_dim, transitions)


def run_sweep(
    preset: Preset,
    out: Path,
    options: Options,
    stream: IO[str] | None = None,
    *,
    told: Collection[str] = (),
) -> SweepResult:
    """Train every run of ``preset`` into ``out`` that is not complete; see the module doc.
    A full disk stops the sweep (every unit checkpoints and returns) with a DiskError. The
    plan's warnings are printed but for those in ``told`` (printed already by the command:
    ``--until-decided``'s earlier interims)."""
    runs.check_results_folder(out)
    runs.ensure_writable(out)
    if options.shares_local_gpu:
        _require_cuda()
    again = "rerun the same command: every run resumes from its last checkpoint"
    with disk_errors("the sweep's files", again), state.Lock(out):
        state.prepare_sweep_folder(out)
        work, history = load_plan(preset, out, options)
        preflight.check_sizes(work, options)
        preflight.check_not_written(work)
        workers = options.worker_count()
        priced = dry_run.price(work, workers, training=True)
        started = time.monotonic()
        executor = _executor(out, options)
        driver = _Driver(work, history, executor, options, stream, told)
        with stop_signals(second_interrupts=False) as received:
            interrupted = driver.run(received)
        bill = {
            "cpu_class": hardware.cpu_class(),
            "executor": options.executor,
            "workers": workers,
            "wall_s": round(time.monotonic() - started, 1),
            "priced_wall_s": round(priced.wall_seconds, 1),
            "priced_core_hours": round(priced.core_seconds / 3600, 3),
        }
        load = driver.load.mean() if driver.load is not None else None
        if load is not None:  # the machine's, the sweep's own workers included
            bill.update(load_average=round(load, 2), cores=os.cpu_count())
        if driver.disk_full:
            raise DiskError(
                f"the sweep stopped: {driver.disk_full} could not write its files because the "
                f"disk under {out} is full; free some space, then rerun the same command (every "
                "run resumes from its last checkpoint).",
                full=True,
            )
        final, history = load_plan(preset, out, options)
        result = summary.summarize(
            final,
            history,
            refused=driver.refused,
            command=options.command,
            interrupted=interrupted,
            bill=bill,
        )
        text = summary.summary_text(result, options.command)
        kept = _billed_summary(out, result) if not summary.counts(work)["to_train"] else None
        if kept is None:
            summary.write_summary(out, result, text)
        else:
            text += f"\nkept {kept}: this sweep trained nothing; its bill is what the runs took"
        return SweepResult(result, text, interrupted, tuple(work.warnings), kept is not None)


def _billed_summary(out: Path, result: dict[str, Any]) -> Path | None:
    """The summary.json of an earlier sweep of the same command that trained and left the runs
    as ``result`` finds them: a sweep that trains nothing keeps it, so that its bill (what the
    runs took, the price they had) is not replaced by a bill of nothing."""
    path = state.sweep_dir(out) / "summary.json"
    try:
        earlier = runs.read_json(path)
    except TacbenchError:  # none yet, or damaged: this sweep's summary replaces it
        return None
    counts = earlier.get("counts")
    zeros = dict.fromkeys(result["counts"], 0)  # a count added since that summary is 0 there
    if not isinstance(counts, dict) or {**zeros, **counts} != result["counts"]:
        return None
    if earlier.get("command") != result.get("command"):  # its bill is of other runs
        return None
    bill = earlier.get("bill")
    priced = bill.get("priced_wall_s") if isinstance(bill, dict) else None
    return path if isinstance(priced, (int, float)) and priced > 0 else None


def _require_cuda() -> None:
    import torch

    if not torch.cuda.is_available():
        raise TacbenchError(
            "--gpus-per-run trains on a CUDA GPU, and torch sees none here "
            f"(torch {torch.__version__}): install a CUDA build of torch on a machine with an "
            "NVIDIA GPU, or leave --gpus-per-run out to train on the CPU."
        )


def _executor(out: Path, options: Options) -> executors.Executor:
    if options.executor == "slurm":
        return slurm.SlurmExecutor(
            out,
            workers=options.workers,
            partition=options.partition,
            time_limit=options.time_limit or slurm.DEFAULT_TIME,
            cpus=options.cpus_per_run,
            gpus=options.gpus_per_run,
            slurm_args=slurm.parse_slurm_args(options.slurm_args),
            command=options.command,
        )
    if options.executor == "ray":
        return executors.RayExecutor(
            out,
            address=options.address,
            workers=options.workers,
            cpus=options.cpus_per_run,
            gpus=options.gpus_per_run,
            scratch=options.scratch,
            shared_fs=options.shared_fs,
            command=options.command,
        )
    return executors.LocalExecutor(out, options.worker_count(), options.command)


class _Driver:
    """The loop: keep the executor busy, handle each unit that ends, show progress."""

    def __init__(
        self,
        work: plan.SweepPlan,
        history: state.SweepState,
        executor: executors.Executor,
        options: Options,
        stream: IO[str] | None,
        told: Collection[str] = (),
    ) -> None:
        self.plan, self.history, self.executor, self.options = work, history, executor, options
        self.queue = deque(work.units)
        self.step = {p.run.key: p.start_step for p in work.runs}
        self.ended = {p.run.key for p in work.runs if p.action in ("skip", "give-up")}
        budgets = {p.run.key: (p.run.total_steps, p.run.config.learning_steps) for p in work.runs}
        self.progress = SweepProgress(budgets, self.step, self.ended, stream)
        for warning in work.warnings:
            if warning not in told:
                self.progress.message(warning)
        self.stopping = self.forced = False
        self.disk_full = ""  # the unit that found the disk full: the sweep stops
        # runs refused before training (their files cannot resume): not retried in this sweep
        self.refused: set[str] = set()
        # what else this machine ran meanwhile, for the bill (a local sweep's units run here)
        self.load = hardware.LoadMeter() if options.executor == "local" else None
        self.unit_runs: dict[str, list[str]] = {}  # the runs of each submitted unit, by its key

    def run(self, received: dict[str, int]) -> bool:
        """Train until the queue is empty or a stop is requested; True if stopped early."""
        try:
            while (self.queue and not self.stopping) or self.executor.running():
                self._stop_if(received)
                if self.load is not None:
                    self.load.sample()
                if received.get("count", 0) > 1:
                    self.forced = True
                    break
                while self.queue and not self.stopping:
                    if self.executor.running() >= self.executor.capacity():
                        break
                    unit = self.queue.popleft()
                    self.unit_runs[unit.key] = [r.key for r in unit.runs]
                    self.executor.submit(unit, self.history.node(unit.runs[0].key))
                for finished in self.executor.wait(timeout=1.0):
                    # a Ctrl-C reaches the workers too: one that died of it while starting up
                    # (before it ignores it) is stopped, not failed
                    self._stop_if(received)
                    self._handle(finished)
                for notice in self.executor.notices():
                    self.progress.message(notice)
                for key, step in self.executor.steps().items():
                    for run_key in self.unit_runs.get(key, ()):
                        self.step[run_key] = max(self.step[run_key], step)
                self.progress.update(self.step, self.ended)
        finally:
            self.executor.close(force=self.forced)
            self.progress.close()
        return self.stopping or bool(self.queue)

    def _stop_if(self, received: dict[str, int]) -> None:
        """Begin stopping once a stop signal has been received."""
        if received and not self.stopping:
            self.stopping = True
            self.progress.message("stopping: every running run checkpoints and returns")
            self.executor.request_stop()

    def _handle(self, finished: executors.Finished) -> None:
        """Read each run's status after its unit ended; record failures, queue retries."""
        result, out = finished.result, self.plan.out
        node = result.node if result is not None else finished.node
        if node:  # a retry goes back to the node holding the checkpoints
            self.history.set_node([r.key for r in finished.unit.runs], node)
        error = finished.died or (result.error if result else "")
        if result is not None and result.disk_full:  # not the run's fault: stop, keep no failure
            self.disk_full = self.disk_full or finished.unit.key
            if not self.stopping:
                self.stopping = True
                self.progress.message(f"the disk is full ({error}); stopping every run")
                self.executor.request_stop()
            return
        again: list[plan.Run] = []
        retry: list[plan.Run] = []
        for run in finished.unit.runs:
            status = plan.read_status(out, run)
            self.step[run.key] = status.step if status.state != "complete" else run.total_steps
            if status.state == "complete":
                self.ended.add(run.key)
                self.progress.message(f"complete: {run.key}")
                continue
            # a retried run's status.json still holds the failure recorded already when its
            # worker died before resetting it: that attempt's error is the worker's death
            stale = bool(finished.died) and self._recorded(run.key, status)
            failed_now = status.state == "failed" and not stale
            reason = status.reason if failed_now else _error_of(run, error, result)
            if not reason and result is not None and not self.stopping:
                # its worker returned it unfinished though the sweep did not stop it: a signal
                # from elsewhere (its trainer checkpoints and returns), so it is retried
                reason = f"its worker ended at step {status.step:,}; the sweep did not stop it"
            if not failed_now and (not reason or self.stopping):
                continue  # interrupted (or never started): resumes with the next sweep
            # checked before anything was written: every attempt would be refused alike
            refused = result is not None and run.key in result.run_errors
            host = self._host(finished)
            self.history.add_failure(run.key, status.step, reason, host, refused=refused)
            n = self.history.attempts_failed(run.key)
            if refused:
                self.ended.add(run.key)
                self.refused.add(run.key)
                self.progress.message(f"cannot resume, not retried: {run.key}: {reason}")
            elif n > self.options.max_retries:
                self.ended.add(run.key)
                self.progress.message(f"failed ({n} attempts, giving up): {run.key}: {reason}")
            elif not self.stopping:
                self.progress.message(f"failed (attempt {n}, retrying): {run.key}: {reason}")
                (retry if status.state == "failed" else again).append(run)
        if again:
            self.queue.append(plan.Unit(tuple(again)))
        self.queue.extend(plan.Unit((run,), retry=(run.key,)) for run in retry)

    def _recorded(self, key: str, status: plan.Status) -> bool:
        """Whether the history holds ``status``'s failure (its step and reason) already."""
        return any(
            (f.step, f.reason) == (status.step, status.reason) for f in self.history.failures(key)
        )

    def _host(self, finished: executors.Finished) -> str:
        """Where the attempt ran: its worker's host, this machine's for a local worker that died
        (empty: the history records this host), else where the cluster said it started, or
        unknown."""
        if finished.result is not None:
            return finished.result.host
        if self.options.executor == "local":
            return ""
        return finished.host or "unknown"


def _error_of(run: plan.Run, error: str, result: worker.JobResult | None) -> str:
    """The error that ended ``run``'s attempt: its own, if the unit left it out (it could not
    continue: the others trained on), else the unit's."""
    return result.run_errors.get(run.key, error) if result is not None else error
