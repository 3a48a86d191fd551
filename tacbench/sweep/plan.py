"""From a preset to the work of one sweep: every run's config, its state on disk, what to do with
it, and the units (one process or Ray task each) that do it.

A run's state comes from its directory under ``--out`` (docs/results-schema.md):
no ``config.json``: *new*; ``status.json`` ``complete``: *complete*; ``failed``: *failed*;
otherwise *partial* (``running``: interrupted or crashed, resumable from its checkpoint). A
directory holding another config, or files but no ``config.json``, stops the sweep before
anything runs.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from tacbench import runs, trainers
from tacbench.config import RESULT_NEUTRAL_FIELDS, RunConfig
from tacbench.errors import TacbenchError
from tacbench.runs import checkpoints
from tacbench.settings import RunWarning
from tacbench.sweep.presets import Preset

if TYPE_CHECKING:
    from tacbench.trainers import AnyConfig

State = Literal["new", "partial", "complete", "failed"]
Action = Literal["skip", "train", "retry", "give-up"]


@dataclass(frozen=True)
class Run:
    """One run of the sweep: its config and where its directory is, relative to ``--out``."""

    config: AnyConfig
    label: str = ""

    @property
    def key(self) -> str:
        """``runs/<algo>/<env>/<variant>/seed<k>``: the run directory under ``--out``."""
        c = self.config
        return runs.run_directory(Path(), c.algo, c.env, c.variant, c.seed).as_posix()

    @property
    def total_steps(self) -> int:
        """The run's budget in environment steps."""
        return self.config.total_steps


@dataclass(frozen=True)
class Status:
    """A run's state on disk, the step it reached (its last checkpoint, unless complete or
    failed) and the trainer's reason (failed runs); a failed run's retry resumes at
    ``resumes_at``, its last checkpoint under ``--out`` (0 without one: a retry starts afresh,
    and a Ray node's checkpoint is not seen from here)."""

    state: State
    step: int = 0
    reason: str = ""
    resumes_at: int = field(default=0, compare=False)


@dataclass(frozen=True)
class PlannedRun:
    """A run, its state, its failed attempts so far and what this sweep does with it."""

    run: Run
    status: Status
    failures: int
    action: Action

    @property
    def start_step(self) -> int:
        """Where this sweep's training of it starts: where a retry resumes, else the step it
        reached."""
        return self.status.resumes_at if self.action == "retry" else self.status.step

    @property
    def steps_left(self) -> int:
        """The steps this sweep trains of it, if it trains it."""
        return self.run.total_steps - self.start_step


@dataclass(frozen=True)
class Unit:
    """The work of one process (local) or task (Ray): one run, or TAC members (``--group``: runs
    equal but for the seed, or for q, alpha and the seed, resuming from the same step).
    ``retry`` lists the keys of failed runs to reset to "running" before training, so they
    continue from their checkpoint; ``fresh`` those with nothing under ``--out``, whose copy in
    a Ray node's scratch folder (a run since deleted from ``--out``) must not be continued."""

    runs: tuple[Run, ...]
    retry: tuple[str, ...] = ()
    fresh: tuple[str, ...] = ()

    @property
    def key(self) -> str:
        """The run's key; for members of one variant ``<variant dir>/seeds<a>,<b>,...``, for
        members of several ``runs/<algo>/<env>/members<n>-<digest of their keys>``."""
        if len(self.runs) == 1:
            return self.runs[0].key
        parents = {r.key.rsplit("/", 1)[0] for r in self.runs}
        if len(parents) == 1:
            seeds = ",".join(str(r.config.seed) for r in self.runs)
            return f"{parents.pop()}/seeds{seeds}"
        digest = hashlib.sha1("\n".join(r.key for r in self.runs).encode()).hexdigest()[:8]
        c = self.runs[0].config
        return f"runs/{c.algo}/{c.env}/members{len(self.runs)}-{digest}"

    @property
    def algo(self) -> str:
        """The algorithm of every run in the unit."""
        return self.runs[0].config.algo


@dataclass
class SweepPlan:
    """Every run of the sweep with its state and action, and the units to train."""

    preset: Preset
    out: Path
    runs: list[PlannedRun]
    units: list[Unit] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)  # the runs' own (build_runs)

    def count(self, **where: Any) -> int:
        """How many runs have the given ``state`` and/or ``action``."""
        return sum(
            all(getattr(p.status if k == "state" else p, k) == v for k, v in where.items())
            for p in self.runs
        )

    def steps_left(self) -> int:
        """Environment steps still to train (runs given up on count nothing)."""
        return sum(p.steps_left for p in self.runs if p.action in ("train", "retry"))


def build_runs(
    preset: Preset, *, device: str = "cpu", threads: int = 1, warnings: list[str] | None = None
) -> list[Run]:
    """Every run of ``preset`` (narrowed already), in preset order, each directory once; the
    warnings ``tacbench run`` would print of the runs' own settings (:class:`RunWarning`: random
    steps filling the budget, so that the networks are never updated; a PPO or TRPO rollout
    longer than it; a ``--pbt-every`` that leaves no population round) are added to
    ``warnings``, each once, named by algorithm and task. (Not the compile note: it describes
    this machine, not where a unit trains.)"""
    built: dict[str, Run] = {}
    for entry in preset.entries:
        settings = {**entry.settings, "device": device, "threads": threads}
        for task in entry.tasks:
            env_id = entry.env_id(task)
            configs, notes = trainers.make_configs(
                entry.algo,
                env_id,
                task,
                entry.seeds,
                settings,
                qs=entry.q_values(task),
                hp=entry.hp,
            )
            for note in notes:
                named = f"WARNING: {entry.algo} {env_id}: {note.removeprefix('WARNING: ')}"
                if isinstance(note, RunWarning) and warnings is not None and named not in warnings:
                    warnings.append(named)
            for config in configs:
                run = Run(config, entry.label)
                built.setdefault(run.key, run)
    return list(built.values())


def read_status(out: Path, run: Run) -> Status:
    """The state of ``run``'s directory under ``out``; TacbenchError if it holds another config."""
    directory = out / run.key
    config_path = directory / "config.json"
    if not config_path.exists():
        runs.check_nothing_to_lose(directory)  # else its worker would refuse it, mid-sweep
        return Status("new")
    stored = runs.read_json(config_path).get("config")
    if not isinstance(stored, dict):
        raise TacbenchError(
            f"{config_path} holds no run config; restore it, or delete {directory} to retrain it "
            "with this sweep's config."
        )
    stored = runs.as_read_now(stored, run.config)
    status = runs.read_status(directory)  # a damaged one stops the sweep before anything runs
    planned = dict(run.config.to_dict())
    if planned.get("compile") == "auto":  # resolved where the run started; a resume keeps it
        planned["compile"] = stored.get("compile", "auto")
    differences = runs.differing_fields(stored, planned, RESULT_NEUTRAL_FIELDS)
    if differences:
        raise TacbenchError(
            f"{directory} holds a run with another config ({'; '.join(differences)}). "
            "Use another --out, or delete that directory to retrain it with this sweep's config."
        )
    state, step = status["state"], status["step"]  # read_status checked both
    if state == "failed":
        resumes_at = checkpoints.newest_step(directory / "checkpoint") or 0
        return Status(state, step, str(status.get("reason", "")), resumes_at)
    if state == "complete":
        return Status(state, step, str(status.get("reason", "")))
    return Status("partial", step)


UnitSize = Callable[[Sequence["Run"], int], int]  # a group's runs, how many groups -> unit size
# what the members of a "task" and a "seeds" unit may differ in (runs equal in everything else)
_MEMBER_FIELDS = {"task": ("q", "alpha", "seed"), "seeds": ("seed",)}


def make_plan(
    preset: Preset,
    out: Path,
    runs_: Sequence[Run],
    statuses: Mapping[str, Status],
    failures: Mapping[str, int],
    *,
    max_retries: int,
    group: str,
    unit_size: UnitSize,
    nodes: Mapping[str, str] | None = None,
) -> SweepPlan:
    """Each run's action and the units to train, from its status (:func:`read_status`) and its
    number of recorded failures: a run that failed more than ``max_retries`` times is given up
    on, a failed run with fewer failures is retried, complete runs are skipped. ``nodes``: the
    Ray node holding each run's checkpoints, where they stay on the nodes."""
    planned = []
    for run in runs_:
        status, n_failed = statuses[run.key], failures.get(run.key, 0)
        action: Action
        if status.state == "complete":
            action = "skip"
        elif n_failed > max_retries:
            action = "give-up"
        else:
            action = "retry" if status.state == "failed" else "train"
        planned.append(PlannedRun(run, status, n_failed, action))
    return SweepPlan(preset, out, planned, make_units(planned, group, unit_size, nodes))


def make_units(
    planned: Sequence[PlannedRun],
    group: str,
    unit_size: UnitSize,
    nodes: Mapping[str, str] | None = None,
) -> list[Unit]:
    """One unit per run to train, or (``group`` "seeds" or "task") TAC runs equal but for the
    seed, or for q, alpha and the seed, at the same resume step and on the same node (``nodes``,
    by run key: where its checkpoints are), as members of units of at most ``unit_size(runs of
    the group, number of groups)`` runs (a larger group is split into units of near-equal size).
    Failed runs are retried alone."""
    nodes = nodes or {}
    new = {p.run.key for p in planned if p.status.state == "new"}

    def unit(runs: Sequence[Run]) -> Unit:
        return Unit(tuple(runs), fresh=tuple(r.key for r in runs if r.key in new))

    units: list[Unit | tuple[str, int, str]] = []  # a tuple marks where a group goes
    groups: dict[tuple[str, int, str], list[Run]] = {}
    for p in planned:
        config = p.run.config
        if p.action == "retry":
            units.append(Unit((p.run,), retry=(p.run.key,)))
        elif p.action != "train":
            continue
        elif group in _MEMBER_FIELDS and isinstance(config, RunConfig):
            ignored = _MEMBER_FIELDS[group]
            shared = {k: v for k, v in config.to_dict().items() if k not in ignored}
            where = nodes.get(p.run.key, "") if p.status.step else ""
            key = (json.dumps(shared, sort_keys=True), p.status.step, where)
            if key not in groups:
                groups[key] = []
                units.append(key)
            groups[key].append(p.run)
        else:
            units.append(unit([p.run]))
    made: list[Unit] = []
    for u in units:
        if isinstance(u, Unit):
            made.append(u)
            continue
        grouped = groups[u]
        n_units = math.ceil(len(grouped) / unit_size(grouped, len(groups)))
        base, extra = divmod(len(grouped), n_units)  # sizes differ by at most one
        start = 0
        for i in range(n_units):
            stop = start + base + (i < extra)
            made.append(unit(grouped[start:stop]))
            start = stop
    return made
