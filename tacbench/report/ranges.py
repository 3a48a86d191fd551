"""The paper's claim about ranges of q as a table: TAC's runs pooled by entropic-index range.

Section 7.1 of the paper: TAC "performs better when 1 <= q < 2 than when 0 < q < 1 and q >= 2,
in terms of stable convergence and final total average returns". Per task (and alpha), the TAC
runs of each range of :data:`Q_RANGES` are pooled; each range gets the IQM of its final
returns with a 95 % bootstrap interval, its *spread* (the mean over its runs of the standard
deviation of a run's last logged returns: how steadily a run holds its level, the "stable
convergence" part) and, for the two outer ranges, P(a run of 1 <= q < 2 beats a run of this
range) with its interval (:func:`tacbench.report.stats.probability_of_improvement`), the
p-value of its permutation test and its verdict (:mod:`tacbench.verdicts`). Over
several tasks an "all tasks" row pools the normalised scores for the IQM and averages the
per-task probabilities, for each range that every task (and alpha) has runs in (a range that
one lacks gets none: its row would pool other tasks than the rest); a task run at several
alphas counts once per alpha, as the table shows it (``HalfCheetah-v4 [a0.1]``). The claim is
of a fixed alpha and float32 products: runs that learn their alpha (``--alpha auto``) or train
with bfloat16 products (``--matmul-precision bf16``) are left out, as their own comparisons
with q = 1 are in the improvement table.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from tacbench.config import has_bf16_products
from tacbench.report.mixing import learns_alpha
from tacbench.report.stats import ALL_TASKS, interval_estimates, probability_of_improvement
from tacbench.verdicts import improvement_verdict

Q_RANGES: tuple[tuple[str, float, float], ...] = (
    ("0 < q < 1", 0.0, 1.0),
    ("1 <= q < 2", 1.0, 2.0),
    ("q >= 2", 2.0, math.inf),
)
MIDDLE = "1 <= q < 2"
COLUMNS = [
    "env", "alpha", "range", "qs", "runs", "iqm", "iqm_low", "iqm_high", "spread",
    "p_middle", "p_low", "p_high", "p_value", "verdict",
]  # fmt: skip


def within_run_spread(data: pd.DataFrame, last: int) -> pd.Series:
    """Per run: the (population) standard deviation of its last ``last`` logged returns."""
    tail = data.groupby("run", sort=False).tail(last)
    return tail.groupby("run")["return"].std(ddof=0)


def _range_of(q: float) -> str | None:
    return next((name for name, low, high in Q_RANGES if low <= q < high), None)


def _row(env: str, alpha: float, name: str, runs: pd.DataFrame) -> dict[str, object]:
    qs = ", ".join(f"{q:g}" for q in sorted(runs["q"].unique()))
    return {"env": env, "alpha": alpha, "range": name, "qs": qs, "runs": len(runs)}


def _against_middle(
    middle: list[np.ndarray], finals: list[np.ndarray], reps: int, seed: int
) -> dict[str, object]:
    """P(a run of 1 <= q < 2 beats a run of the range) over the tasks given, its interval, its
    test's p-value and verdict: the row's columns from ``p_middle`` on."""
    p, p_low, p_high = probability_of_improvement(middle, finals, reps, seed)
    p_value, verdict = improvement_verdict(middle, finals, seed)
    return {"p_middle": p, "p_low": p_low, "p_high": p_high, "p_value": p_value, "verdict": verdict}


def q_range_table(
    scores: pd.DataFrame, data: pd.DataFrame, last: int, reps: int, seed: int
) -> pd.DataFrame:
    """The table of the module docstring from the report's per-run ``scores`` (TAC runs have a
    q; ``final`` and the normalised ``score``) and its tidy ``data`` (for the spread)."""
    fixed_alpha = scores["q"].notna() & ~learns_alpha(scores["variant"])
    tac = scores[fixed_alpha & ~scores["variant"].map(has_bf16_products)].copy()
    tac["range"] = [_range_of(float(q)) for q in tac["q"]]
    tac = tac[tac["range"].notna()]
    tac = tac.join(within_run_spread(data, last).rename("spread"), on="run")
    rows: list[dict[str, object]] = []
    pooled: dict[str, dict[str, list[np.ndarray]]] = {}
    compared = 0  # the (task, alpha) groups with rows
    for (env, _), task in tac.groupby(["env", "alpha"], sort=False, dropna=False):
        ranges = {name: group for name, group in task.groupby("range", sort=False)}
        if MIDDLE not in ranges or len(ranges) < 2:
            continue
        middle = ranges[MIDDLE]["final"].to_numpy()
        compared += 1
        for name, _, _ in Q_RANGES:
            if name not in ranges:
                continue
            group = ranges[name]
            finals = group["final"].to_numpy()
            iqm, low, high = interval_estimates([finals], reps, seed)["iqm"]
            row = _row(str(env), float(group["alpha"].iloc[0]), name, group)
            row.update(iqm=iqm, iqm_low=low, iqm_high=high, spread=group["spread"].mean())
            if name != MIDDLE:
                row.update(_against_middle([middle], [finals], reps, seed))
            rows.append(row)
            pooled.setdefault(name, {"score": [], "final": [], "middle": []})
            pooled[name]["score"].append(group["score"].to_numpy())
            pooled[name]["final"].append(finals)
            pooled[name]["middle"].append(middle)
    tasks = {row["env"] for row in rows}
    if len(tasks) > 1:
        for name, _, _ in Q_RANGES:
            if len(pooled.get(name, {}).get("score", [])) < compared:
                continue
            parts = pooled[name]
            iqm, low, high = interval_estimates(parts["score"], reps, seed)["iqm"]
            row = {
                "env": ALL_TASKS,
                "alpha": math.nan,
                "range": name,
                "qs": "",
                "runs": sum(len(s) for s in parts["score"]),
                "iqm": iqm,
                "iqm_low": low,
                "iqm_high": high,
                "spread": math.nan,  # returns of different tasks do not pool
            }
            if name != MIDDLE:
                row.update(_against_middle(parts["middle"], parts["final"], reps, seed))
            rows.append(row)
    return pd.DataFrame(rows, columns=COLUMNS)
