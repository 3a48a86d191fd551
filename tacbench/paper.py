"""The paper's facts, in one place: its tasks, q grid, seeds, hyperparameter table, each task's
alpha and best q, the baselines it compared, and where the authors' code (the ``reference``
profile) did otherwise than its table.

Everything in tacbench that needs one of these imports it from here; ``tests/test_paper.py``
reads the tables of ``shared/paper/tsallis-rl-paper.tex`` and checks this module against them.
Line numbers below refer to that file. The paper ran the ``-v2`` MuJoCo tasks (mujoco-py); a
run of any version of a task (``Hopper-v4``, ``Hopper-v5``) is matched on the task's name.
No imports beyond the standard library: the CLI reads this at start-up.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

TASKS: tuple[str, ...] = ("HalfCheetah", "Ant", "Pusher", "Humanoid", "Hopper", "Swimmer")
"""The six MuJoCo tasks (section 7, line 767), in the paper's panel order: the four of the main
text, then the two of the appendix "Full Experimental Results"."""

ENV_IDS: MappingProxyType[str, str] = MappingProxyType(
    {
        "HalfCheetah": "HalfCheetah-v4",
        "Ant": "Ant-v4",
        "Pusher": "Pusher-v5",
        "Humanoid": "Humanoid-v4",
        "Hopper": "Hopper-v4",
        "Swimmer": "Swimmer-v4",
    }
)
"""Each task's Gymnasium id: v4, the closest to the paper's v2 that runs on mujoco >= 3, except
Pusher, whose v4 only loads with mujoco < 3 (Gymnasium issue 950)."""

SUITES: MappingProxyType[str, MappingProxyType[str, str]] = MappingProxyType(
    {
        "v4": ENV_IDS,
        "v5": MappingProxyType({task: f"{task}-v5" for task in ENV_IDS}),
    }
)
"""The task suites by Gymnasium version (``--suite``). ``v4``, the default and the published
studies' suite: the closest to the paper's v2 (:data:`ENV_IDS`). ``v5``: what Gymnasium
recommends for new work (Ant-v5 observes 105 dimensions instead of 27; Hopper, Walker2d, Ant
and Humanoid pay the healthy reward only while healthy). The paper's alpha and best q per task
(:data:`TASK_FACTS`) are carried over to v5 unchanged: the paper tuned them on v2."""

DEFAULT_SUITE = "v4"

Q_GRID: tuple[float, ...] = (0.5, 0.7, 1.0, 1.2, 1.5, 1.7, 2.0, 3.0, 5.0)
"""The entropic indices of the q sweep (section "Effect of Entropic Index", line 797)."""

SEEDS: tuple[int, ...] = (0, 10, 20, 30, 40, 50, 60, 70, 80, 90)
"""Hyperparameter Settings table (line 2054); "ten different random seeds" (lines 800, 867)."""

TOTAL_STEPS = 1_000_000
"""Environment steps per run: the paper's figures span 1M steps; the reference code runs 200
epochs of 5,000 steps."""

BASELINES: tuple[str, ...] = ("ddpg", "td3", "ppo", "trpo")
"""The compared methods of section "Comparative Evaluation" (lines 773-784) besides SAC, which
the paper runs as TAC with q = 1 (lines 786-788)."""


@dataclass(frozen=True)
class Hyperparameters:
    """The Hyperparameter Settings table (appendix "Implementation Detail", lines 2039-2055)."""

    optimizer: str = "Adam"
    learning_rate: float = 1e-3
    gamma: float = 0.99
    buffer_size: int = 1_000_000
    min_samples: int = 100_000  # "Number of Minimum samples in buffer"; the reference code: 10,000
    hidden_layers: int = 1
    hidden_units: int = 300
    activation: str = "relu"
    batch_size: int = 100
    tau: float = 0.005  # "Moving average ratio"
    seeds: tuple[int, ...] = SEEDS

    @property
    def hidden_sizes(self) -> tuple[int, ...]:
        """The table's networks as layer widths: ``(300,)``."""
        return (self.hidden_units,) * self.hidden_layers


HYPERPARAMETERS = Hyperparameters()


@dataclass(frozen=True)
class TaskFacts:
    """What the paper says about one task: the entropy coefficient of its runs, its best q with
    the table's qualifier (``"slightly better"`` where the table marks the differences as small),
    and what the text says about the q sweep on it."""

    alpha: float
    best_q: float
    qualifier: str
    says: str

    @property
    def best_q_label(self) -> str:
        """``"1.5"`` or ``"2 (slightly better)"``."""
        return f"{self.best_q:g}" + (f" ({self.qualifier})" if self.qualifier else "")


TASK_FACTS: MappingProxyType[str, TaskFacts] = MappingProxyType(
    {
        # per-task table (lines 2058-2068); the text: section 7.1 (lines 819-825) and the
        # appendix "Full Experimental Results" (lines 1826-1831)
        "HalfCheetah": TaskFacts(0.2, 1.5, "", "q = 1.5 best within 1 <= q < 2"),
        "Ant": TaskFacts(0.2, 1.5, "", "q = 1.5 best; SAC (q = 1) third in the comparison"),
        "Pusher": TaskFacts(
            0.2,
            1.2,
            "slightly better",
            "final returns similar for all q; q = 1.2 converges slightly faster",
        ),
        "Humanoid": TaskFacts(0.05, 1.2, "", "q = 1.2 best, 'dramatically' ahead of the others"),
        "Hopper": TaskFacts(0.2, 2.0, "slightly better", "1 <= q <= 2 perform similarly"),
        "Swimmer": TaskFacts(0.2, 2.0, "slightly better", "every q stuck in a local optimum"),
    }
)
"""The paper's facts per task (its table's order differs; :data:`TASKS` is the panel order)."""

DEFAULT_ALPHA = 0.2
"""alpha for a task outside the paper: the paper's value for every task but Humanoid."""

DEFAULT_Q = 1.0
"""q for a task outside the paper, which names no best q there: q = 1 (Shannon entropy, SAC)."""

DENSITY_CAP_RULES: tuple[str, ...] = ("paper", "every-q", "off")
"""Where the density cap ``10^(8/(q-1))`` applies (``--density-cap``): ``paper`` for q >= 2 (the
appendix "Numerical Issue", lines 2026-2035; the authors' final code), ``every-q`` for every q != 1
(the authors' code of 2019-01-16, 7b0308a), ``off`` nowhere (their code before that)."""


def density_log_cap(q: float, rule: str = "paper") -> float:
    """The log of the density cap ``10^(8/(q-1))`` where ``rule`` (:data:`DENSITY_CAP_RULES`)
    applies it: the paper's for q >= 2 ("Numerical Issue"); +inf (no cap) elsewhere and at
    q = 1."""
    if rule not in DENSITY_CAP_RULES:
        raise ValueError(f"unknown density cap rule {rule!r}")
    applies = {"paper": q >= 2.0, "every-q": q != 1.0, "off": False}[rule]
    return 8.0 * math.log(10.0) / (q - 1.0) if applies else math.inf


_PAPER_DENSITY: dict[str, Any] = {
    "lnq": "per-dim",  # the authors' final code; the paper writes the joint density (docs/tac.md)
    "density_floor": 1e-6,  # the authors' final code (7a7e754): each dimension's density >= 1e-6
    "density_cap": "paper",  # appendix "Numerical Issue": q >= 2 only
    "jacobian_clip": 0.0,  # SAC v1 and the authors' final code: 1 - tanh^2 + 1e-6, no clip
    "gaussian_eps": 0.0,  # the exact Gaussian log-density
}
_REFERENCE: dict[str, Any] = {
    "update_schedule": "episode",  # tac.py's main loop: bursts at episode ends
    "warmup_updates": "on",  # tac.py: from the first episode end, during warm-up
    "hidden_sizes": (400, 300),  # core.py's default, never overridden by the scripts
    "time_limits": "terminal-below-1000",  # tac.py: d = False only if ep_len == 1000
    "action_scale": "bound",  # core.py: tanh output times action_space.high[0]
    **_PAPER_DENSITY,
}


def _authors(**density: Any) -> MappingProxyType[str, Any]:
    """The authors' code on a date: the reference profile (which no version changed) with that
    date's density formulas, and Spinning Up's ``sigma + 1e-8`` that every version has."""
    return MappingProxyType({**_REFERENCE, "gaussian_eps": 1e-8, **density})


PROFILES: MappingProxyType[str, MappingProxyType[str, Any]] = MappingProxyType(
    {
        "paper": MappingProxyType(
            {
                "update_schedule": "step",  # one update per environment step
                "warmup_updates": "off",  # the table's minimum samples: no update before them
                "hidden_sizes": HYPERPARAMETERS.hidden_sizes,  # Hyperparameter Settings table
                "time_limits": "not-terminal",  # a time-limit end is never terminal (SB3, CleanRL)
                "action_scale": "unit",  # the critics and the buffer see actions in [-1, 1]
                **_PAPER_DENSITY,
            }
        ),
        "reference": MappingProxyType(_REFERENCE),
        # 3c5cf2b, 2019-01-07 17:23 +0900 ("Check numerical safety of tac"), in force 87.6 h
        "authors-2019-01-07b": _authors(
            lnq="joint-batch-max",  # 3c5cf2b: joint density over the minibatch's largest
            density_floor=1e-8,  # 3c5cf2b: max(..., 1e-8)
            density_cap="off",  # no cap before 7b0308a
            jacobian_clip=1e-3,  # 3c5cf2b: clip_but_pass_gradient(1 - tanh^2, 1e-3, 1)
        ),
        # 5ec199b, 2019-01-11 09:15 +0900 ("Really bug free"), in force 120.4 h
        "authors-2019-01-11b": _authors(
            density_floor=1e-8,  # 5ec199b: each dimension's density >= 1e-8
            density_cap="off",  # no cap before 7b0308a
        ),
        # 7b0308a, 2019-01-16 10:38 +0900 ("Fix bug in clipping pdf"), the code of "Final plot"
        # (f87da3c, 14:13), in force 153.2 h
        "authors-2019-01-16c": _authors(
            density_floor=1e-8,  # 7b0308a: each dimension's density >= 1e-8
            density_cap="every-q",  # 7b0308a: min(density, 10^(8/(q-1))) for every q
        ),
        # 7a7e754, 2019-01-22 19:51 +0900 ("trim useless code"), unchanged to the last commit
        "authors-2019-01-22": _authors(),
    }
)
"""The settings where the paper's table leaves a choice or the authors' code (rllab-snu/
tsallis_actor_critic_mujoco) did otherwise: ``--profile paper`` (the default); ``reference``,
the authors' final code as tacbench first read it (REFERENCE.md; docs/tac.md, "Profiles"),
which is ``authors-2019-01-22`` but for Spinning Up's ``sigma + 1e-8``; and the authors' code
as it stood on a date, each version that could have made a published curve
(docs/authors-versions.md). Each value is also a setting of its own."""

PROFILE_VARIANTS: MappingProxyType[str, str] = MappingProxyType(
    {name: "ref" if name == "reference" else name.replace("-", "") for name in PROFILES}
)
"""Each profile's word in a run's variant name (``-ref``, ``-authors20190111b``); the default
profile's never appears."""


def task_name(env_id: str) -> str:
    """The task's name without its version: ``"Hopper-v4"`` -> ``"Hopper"``."""
    head, sep, tail = env_id.rpartition("-v")
    return head if sep and tail.isdigit() else env_id


def paper_task(env_id: str) -> str | None:
    """The paper's task for a Gymnasium id of any version (``Hopper-v5`` -> ``Hopper``), or
    None for a task the paper did not run."""
    name = task_name(env_id)
    return name if name in ENV_IDS else None


def suite_task(name: str, suite: str = DEFAULT_SUITE) -> str | None:
    """The paper's task that ``name`` names: a task name or its id in ``suite``, in any case
    (``hopper``, ``Hopper-v4``); None for anything else (another version included)."""
    for task, env_id in SUITES[suite].items():
        if name.lower() in (task.lower(), env_id.lower()):
            return task
    return None


def task_facts(env_id: str) -> TaskFacts | None:
    """The paper's facts for a Gymnasium id of any version, or None."""
    task = paper_task(env_id)
    return None if task is None else TASK_FACTS[task]


def task_sort_key(env_id: str) -> tuple[int, str]:
    """Sort key putting tasks in the paper's panel order, unknown tasks after, alphabetically."""
    task = paper_task(env_id)
    return (TASKS.index(task) if task else len(TASKS)), env_id
