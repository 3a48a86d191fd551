"""Where units run: a local pool of worker processes, or Ray tasks on a local Ray or a cluster.

Both give the driver the same interface (:class:`Executor`): submit a unit, wait for units to
finish (:class:`Finished`: the worker's :class:`~tacbench.sweep.worker.JobResult`, or why the
worker died), the latest step of each running unit, and a stop request that makes every running
unit checkpoint and return.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import multiprocessing
import os
import signal
from dataclasses import dataclass
from multiprocessing.connection import wait as wait_for
from pathlib import Path
from typing import Any, Protocol

from tacbench.errors import TacbenchError
from tacbench.sweep import state, worker
from tacbench.sweep.plan import Unit

GRACE_S = 30.0  # how long a stopping worker may take to checkpoint before it is killed


@dataclass(frozen=True)
class Finished:
    """A unit that ended: the worker's result, or None and why the worker died (and, where
    known, the Ray node and host it died on)."""

    unit: Unit
    result: worker.JobResult | None
    died: str = ""
    node: str = ""
    host: str = ""


class Executor(Protocol):
    """What the driver needs from an executor."""

    def capacity(self) -> int:
        """How many units may run at once."""

    def submit(self, unit: Unit, node: str | None) -> None:
        """Start ``unit`` (``node``: a Ray node holding its checkpoint, if known)."""

    def running(self) -> int:
        """How many units are running."""

    def wait(self, timeout: float) -> list[Finished]:
        """Units that ended within ``timeout`` seconds."""

    def steps(self) -> dict[str, int]:
        """The latest step each running unit reported, by unit key."""

    def notices(self) -> list[str]:
        """What the user should hear since last asked: units that wait on something only the
        user can change (a Slurm job held, or asking more than its partition allows)."""

    def request_stop(self) -> None:
        """Ask every running unit to checkpoint and return."""

    def close(self, force: bool = False) -> None:
        """Stop what still runs (at once if ``force``, else after a grace period for its
        checkpoint) and release everything."""


@dataclass
class _Process:
    unit: Unit
    process: Any  # multiprocessing's SpawnProcess
    conn: Any  # the receiving end of its result pipe
    step: Any  # a shared int: the last step it reported
    result: worker.JobResult | None = None


class LocalExecutor:
    """One spawned process per unit, at most ``workers`` at once, each with ``threads`` torch
    threads. A process that dies takes only its own unit down."""

    def __init__(self, out: Path, workers: int, command: str, threads: int = 1) -> None:
        self.out, self.workers, self.command, self.threads = out, workers, command, threads
        self._ctx = multiprocessing.get_context("spawn")
        self._stop = self._ctx.Event()
        self._procs: dict[str, _Process] = {}

    def capacity(self) -> int:
        return self.workers

    def running(self) -> int:
        return len(self._procs)

    def submit(self, unit: Unit, node: str | None = None) -> None:
        log = state.log_path(self.out, unit.key)
        job = worker.Job(unit, self.out, log, self.command, self.threads)
        receive, send = self._ctx.Pipe(duplex=False)
        step = self._ctx.Value("q", 0, lock=False)  # until it reports: the plan's start step
        process = self._ctx.Process(
            target=worker.local_main,
            args=(job, send, step, self._stop, os.getpid()),
            name=f"tacbench-sweep {unit.key}",
            daemon=True,
        )
        process.start()
        send.close()
        self._procs[unit.key] = _Process(unit, process, receive, step)

    def wait(self, timeout: float) -> list[Finished]:
        handles = [h for p in self._procs.values() for h in (p.conn, p.process.sentinel)]
        ready = set(wait_for(handles, timeout)) if handles else set()
        finished = []
        for key, proc in list(self._procs.items()):
            if proc.result is None and (proc.conn in ready or proc.process.sentinel in ready):
                with contextlib.suppress(EOFError):  # died without a result: see its sentinel
                    if proc.conn.poll():
                        proc.result = proc.conn.recv()
            if proc.process.sentinel in ready:
                proc.process.join()
                proc.conn.close()
                del self._procs[key]
                died = "" if proc.result else _exit_reason(proc.process.exitcode)
                finished.append(Finished(proc.unit, proc.result, died))
        return finished

    def steps(self) -> dict[str, int]:
        return {key: int(p.step.value) for key, p in self._procs.items()}

    def notices(self) -> list[str]:
        return []  # a worker process starts at once

    def request_stop(self) -> None:
        self._stop.set()

    def close(self, force: bool = False) -> None:
        self._stop.set()
        for proc in self._procs.values():
            proc.process.join(0 if force else GRACE_S)
            if proc.process.is_alive():
                proc.process.kill()
                proc.process.join()
            proc.conn.close()
        self._procs.clear()


def _exit_reason(code: int | None) -> str:
    if code is not None and code < 0:
        name = signal.Signals(-code).name
        return f"worker process killed by {name}" + (
            " (out of memory? see dmesg)" if name == "SIGKILL" else ""
        )
    return f"worker process exited with status {code} without a result (see its log)"


class RayExecutor:
    """Each unit is a Ray task (``num_cpus``/``num_gpus`` each) on a local Ray (``address``
    None) or an existing cluster (``auto``, ``<host>:6379`` or ``ray://<host>:10001``).

    Without ``shared_fs`` a task writes into ``<scratch>/<digest of --out>`` on its node, keeps
    the checkpoints there and returns the runs' small files, which the driver writes into
    ``--out``; a partial run is sent back to the node holding its checkpoint when that node is
    still in the cluster (else it starts over). With ``shared_fs`` tasks write into ``--out``,
    which must be the same path on every node.
    """

    def __init__(
        self,
        out: Path,
        *,
        address: str | None,
        workers: int | None,
        cpus: float,
        gpus: float,
        scratch: Path | None,
        shared_fs: bool,
        command: str,
    ) -> None:
        try:
            import ray
        except ImportError:
            raise TacbenchError(
                "--executor ray needs Ray: pip install -c constraints.txt -e '.[ray]'"
            ) from None
        self.ray, self.out, self.command = ray, Path(out).resolve(), command
        self.workers, self.cpus, self.gpus, self.shared_fs = workers, cpus, gpus, shared_fs
        digest = hashlib.sha1(str(self.out).encode()).hexdigest()[:12]
        # without --scratch, a path relative to each node's own temporary folder (the driver's
        # may not exist there: a laptop's, through ray://), and ~ each node's own home:
        # worker.on_node resolves both there
        base = scratch or Path(worker.NODE_SCRATCH)
        self.root = self.out if shared_fs else base / digest
        try:
            ray.init(
                address=address,
                include_dashboard=False,
                log_to_driver=False,
                logging_level=logging.WARNING,
                num_cpus=workers if address is None else None,
                # a local Ray's tasks train at this machine's usual priority, as the local
                # executor's workers do: at Ray's default (15) any other busy process starves
                # them, and the dry run prices whole cores. A cluster keeps its own setting.
                _system_config={"worker_niceness": 0} if address is None else None,
            )
        except (ConnectionError, RuntimeError, ValueError) as err:
            raise TacbenchError(
                f"cannot reach the Ray cluster at {address}: {err}. Start it first "
                "(docs/sweep.md, 'A Ray cluster'), or leave out --address for a local Ray."
            ) from None
        try:
            self._board: Any = ray.remote(num_cpus=0)(_Board).remote()
            # a fresh worker process per task (max_calls=1): its threads, memory and output
            # redirection end with it
            self._task = ray.remote(num_cpus=cpus, num_gpus=gpus, max_retries=0, max_calls=1)(
                worker.ray_main
            )
        except BaseException:
            ray.shutdown()
            raise
        self._refs: dict[Any, Unit] = {}

    def capacity(self) -> int:
        if self.workers:
            return self.workers
        total = self.ray.cluster_resources()
        slots = int(total.get("CPU", 0) // self.cpus)
        if self.gpus:
            slots = min(slots, int(total.get("GPU", 0) // self.gpus))
        return max(1, slots)

    def running(self) -> int:
        return len(self._refs)

    def submit(self, unit: Unit, node: str | None = None) -> None:
        log = state.log_path(self.root, unit.key)
        threads = max(1, int(self.cpus))
        job = worker.Job(unit, self.root, log, self.command, threads, not self.shared_fs)
        task = self._task
        if node and not self.shared_fs:
            from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

            task = task.options(scheduling_strategy=NodeAffinitySchedulingStrategy(node, soft=True))
        # a retry that dies before it reports must not be placed where the last attempt ran
        self.ray.get(self._board.forget.remote(unit.key))
        self._refs[task.remote(job, self._board)] = unit

    def wait(self, timeout: float) -> list[Finished]:
        if not self._refs:
            return []
        done, _ = self.ray.wait(list(self._refs), num_returns=len(self._refs), timeout=timeout)
        finished = []
        for ref in done:
            unit = self._refs.pop(ref)
            try:
                result: worker.JobResult = self.ray.get(ref)
            except self.ray.exceptions.RayError as err:
                lines = str(err).strip().splitlines()
                node, host = self.ray.get(self._board.where.remote(unit.key))
                died = f"Ray task failed: {type(err).__name__}: {lines[-1]}"
                finished.append(Finished(unit, None, died, node, host))
                continue
            if not self.shared_fs:
                self._write_back(unit, result)
            finished.append(Finished(unit, result))
        return finished

    def _write_back(self, unit: Unit, result: worker.JobResult) -> None:
        """Write the returned files into ``--out``: CSVs first, status.json last, each by
        temporary name and rename (a reader never sees half a file)."""
        for key, files in result.files.items():
            directory = self.out / key
            directory.mkdir(parents=True, exist_ok=True)
            order = sorted(files, key=lambda name: (name == "status.json", name))
            for name in order:
                tmp = directory / (name + ".tmp")
                tmp.write_bytes(files[name])
                tmp.replace(directory / name)
        if result.log_tail:
            log = state.log_path(self.out, unit.key)
            log.parent.mkdir(parents=True, exist_ok=True)
            with log.open("a") as handle:
                handle.write(f"=== {result.host or 'ray'} node {result.node[:12]}\n")
                handle.write(result.log_tail)

    def steps(self) -> dict[str, int]:
        steps: dict[str, int] = self.ray.get(self._board.snapshot.remote())
        return steps

    def notices(self) -> list[str]:
        return []  # Ray warns itself of tasks that no node can take

    def request_stop(self) -> None:
        self.ray.get(self._board.request_stop.remote())

    def close(self, force: bool = False) -> None:
        try:
            if self._refs:  # an abnormal end: keep what the tasks return within the grace period
                self.request_stop()
                if not force:
                    self.wait(GRACE_S)
                for ref in self._refs:
                    self.ray.cancel(ref, force=True)
        finally:
            self.ray.shutdown()


class _Board:
    """A Ray actor: where each unit's latest attempt runs, the latest step of each running
    unit, and the stop flag tasks poll."""

    def __init__(self) -> None:
        self.latest: dict[str, int] = {}
        self.nodes: dict[str, tuple[str, str]] = {}  # unit key -> (Ray node id, host)
        self.stop = False

    def started(self, key: str, node: str, host: str) -> None:
        self.nodes[key] = (node, host)

    def forget(self, key: str) -> None:
        self.nodes.pop(key, None)

    def where(self, key: str) -> tuple[str, str]:
        """The node and host of the unit's latest attempt; empty if it never started."""
        return self.nodes.get(key, ("", ""))

    def report(self, key: str, step: int) -> bool:
        self.latest[key] = step
        return self.stop

    def snapshot(self) -> dict[str, int]:
        return dict(self.latest)

    def request_stop(self) -> None:
        self.stop = True
