"""What a sweep checks before it trains anything, where every attempt would fail alike: a unit
too big for this machine, and runs another process is writing."""

from __future__ import annotations

import functools

from tacbench import envs, trainers
from tacbench.errors import TacbenchError, listing, plural
from tacbench.runs import locks
from tacbench.sweep import plan
from tacbench.sweep.options import Options


def check_sizes(work: plan.SweepPlan, options: Options) -> None:
    """Refuse, before anything runs, a unit its trainer would refuse as too big for this
    machine (every attempt would fail the same way); for the local executor, whose workers
    run here (a cluster's nodes are checked where they train)."""
    if options.executor == "local":
        info_of = functools.cache(envs.env_info)  # builds the task's env: once per task
        for unit in work.units:
            try:
                configs = [run.config for run in unit.runs]
                trainers.check_sizes(configs, info_of(configs[0].env))
            except TacbenchError as err:
                runs_in = plural(len(unit.runs), "run")
                raise TacbenchError(f"the unit {unit.key} ({runs_in}): {err}") from None


def check_not_written(work: plan.SweepPlan) -> None:
    """Refuse, before anything runs, runs to train whose directories another process writes
    (a ``tacbench run`` into ``--out``): each attempt would fail against its lock, and the sweep
    gave the runs up after ``--max-retries`` such failures."""
    held = {}
    for planned in work.runs:
        if planned.action in ("train", "retry"):
            recorded = locks.holder(work.out / planned.run.key)
            if recorded is not None:
                held[planned.run.key] = recorded
    if held:
        first, by = next(iter(held.items()))
        raise TacbenchError(
            f"{plural(len(held), 'run')} of this sweep {'is' if len(held) == 1 else 'are'} "
            f"being written by another tacbench process ({listing(list(held), 3)}; {first}: "
            f"{by}); nothing was changed. Wait for it to finish or stop it, then run the sweep "
            "again."
        )
