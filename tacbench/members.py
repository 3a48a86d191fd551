"""The members of one ``tacbench run``: a config per (q, alpha, seed) of the flags' product, or
a ``--q auto`` population, with the paper's values filled in and notes that say where each
default came from and what ``--compile auto`` chose."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from typing import Any

from tacbench import paper
from tacbench.config import COMPILE_AUTO_LEARNING_STEPS, RunConfig
from tacbench.config_checks import check_q_range
from tacbench.errors import TacbenchError
from tacbench.settings import RunWarning, never_updated, settings_of


def paper_defaults(task: str | None) -> tuple[float, float, str, str]:
    """(q, alpha, where q comes from, where alpha comes from) for a paper task name (None: a
    task the paper did not run)."""
    if task is None:
        return (
            paper.DEFAULT_Q,
            paper.DEFAULT_ALPHA,
            "the paper reports no best q for this task; q = 1 is Shannon entropy, i.e. SAC",
            "the paper's alpha for every task but Humanoid",
        )
    facts = paper.TASK_FACTS[task]
    qualifier = f", {facts.qualifier}" if facts.qualifier else ""
    return (
        facts.best_q,
        facts.alpha,
        f"the paper's best q for {task} (appendix, per-task table{qualifier})",
        f"the paper's alpha for {task} (appendix, per-task table)",
    )


def make_run_configs(
    env: str,
    task: str | None,
    seeds: Sequence[int],
    qs: Sequence[float] = (),
    alphas: Sequence[float] = (),
    **overrides: Any,
) -> tuple[list[RunConfig], list[str]]:
    """One config per (q, alpha, seed) of the cross product (the members of one process) and
    notes on the defaults chosen.

    ``task`` is the paper's name for ``env`` (None if the paper did not run it); ``qs`` and
    ``alphas`` left empty take the paper's values for that task.
    """
    for flag, values in (("--seed", seeds), ("--q", qs), ("--alpha", alphas)):
        if len(set(values)) != len(values):
            raise TacbenchError(f"{flag} values must differ (got {list(values)}).")
    if not seeds:
        raise TacbenchError("give at least one --seed.")
    paper_q, paper_alpha, q_source, alpha_source = paper_defaults(task)
    if task is not None and env != paper.ENV_IDS[task]:  # another version (--suite v5)
        carried = f", tuned on {task}-v2 and carried over to {env} unchanged"
        q_source, alpha_source = q_source + carried, alpha_source + carried
    notes = []
    if not qs:
        notes.append(f"q = {paper_q:g}: {q_source}")
    if not alphas:
        notes.append(f"alpha = {paper_alpha:g}: {alpha_source}")
    learned_q = overrides.get("q_mode") == "auto"  # q changes during training
    if learned_q:
        configs = _population(env, seeds, qs, alphas or (paper_alpha,), overrides)
        notes[:1] = [
            f"q = auto: {len(seeds)} members start at q = "
            + ", ".join(f"{c.q:.3g}" for c in configs)
        ]
    else:
        configs = [
            RunConfig(env=env, q=q, alpha=alpha, seed=seed, **overrides)
            for q in qs or (paper_q,)
            for alpha in alphas or (paper_alpha,)
            for seed in seeds
        ]
    first = configs[0]
    rule = first.density_cap
    if learned_q:
        if rule == "every-q" or (rule == "paper" and max(c.q_range[1] for c in configs) >= 2):
            notes.append(
                f"q = auto: while a member's q is {'2 or more' if rule == 'paper' else 'not 1'}, "
                f"its policy density is capped at 10^(8/(q-1)) (--density-cap {rule})"
            )
    else:
        for q in sorted({c.q for c in configs}):
            log_cap = paper.density_log_cap(q, rule)
            if math.isfinite(log_cap):  # as a power of ten: near q = 1 it overflows a float
                notes.append(
                    f"q = {q:g}: the policy density is capped at 10^{log_cap / math.log(10):.3g} "
                    f"(--density-cap {rule}; the paper's Numerical Issue)"
                )
    if learned_q and 0 < first.learning_steps <= first.pbt_every:  # no round at the last step
        notes.append(
            RunWarning(
                f"WARNING: --pbt-every {first.pbt_every:,} is not shorter than the run's "
                f"{first.learning_steps:,} learning steps: no population round happens, so each "
                "member keeps the q it starts with"
            )
        )
    if first.warmup_updates != "on":  # on: updates start at each member's first episode end
        starts, total = first.learning_starts, first.total_steps
        notes += never_updated("--learning-starts", starts, total, first_update_at_start=True)
    notes.append(compile_note(resolve_compile(first), overrides.get("compile", "auto")))
    return configs, notes


MIN_POPULATION = 4  # --q auto: the bottom quarter of fewer than four is nobody


def initial_qs(n: int, q_range: tuple[float, float]) -> list[float]:
    """``n`` values spread evenly in log q over ``q_range`` (both ends included, never beyond
    ``high``: ``low * (high / low)`` can round above it, as for 0.1,1.7, or below, as for 0.7,3,
    which populations started before the cap keep): where the members of a ``--q auto``
    population start."""
    low, high = q_range
    if n == 1:
        return [math.sqrt(low * high)]
    return [min(low * (high / low) ** (i / (n - 1)), high) for i in range(n)]


def _population(
    env: str,
    seeds: Sequence[int],
    qs: Sequence[float],
    alphas: Sequence[float],
    overrides: Mapping[str, Any],
) -> list[RunConfig]:
    """``--q auto``: one member per seed, starting at q spread in log q over ``--q-range``."""
    if qs or len(alphas) != 1:
        raise TacbenchError(
            "--q auto learns q: give no other --q, and one --alpha (or --alpha auto)."
        )
    if len(seeds) < MIN_POPULATION:
        raise TacbenchError(
            f"--q auto needs a population of at least {MIN_POPULATION} members: repeat --seed "
            f"(got {len(seeds)}; e.g. --seed 0 --seed 10 --seed 20 --seed 30)."
        )
    q_range = overrides.get("q_range", settings_of(RunConfig)["q_range"].default)
    starts = initial_qs(len(seeds), check_q_range(q_range))
    return [
        RunConfig(env=env, q=q, alpha=alphas[0], seed=seed, **overrides)
        for q, seed in zip(starts, seeds, strict=True)
    ]


def resolve_compile(config: RunConfig, recorded: str | None = None) -> RunConfig:
    """``config`` with ``--compile auto`` resolved where the run trains: the value ``recorded``
    in the run's ``config.json`` when it resumes (a run keeps the rounding it started with),
    else on for a run long enough to repay the compilation, where a C++ compiler is found
    (which torch.compile needs on a CPU). Configs are built with ``auto`` left in them, so a
    sweep's worker decides for its own machine, not the planning one."""
    if config.compile != "auto":
        return config
    if recorded in ("on", "off"):
        return dataclasses.replace(config, compile=recorded)
    from tacbench.hardware import cpp_compiler  # torch's Inductor: only when it matters

    chosen = "on" if repays_compilation(config) and cpp_compiler() is not None else "off"
    return dataclasses.replace(config, compile=chosen)


def repays_compilation(config: RunConfig) -> bool:
    """Whether ``config`` has the learning steps that ``--compile auto`` compiles for."""
    return config.learning_steps >= COMPILE_AUTO_LEARNING_STEPS


def compile_note(config: RunConfig, asked: str) -> str:
    """What ``--compile`` resolved to for ``config``, and why."""
    if asked != "auto":
        return f"compile: {config.compile} (--compile {asked})"
    if not repays_compilation(config):
        return (
            f"compile: off (--compile auto: {config.learning_steps:,} learning steps, fewer than "
            f"the {COMPILE_AUTO_LEARNING_STEPS:,} that repay the compilation)"
        )
    if config.compile == "off":
        return (
            "WARNING: compile: off (--compile auto found no C++ compiler, which torch.compile "
            "needs on a CPU; install one, e.g. Debian's g++, for a 3-4x faster update)"
        )
    return (
        f"compile: on (--compile auto: {config.learning_steps:,} learning steps repay the "
        "compilation of the first update)"
    )


def members_label(configs: Sequence[RunConfig]) -> str:
    """``q=1.5 seeds 0,10`` or, for a mixed group, ``q=0.5,1,1.5 alpha=0.2,0.1 seeds 0,10 (12
    members)``; a long list shows its ends (``seeds 0,1,...,44``)."""

    def listed(values: list[float]) -> str:
        shown = [f"{v:g}" for v in values]
        return ",".join(shown if len(shown) <= 6 else [*shown[:2], "...", shown[-1]])

    qs = list(dict.fromkeys(c.q for c in configs))
    alphas = list(dict.fromkeys(c.alpha for c in configs))
    seeds = list(dict.fromkeys(c.seed for c in configs))
    q_part = "q=auto" if configs[0].q_mode == "auto" else f"q={listed(qs)}"
    parts = [q_part] + ([f"alpha={listed(alphas)}"] if len(alphas) > 1 else [])
    parts.append(f"seed{'s' if len(seeds) > 1 else ''} {listed([float(s) for s in seeds])}")
    return " ".join(parts) + (f" ({len(configs)} members)" if len(configs) > 1 else "")
