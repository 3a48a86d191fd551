"""What a sweep is asked to run on (``tacbench sweep``'s executor, worker and resource flags),
checked as a whole before anything is planned, and how many workers its estimate assumes."""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

from tacbench.errors import TacbenchError
from tacbench.sweep import EXECUTORS, GROUPS, slurm


@dataclass(frozen=True)
class Options:
    """How to run a sweep (the ``tacbench sweep`` flags other than the preset narrowing)."""

    executor: str = "local"
    workers: int | None = None  # local: the core count; Ray: what the cluster has room for
    address: str | None = None
    cpus_per_run: float = 1.0
    gpus_per_run: float = 0.0
    scratch: Path | None = None
    shared_fs: bool = False
    group: str = "task"  # TAC runs of one task differing in q, alpha, seed share a unit
    members: int | None = None  # at most this many per unit; None: what memory and workers allow
    max_retries: int = 2
    command: str = ""
    partition: str | None = None  # Slurm
    time_limit: str | None = None  # Slurm, per job (None: slurm.DEFAULT_TIME); longer: requeued
    slurm_args: tuple[str, ...] = ()  # Slurm: KEY=VALUE sbatch options

    def __post_init__(self) -> None:
        if self.executor not in EXECUTORS:
            raise TacbenchError(
                f"--executor must be one of {', '.join(EXECUTORS)} (got {self.executor!r})."
            )
        if self.workers is not None and self.workers < 1:
            raise TacbenchError(f"--workers must be at least 1 (got {self.workers}).")
        if self.group not in GROUPS:
            raise TacbenchError(f"--group must be one of {', '.join(GROUPS)}.")
        if self.members is not None and self.members < 1:
            raise TacbenchError(f"--members must be at least 1 (got {self.members}).")
        if self.members is not None and self.members > 1 and self.group == "none":
            raise TacbenchError(
                f"--members {self.members} groups runs into units, which --group none does "
                "not: one run per unit. Give --group task or seeds, or leave --members out."
            )
        if self.max_retries < 0:
            raise TacbenchError(f"--max-retries must be 0 or more (got {self.max_retries}).")
        resources = (self.cpus_per_run, self.gpus_per_run)
        if (
            not all(map(math.isfinite, resources))
            or self.cpus_per_run <= 0
            or self.gpus_per_run < 0
        ):
            raise TacbenchError("--cpus-per-run must be > 0 and --gpus-per-run >= 0 (numbers).")
        if self.executor == "slurm" and any(value != int(value) for value in resources):
            raise TacbenchError(
                "Slurm allocates whole CPUs and GPUs: give --cpus-per-run and --gpus-per-run as "
                "whole numbers (a fractional share of a GPU is a Ray request: --executor ray)."
            )
        if self.executor == "local" and (self.address or self.scratch or self.shared_fs):
            raise TacbenchError(
                "--address, --scratch and --shared-fs are Ray options: add --executor ray."
            )
        if self.executor == "local" and self.cpus_per_run != 1.0:
            raise TacbenchError(
                "--cpus-per-run is a Ray or Slurm request: add --executor ray or slurm (the "
                "local executor runs one thread per worker)."
            )
        if self.shares_local_gpu:
            self._check_local_gpu_share()
        if self.partition is not None and not self.partition.strip():
            raise TacbenchError(
                "--partition needs a partition's name (leave it out for the default)."
            )
        slurm_only = self.partition or self.slurm_args or self.time_limit is not None
        if self.executor != "slurm" and slurm_only:
            raise TacbenchError(
                "--partition, --time and --slurm-arg are Slurm options: add --executor slurm."
            )
        scratch = str(self.scratch) if self.scratch is not None else "/"
        if not (scratch.startswith("/") or scratch.startswith("~")):
            raise TacbenchError(
                f"--scratch {scratch}: give an absolute path (or one from ~): each Ray node "
                "finds it on its own, where a relative one would mean nothing."
            )
        if self.executor == "slurm":
            if self.address or self.scratch or self.shared_fs:
                raise TacbenchError(
                    "--address, --scratch and --shared-fs are Ray options; Slurm jobs write "
                    "into --out, which must be on a file system every node shares."
                )
            slurm.parse_time(self.time_limit or slurm.DEFAULT_TIME)
            slurm.parse_slurm_args(self.slurm_args)

    def _check_local_gpu_share(self) -> None:
        if self.gpus_per_run > 1:
            raise TacbenchError(
                f"--gpus-per-run {self.gpus_per_run:g}: the local executor shares one GPU "
                "between its workers, so give a fraction of it (0.2: five workers on the GPU), "
                "or use --executor ray or slurm for several GPUs per run."
            )
        if self.workers and self.workers > self.gpu_workers():
            raise TacbenchError(
                f"--workers {self.workers} with --gpus-per-run {self.gpus_per_run:g} needs "
                f"{self.workers * self.gpus_per_run:g} GPUs; the local executor shares one: "
                f"give --workers {self.gpu_workers()} or less, or a smaller --gpus-per-run."
            )

    @property
    def shares_local_gpu(self) -> bool:
        """The local executor's workers train on the machine's GPU (--gpus-per-run > 0)."""
        return self.executor == "local" and self.gpus_per_run > 0

    def gpu_workers(self) -> int:
        """Local executor with --gpus-per-run G: how many workers share its one GPU, 1/G."""
        return max(1, int(1 / self.gpus_per_run + 1e-9))

    def worker_count(self) -> int:
        """Workers for the plan's estimate: --workers, else this machine's cores (local with
        --gpus-per-run G: at most 1/G, the workers that share the GPU)."""
        if self.workers:
            return self.workers
        cores = usable_cores()
        if self.shares_local_gpu:
            return min(cores, self.gpu_workers())
        return cores

    def oversubscribed(self) -> str:
        """A warning when local workers outnumber this machine's cores (each gets one thread,
        so they only share the cores and the estimate's per-core rates no longer hold)."""
        cores = usable_cores()
        if self.executor != "local" or not self.workers or self.workers <= cores:
            return ""
        return (
            f"WARNING: --workers {self.workers} is more than the {cores} cores this process may "
            "use: the workers share them, each runs slower, and the dry run's price is too low"
        )

    def workers_source(self) -> str:
        """Where :meth:`worker_count` comes from, for the dry run's estimate."""
        if self.workers:
            return "--workers"
        if self.executor == "local":
            return "this machine's cores"
        return (
            f"this machine's cores, not the cluster's: give --workers N for a {self.executor} "
            "estimate"
        )


def usable_cores() -> int:
    """The cores this process may use (its affinity, on Linux), else the machine's."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1
