"""The sweep presets, and how a preset is narrowed.

The paper's values come from :mod:`tacbench.paper`, which cites the paper for each: the six tasks
(:data:`~tacbench.paper.TASKS`, as the Gymnasium ids of :data:`~tacbench.paper.ENV_IDS`), the q
grid of section 7.1, each task's alpha and best q (per-task table), the seeds (Hyperparameter
Settings table), the compared methods of section 7.2 (:data:`~tacbench.paper.BASELINES`; TAC with
q = 1 "denoted as SAC") and 1M steps per run (:data:`~tacbench.paper.TOTAL_STEPS`).

Every other setting is the trainer's default (docs/tac.md, baselines/hyperparams/*.yaml).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Any

from tacbench import paper
from tacbench.errors import TacbenchError
from tacbench.settings import RunSettings, settings_of
from tacbench.trainers import tac_flags_for_baseline

# smoke: ours, the budgets of the trainers' own smoke tests, halved: 1,000 steps,
# learning from step 500 with minibatches of 32, two evaluation episodes at 500 and 1,000.
SMOKE_STEPS = 1000
SMOKE_TAC = {
    "learning_starts": 500,
    "batch_size": 32,
    "eval_every": 500,
    "eval_episodes": 2,
    "log_every": 250,
    "checkpoint_every": 500,
}
SMOKE_BASELINE = {k: v for k, v in SMOKE_TAC.items() if k not in ("learning_starts", "batch_size")}
SMOKE_HP = {
    "td3": ("learning_starts=500", "batch_size=32"),
    "ppo": ("n_steps=250", "batch_size=50", "n_epochs=2"),  # 4 rollouts in 1,000 steps
}


@dataclass(frozen=True)
class Entry:
    """One algorithm on some tasks and seeds: TAC at each of ``q`` (empty: the paper's best q
    per task) with the paper's alpha, or a baseline with its table's hyperparameters and the
    ``hp`` overrides. ``settings`` are run settings (``total_steps``, ``eval_every``, ...)."""

    algo: str
    tasks: tuple[str, ...]
    seeds: tuple[int, ...]
    q: tuple[float, ...] = ()
    settings: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))
    hp: tuple[str, ...] = ()
    label: str = ""
    suite: str = paper.DEFAULT_SUITE  # which Gymnasium version of the tasks (paper.SUITES)

    def env_id(self, task: str) -> str:
        """The Gymnasium id this entry trains ``task`` on."""
        return paper.SUITES[self.suite][task]

    def q_values(self, task: str) -> tuple[float, ...]:
        """The q values this entry trains on ``task`` (TAC only; empty for a baseline)."""
        if self.algo != "tac":
            return ()
        return self.q or (paper.TASK_FACTS[task].best_q,)


@dataclass(frozen=True)
class Preset:
    """A named grid: a list of entries and a description naming its sources."""

    name: str
    description: str
    entries: tuple[Entry, ...]


def _frozen(values: Mapping[str, Any]) -> Mapping[str, Any]:
    return MappingProxyType(dict(values))


PAPER_STEPS = _frozen({"total_steps": paper.TOTAL_STEPS})

PRESETS: dict[str, Preset] = {
    preset.name: preset
    for preset in (
        Preset(
            "paper-q-grid",
            f"TAC at q in {{{', '.join(f'{q:g}' for q in paper.Q_GRID)}}} (paper section 7.1, "
            "line 797) on "
            "the six tasks (line 767), the paper's alpha per task (line 799), seeds 0..90 step "
            "10 (line 2054), 1M steps each",
            (Entry("tac", paper.TASKS, paper.SEEDS, paper.Q_GRID, PAPER_STEPS),),
        ),
        Preset(
            "paper-comparison",
            "TAC at the paper's best q per task (line 857, per-task table), TAC q = 1 as SAC "
            "(lines 786-788), DDPG, TD3, PPO, TRPO (lines 773-784) and, ours, stable-baselines3's "
            "SAC as an independent SAC (docs/parity.md) on the six tasks, seeds 0..90 step 10 "
            "(line 2054), 1M steps each",
            (
                Entry("tac", paper.TASKS, paper.SEEDS, (), PAPER_STEPS, label="TAC"),
                Entry("tac", paper.TASKS, paper.SEEDS, (1.0,), PAPER_STEPS, label="SAC"),
                *(Entry(a, paper.TASKS, paper.SEEDS, (), PAPER_STEPS) for a in paper.BASELINES),
                Entry("sac-sb3", paper.TASKS, paper.SEEDS, (), PAPER_STEPS),
            ),
        ),
        Preset(
            "smoke",
            "tiny budgets for tests and a first try (ours): TAC q = 1 and 2, TD3 and PPO on "
            f"Hopper, seeds 0 and 10, {SMOKE_STEPS:,} steps each",
            (
                Entry(
                    "tac",
                    ("Hopper",),
                    (0, 10),
                    (1.0, 2.0),
                    _frozen({"total_steps": SMOKE_STEPS, **SMOKE_TAC}),
                ),
                *(
                    Entry(
                        algo,
                        ("Hopper",),
                        (0, 10),
                        (),
                        _frozen({"total_steps": SMOKE_STEPS, **SMOKE_BASELINE}),
                        hp,
                    )
                    for algo, hp in SMOKE_HP.items()
                ),
            ),
        ),
    )
}


@dataclass(frozen=True)
class Narrowing:
    """What ``--env/--q/--algo/--seed`` keep (empty: all) and the settings that replace the
    preset's (``--steps``, ``--critic-target``, ...: config field -> value). A TAC setting
    applies to TAC's entries (a baseline's: :func:`narrow`); a run setting
    (:class:`tacbench.settings.RunSettings`) to all."""

    tasks: tuple[str, ...] = ()
    q: tuple[float, ...] = ()
    algos: tuple[str, ...] = ()
    seeds: tuple[int, ...] = ()
    settings: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))
    suite: str = paper.DEFAULT_SUITE  # --suite: the tasks' Gymnasium version (paper.SUITES)


def get_preset(name: str) -> Preset:
    """The preset called ``name``."""
    if name not in PRESETS:
        raise TacbenchError(f"unknown preset {name!r}; choose one of {', '.join(PRESETS)}.")
    return PRESETS[name]


def narrow(preset: Preset, by: Narrowing) -> Preset:
    """``preset`` restricted to the tasks, q values, algorithms and seeds in ``by`` (each must
    occur in the preset), with ``by.settings`` replacing the preset's. A TAC setting given for
    a baseline's entry becomes its equivalent hyperparameter or is refused, as in ``tacbench
    run`` (:func:`tacbench.trainers.tac_flags_for_baseline`). A ``--q`` keeps TAC entries only:
    baselines have no q. Every entry trains the tasks of suite ``by.suite``."""
    if by.suite not in paper.SUITES:
        raise TacbenchError(f"--suite {by.suite}: choose one of {', '.join(paper.SUITES)}.")
    entries = tuple(replace(e, suite=by.suite) for e in preset.entries)
    run_settings = set(settings_of(RunSettings))
    by = replace(by, tasks=tuple(task_of(name, by.suite) for name in by.tasks))
    _check_subset("--env", by.tasks, {t for e in entries for t in e.tasks})
    _check_subset("--algo", by.algos, {e.algo for e in entries})
    _check_subset("--seed", by.seeds, {s for e in entries for s in e.seeds})
    all_q = {q for e in entries for t in e.tasks for q in e.q_values(t)}
    _check_subset("--q", by.q, all_q)
    kept = []
    for entry in entries:
        if by.algos and entry.algo not in by.algos:
            continue
        if by.q and entry.algo != "tac":
            continue
        tasks = tuple(t for t in entry.tasks if not by.tasks or t in by.tasks)
        if by.q and entry.q:
            entry = replace(entry, q=tuple(q for q in entry.q if q in by.q))
            if not entry.q:
                continue
        elif by.q:  # the paper's best q per task: keep the tasks whose best q was asked for
            tasks = tuple(t for t in tasks if entry.q_values(t)[0] in by.q)
        seeds = tuple(s for s in entry.seeds if not by.seeds or s in by.seeds)
        if not tasks or not seeds:
            continue
        given = dict(by.settings)
        hp = entry.hp
        if entry.algo != "tac":  # TAC's flags: the baseline's equivalent, or refused
            tac_only = {k: v for k, v in given.items() if k not in run_settings}
            flags = tac_flags_for_baseline(entry.algo, tac_only)
            replaced = {item.partition("=")[0] for item in flags}  # the user's over the preset's
            hp = (*(item for item in hp if item.partition("=")[0] not in replaced), *flags)
            given = {k: v for k, v in given.items() if k in run_settings}
        settings = _frozen({**entry.settings, **given})
        kept.append(replace(entry, tasks=tasks, seeds=seeds, settings=settings, hp=hp))
    if not kept:
        raise TacbenchError(
            f"--env/--q/--algo/--seed leave no run of preset {preset.name!r}; "
            "`tacbench sweep --preset NAME --dry-run` lists what it holds."
        )
    return replace(preset, entries=tuple(kept))


def task_of(name: str, suite: str = paper.DEFAULT_SUITE) -> str:
    """The paper task for ``name``: a task name in any case (``hopper``) or its id in ``suite``
    (``Hopper-v4``). Another version of a task is refused: the presets train the suite's."""
    task = paper.suite_task(name, suite)
    if task is None:
        ids = ", ".join(f"{task} ({env_id})" for task, env_id in paper.SUITES[suite].items())
        other = [s for s in paper.SUITES if paper.suite_task(name, s)]
        hint = f" {name} is in suite {other[0]}: add --suite {other[0]}." if other else ""
        raise TacbenchError(
            f"--env {name}: the presets train the paper's tasks, here of suite {suite}: "
            f"{ids}.{hint}"
        )
    return task


def _check_subset(flag: str, given: Sequence[Any], available: set[Any]) -> None:
    def show(values: Sequence[Any]) -> str:  # short, but never two values the same
        return ", ".join(
            f"{v:g}" if isinstance(v, float) and float(f"{v:g}") == v else str(v) for v in values
        )

    missing = [v for v in given if v not in available]
    if missing:
        raise TacbenchError(
            f"{flag} {show(missing)}: not in this preset, which has {show(sorted(available))}."
        )
