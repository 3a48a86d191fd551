"""What a report's runs mix that its comparisons take as alike: several TAC settings on one task
(compared with one q = 1 and pooled into the q ranges by q alone; float32 and bfloat16 products
never are: each compares with its own q = 1, and bf16 runs stay out of the q ranges), several
budgets on one task (final returns of different lengths of training) and several evaluation
intervals on one task (final returns over different stretches of training). The report says so;
it does not refuse."""

from __future__ import annotations

import math
import re

import pandas as pd

from tacbench.config import has_bf16_products
from tacbench.errors import listing

# a TAC variant's q and alpha part: q1.5-a0.2, qauto-aauto0.2, q1e-05-a0.2 (numbers in %g form)
_Q = re.compile(r"^q(?:auto|[0-9.]+(?:e[+-]\d+)?)-")
_Q_ALPHA = re.compile(_Q.pattern + r"a(?:auto)?[0-9.]+(?:e[+-]\d+)?")


def learns_alpha(variants: pd.Series) -> pd.Series:
    """Whether each run learned its alpha (--alpha auto: ``-aauto`` in the variant)."""
    return variants.astype(str).str.contains("-aauto", regex=False)


def without_q(variant: str) -> str:
    """A TAC variant without its q: the runs of one design across q (``q1.5-a0.2-bs32`` ->
    ``a0.2-bs32``; ``qauto-aauto0.2`` -> ``aauto0.2``)."""
    match = _Q.match(variant)
    return variant[match.end() :] if match else variant


def tac_setting(variant: str) -> str:
    """A TAC variant without its q and alpha: the settings that differ from the defaults
    (``q1.5-a0.2-bs32`` -> ``bs32``; ``""`` for the defaults)."""
    match = _Q_ALPHA.match(variant)
    return variant[match.end() :].lstrip("-") if match else variant


def cautions(runs: pd.DataFrame, last: int) -> list[str]:
    """One sentence per task whose TAC runs have several settings, and per task whose runs
    were planned for several budgets; one when runs are partial, one when runs logged fewer
    returns than the ``last`` that their final return averages, and one when runs logged
    non-finite returns (left out)."""
    found = []
    tac = runs[runs["algo"] == "tac"]
    for env, group in tac.groupby("env"):
        for bf16, same_products in group.groupby(group["variant"].map(has_bf16_products)):
            settings = sorted({tac_setting(v) for v in same_products["variant"]})
            if len(settings) > 1:
                shown = ", ".join(f"`{s}`" if s else "the defaults" for s in settings)
                pooled = "comparisons with q = 1" + ("" if bf16 else " and the q ranges")
                found.append(
                    f"{env}: TAC runs of {len(settings)} settings ({shown}); the {pooled} take "
                    "them as one family (rows carry the variant where a q has several). Report "
                    "one setting at a time to compare like with like."
                )
    for env, group in runs.groupby("env"):
        budgets = sorted({int(b) for b in group["total_steps"] if not math.isnan(b)})
        if len(budgets) > 1:
            found.append(
                f"{env}: runs planned for {len(budgets)} budgets "
                f"({', '.join(f'{b:,}' for b in budgets)} steps); final returns after different "
                "lengths of training are compared as if alike."
            )
    partial = runs[runs["partial"]]
    if len(partial):
        found.append(
            f"{len(partial)} of {len(runs)} runs are partial ({listing(list(partial['path']), 3)}):"
            " their final returns are taken where they stopped, and the comparisons, verdicts "
            "and best q count them as the complete runs beside them (the Runs section lists "
            "them)."
        )
    short = runs[runs["rows"] < last]
    if len(short):
        found.append(
            f"{len(short)} of {len(runs)} runs logged fewer returns than --last {last:,} (the "
            f"fewest: {int(short['rows'].min()):,}): their final return is the mean of all of "
            "them, early ones included."
        )
    dropped = runs[runs["dropped"] > 0]
    if len(dropped):
        found.append(
            f"{len(dropped)} of {len(runs)} runs logged rows with a non-finite step or return "
            f"({listing(list(dropped['path']), 3)}; {int(dropped['dropped'].sum()):,} rows in "
            "all), which are left out: a diverged evaluation or episode is in none of their "
            "scores."
        )
    return found


def eval_intervals(data: pd.DataFrame, last: int) -> list[str]:
    """One sentence per task whose runs evaluated at several intervals (``--eval-every``, each
    run's median step between evaluations): the final return, the mean of the last ``last``
    evaluations, then averages a longer stretch of training for some runs than for others
    (with ``last`` 1 it is each run's final evaluation alike)."""
    if last <= 1:
        return []
    steps = data[["run", "env", "step"]].sort_values(["run", "step"], kind="stable")
    gaps = steps.assign(gap=steps.groupby("run")["step"].diff()).dropna(subset=["gap"])
    per_run = gaps.groupby("run").agg(env=("env", "first"), gap=("gap", "median"))
    found = []
    for env, group in per_run.groupby("env"):
        intervals = sorted({int(g) for g in group["gap"]})
        if len(intervals) > 1:
            found.append(
                f"{env}: runs evaluated every {', '.join(f'{i:,}' for i in intervals)} steps; "
                f"their final returns (the last {last:,} evaluations each) span "
                f"{', '.join(f'{(last - 1) * i:,}' for i in intervals)} steps of training, "
                "compared as if alike."
            )
    return found
