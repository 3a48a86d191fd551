"""The sequential design of ``tacbench sweep --until-decided``: its numbers (:class:`Design`),
each task's methods, labelled as the report labels them, and what each is compared with
(``--control``), checked before anything trains (:mod:`tacbench.sweep.until_decided` runs it)."""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

from tacbench import paper
from tacbench.errors import TacbenchError
from tacbench.report.methods import BASELINE_NAMES, tac_label
from tacbench.sequential import DEFAULT_ALPHA, DEFAULT_B, run_sequential
from tacbench.sweep import plan
from tacbench.sweep.presets import Entry, Preset

# the paper's seeds are 0, 10, ..., 90 (line 2054); further seeds continue that spacing
SEED_SPACING = 10
PAIRS = "pairs"  # --control pairs: every pair of methods
BEST_Q = "best-q"  # --control best-q: TAC at the paper's best q of each task


MAX_RUNS_PER_METHOD = 1_000  # n x K: a hundred times the paper's ten seeds


@dataclass(frozen=True)
class Design:
    """The sequential design: ``n`` runs per method per interim, at most ``K`` interims,
    family-wise error rate ``alpha`` per task, the ``control`` each method is compared with
    (a method label, ``best-q`` or ``pairs``), AdaStop's ``B`` permutations and its ``seed``."""

    n: int = 5  # two interims of five: at most the paper's ten seeds (line 2054)
    K: int = 2
    alpha: float = DEFAULT_ALPHA
    control: str = ""  # "": the preset's (default_control)
    B: int = DEFAULT_B
    seed: int = 0

    def __post_init__(self) -> None:
        if self.n < 1 or self.K < 1:
            raise TacbenchError(
                f"--interim-runs and --interims must be at least 1 (got {self.n}, {self.K})."
            )
        if self.n * self.K > MAX_RUNS_PER_METHOD:
            raise TacbenchError(
                f"--interim-runs {self.n} x --interims {self.K} is {self.n * self.K:,} runs per "
                f"method and task, above {MAX_RUNS_PER_METHOD:,} (the paper ran 10); lower "
                "--interim-runs or --interims."
            )
        if not 0.0 < self.alpha < 1.0:
            raise TacbenchError(f"--fwer must lie between 0 and 1 (got {self.alpha!r}).")


@dataclass(frozen=True)
class Method:
    """One method of a task: a preset entry narrowed to the task (and to one q for TAC)."""

    label: str
    entry: Entry

    def first(self, count: int) -> Entry:
        """Its entry narrowed to its first ``count`` seeds (:func:`seed_order`)."""
        return replace(self.entry, seeds=seed_order(self.entry.seeds, count))

    def runs(self, count: int) -> list[plan.Run]:
        """Its first ``count`` runs, in seed order."""
        return plan.build_runs(Preset("", "", (self.first(count),)))


def seed_order(seeds: Sequence[int], count: int) -> tuple[int, ...]:
    """The first ``count`` seeds: ``seeds`` in order, then ``SEED_SPACING`` apart after the
    largest."""
    order = list(seeds[:count])
    after = max(seeds, default=-SEED_SPACING)
    order += [after + SEED_SPACING * k for k in range(1, count - len(order) + 1)]
    return tuple(order)


def default_control(preset: Preset) -> str:
    """TAC at the paper's best q for a grid that holds baselines (the comparison study), SAC
    (TAC q = 1, the paper's question: does a q other than 1 help?) for TAC alone, and every
    pair for baselines alone (no TAC to compare them with)."""
    algos = {e.algo for e in preset.entries}
    if "tac" not in algos:
        return PAIRS
    return BEST_Q if algos != {"tac"} else tac_label(1.0)


def methods_of(preset: Preset) -> dict[str, list[Method]]:
    """Each task's methods (by Gymnasium id), labelled as the report labels them: TAC by q
    (``SAC (TAC q=1)``, ``TAC q=1.5``), a baseline by name. A method listed twice (the
    comparison's TAC at a best q of 1 and its SAC) is kept once."""
    tasks: dict[str, list[Method]] = {}
    for entry in preset.entries:
        for task in entry.tasks:
            for q in entry.q_values(task) or (math.nan,):
                label = BASELINE_NAMES.get(entry.algo, entry.algo.upper())
                narrowed = replace(entry, tasks=(task,))
                if entry.algo == "tac":
                    label, narrowed = tac_label(q), replace(narrowed, q=(q,))
                methods = tasks.setdefault(entry.env_id(task), [])
                if label not in [m.label for m in methods]:
                    methods.append(Method(label, narrowed))
    return tasks


def with_controls(
    design: Design, preset: Preset, tasks: dict[str, list[Method]]
) -> tuple[Design, dict[str, str | None]]:
    """``design`` with its control (the grid's default, :func:`default_control`, where none was
    given) and each task's control label (:func:`control_of`); a default the grid lacks is
    refused as such, not as a ``--control`` the user never gave."""
    defaulted = not design.control
    design = replace(design, control=design.control or default_control(preset))
    controls = {env: control_of(design, env, m, defaulted) for env, m in tasks.items()}
    return design, controls


def control_of(
    design: Design, env: str, methods: Sequence[Method], defaulted: bool = False
) -> str | None:
    """The label of ``env``'s control (None: every pair), or TacbenchError naming the choices
    (also for a task with a single method: nothing to compare); ``defaulted``: the control is
    the grid's default, not a --control given."""
    labels = [m.label for m in methods]
    if len(labels) < 2:
        raise TacbenchError(
            f"--until-decided compares the methods of a task, and {env} has one ("
            f"{', '.join(labels)}); keep more of the preset's q values or algorithms."
        )
    wanted = design.control
    if wanted.lower() == PAIRS:
        return None
    if wanted.lower() == BEST_Q:
        facts = paper.TASK_FACTS[paper.task_name(env)]
        wanted = tac_label(facts.best_q)
    found = [label for label in labels if label.lower() == wanted.lower()]
    q = wanted.lower().removeprefix("q=")
    if q != wanted.lower() and q.replace(".", "", 1).isdigit():  # q=1.5: TAC q=1.5 (q=1: SAC)
        found = [label for label in labels if label == tac_label(float(q))]
    choices = f"{', '.join(labels)}, {BEST_Q} or {PAIRS}"
    if not found and defaulted:
        raise TacbenchError(
            f"{env} has no {design.control}, this grid's default control: keep it in the grid, "
            f"or give --control one of {choices}."
        )
    if not found:
        raise TacbenchError(
            f"--control {design.control}: {env} has no such method; choose one of {choices}."
        )
    return found[0]


@functools.cache
def earliest_decision(design: Design, methods: int, paired: bool) -> int | None:
    """The first interim at which the design can decide a comparison at all: when every run of
    one method beats every run of the other (None: never, whatever the runs give). Cached:
    tasks with as many methods share the answer, and AdaStop takes seconds to give it."""
    names = [f"m{i}" for i in range(methods)]
    scores = {m: [1e6 * i + j for j in range(design.n * design.K)] for i, m in enumerate(names)}
    control = None if paired else names[0]
    result = run_sequential(scores, design.n, design.K, design.alpha, control, design.B)
    decided = [result.decided_at(p) for p in result.comparisons]
    return min((d for d in decided if d is not None), default=None)


def check_decidable(design: Design, tasks: dict[str, list[Method]]) -> None:
    """Refuse a design that can never decide a comparison of some task, saying what can."""
    for env, methods in tasks.items():
        paired = design.control.lower() == PAIRS
        if earliest_decision(design, len(methods), paired) is not None:
            continue
        larger = next(
            (
                n
                for n in range(design.n + 1, 11)
                if earliest_decision(replace(design, n=n), len(methods), paired) is not None
            ),
            None,
        )
        hint = f"--interim-runs {larger} can" if larger else "raise --interim-runs or --fwer"
        raise TacbenchError(
            f"with --interim-runs {design.n}, --interims {design.K} and --fwer {design.alpha:g} "
            f"no comparison of the {len(methods)} methods on {env} can ever be decided, even if "
            f"every run of one method beats every run of another: too few runs for the "
            f"permutation test to reach its share of the error rate; {hint}."
        )


def check_evaluated(tasks: dict[str, list[Method]]) -> None:
    """Refuse, before anything trains, methods whose runs make no evaluation: every interim is
    scored by its runs' final evaluation returns (eval.csv)."""
    for env, methods in tasks.items():
        for method in methods:
            (run,) = method.runs(1)
            if run.config.eval_every == 0:
                raise TacbenchError(
                    f"--until-decided scores each interim by its runs' final evaluation returns, "
                    f"and {method.label} on {env} would make none (--eval-every 0); give "
                    "--eval-every a number of steps."
                )


def same_design(stored: Any, design: Design, tasks: dict[str, list[Method]]) -> bool:
    """Whether a recorded design is ``design``, its control compared as resolved on each task
    (``q=1`` is ``SAC (TAC q=1)``, ``BEST-Q`` is ``best-q``), not as spelled."""
    try:
        before = Design(**stored)
        resolved = [
            {env: control_of(d, env, methods) for env, methods in tasks.items()}
            for d in (before, design)
        ]
    except (TypeError, TacbenchError):  # not a design, or a control these tasks do not have
        return False
    return replace(before, control="") == replace(design, control="") and resolved[0] == resolved[1]
