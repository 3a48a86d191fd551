"""rliable statistics: its estimators and its stratified bootstrap.

The estimators are rliable's (Agarwal et al., 2021, "Deep RL at the Edge of the Statistical
Precipice"): the interquartile mean (IQM, 25 % trimmed mean over all runs of all tasks), the
mean of per-task means, the probability of improvement P(X > Y) (Mann-Whitney U / (n_x n_y),
averaged over tasks) and score-distribution performance profiles (fraction of runs scoring above
tau). Point estimates call ``rliable.metrics`` directly where its matrices (runs x tasks) can
hold the scores; with different run counts per task the same quantities are computed per task.

Confidence intervals are 95 % percentile intervals of rliable's stratified bootstrap
(:func:`tacbench.bootstrap.interval`): runs are resampled with replacement within each task
(tasks are not resampled), and for P(X > Y) the runs of X and of Y are resampled independently.
Each interval resamples each task's scores in ascending order from a seed derived from those
scores and the ``seed`` it is given (:func:`tacbench.bootstrap.strata_seed`;
``ReportOptions.seed``, 0): a report is a function of its scores and that seed, the same
comparison gets the same interval in every report, and adding a task or a method to a report
leaves every other interval unchanged.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import partial

import numpy as np
import pandas as pd
from rliable import metrics

from tacbench.bootstrap import interval, scalar_interval, strata_seed
from tacbench.config import has_bf16_products
from tacbench.detectable import detectable_difference, detectable_shift
from tacbench.report.mixing import learns_alpha
from tacbench.sequential import NOT_DISTINGUISHABLE
from tacbench.verdicts import improvement_verdict

DEFAULT_REPS = 2000
"""Bootstrap replications. With 2,000 the Monte-Carlo standard deviation of each interval endpoint
is about 1.5 % of the interval's width (measured on 10 runs per task); Efron & Tibshirani ask for
at least 1,000 for percentile intervals, and rliable uses 2,000 for performance profiles."""

ALL_TASKS = "all tasks"
"""The ``env`` value of rows aggregated over tasks."""
IMPROVEMENT_COLUMNS = [
    "method",
    "env",
    "tasks",
    "p",
    "low",
    "high",
    "p_value",
    "verdict",
    "difference",
    "detectable",
]
"""The improvement table: P(method > q = 1) [low, high], the p-value of its permutation test
and its verdict (:mod:`tacbench.verdicts`), and per task the
difference of mean final returns and, where not distinguishable, the smallest difference these
run counts detect with 80 % power (two-sided permutation test at 5 %)."""
BASELINE_COLUMNS = ["method", "baseline", *IMPROVEMENT_COLUMNS[1:]]
"""The comparison with the baselines: P(method > baseline) and the rest as
:data:`IMPROVEMENT_COLUMNS`."""
Estimate = tuple[float, float, float]
"""(point estimate, lower 95 % bound, upper 95 % bound)."""


def _sorted_scores(tasks: Sequence[np.ndarray]) -> list[np.ndarray]:
    """Each task's scores as float64 in ascending order. Every statistic here ignores the order
    of the runs within a task, and sorted, the resampled scores (and the seed drawn from them)
    no longer depend on the order the runs were loaded in: two reports holding the same runs
    give the same interval."""
    return [np.sort(np.asarray(scores, dtype=np.float64)) for scores in tasks]


def iqm(*tasks: np.ndarray) -> np.ndarray:
    """IQM over all runs of all tasks (one array per task, runs on the last axis, any leading
    axes: bootstrap replications): the mean of the middle runs after cutting ``int(0.25 n)``
    from each end, as ``scipy.stats.trim_mean(x, 0.25)`` (which ``rliable.metrics.aggregate_iqm``
    calls) at a sixth of its per-call cost. 1-D tasks give a 0-d array."""
    pooled = np.sort(np.concatenate(tasks, axis=-1), axis=-1)
    n = pooled.shape[-1]
    cut = int(0.25 * n)
    return np.asarray(pooled[..., cut : n - cut].mean(axis=-1))


def mean_of_means(*tasks: np.ndarray) -> np.ndarray:
    """Mean over tasks of the per-task mean (runs on the last axis, as :func:`iqm`)."""
    return np.asarray(np.stack([scores.mean(axis=-1) for scores in tasks], axis=-1).mean(axis=-1))


def _iqm_and_mean(*tasks: np.ndarray) -> np.ndarray:
    return np.stack([iqm(*tasks), mean_of_means(*tasks)], axis=-1)


def interval_estimates(tasks: Sequence[np.ndarray], reps: int, seed: int) -> dict[str, Estimate]:
    """IQM and mean with stratified-bootstrap 95 % intervals; ``tasks`` holds one array per task.

    With one run on every task the bootstrap can only draw those runs again: the interval is
    NaN (the page's n/a), not the point repeated as if it were certain.
    """
    tasks = _sorted_scores(tasks)
    equal = len({len(scores) for scores in tasks}) == 1
    matrix = np.stack(tasks, axis=1) if equal else None
    points = {
        "iqm": float(metrics.aggregate_iqm(matrix) if equal else iqm(*tasks)),
        "mean": float(metrics.aggregate_mean(matrix) if equal else mean_of_means(*tasks)),
    }
    if _single_runs(tasks):
        return {name: (point, math.nan, math.nan) for name, point in points.items()}
    _, low, high = interval(_iqm_and_mean, tasks, reps, strata_seed(seed, tasks))
    return {name: (points[name], float(low[i]), float(high[i])) for i, name in enumerate(points)}


def _single_runs(strata: Sequence[np.ndarray]) -> bool:
    """Whether every stratum holds one run: a bootstrap of them has no spread to show."""
    return all(len(scores) < 2 for scores in strata)


def pairwise_improvement(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """P(X > Y) + P(X = Y) / 2 over all pairs: Mann-Whitney U / (n_x n_y), as rliable's
    ``probability_of_improvement`` on one task, without scipy's per-call overhead. Runs on the
    last axis, as :func:`iqm`."""
    greater = (x[..., :, None] > y[..., None, :]).mean(axis=(-2, -1))
    ties = (x[..., :, None] == y[..., None, :]).mean(axis=(-2, -1))
    return np.asarray(greater + 0.5 * ties)


def probability_of_improvement(
    xs: Sequence[np.ndarray], ys: Sequence[np.ndarray], reps: int, seed: int
) -> Estimate:
    """P(X > Y) averaged over tasks, with a 95 % interval; ``xs[i]`` and ``ys[i]`` share task i.

    The point estimate is ``rliable.metrics.probability_of_improvement`` when X and Y have the
    same number of runs on every task; the pairwise count is the same quantity in general. The
    interval is NaN where X and Y have one run on every task (:func:`interval_estimates`).
    """
    xs, ys = _sorted_scores(xs), _sorted_scores(ys)
    if len(xs) != len(ys):
        raise ValueError("X and Y need scores on the same tasks")
    averaged = partial(_averaged_improvement, len(xs))
    if len({len(a) for a in xs}) == 1 and len({len(b) for b in ys}) == 1:
        point = float(
            metrics.probability_of_improvement(np.stack(xs, axis=1), np.stack(ys, axis=1))
        )
    else:
        point = float(averaged(*xs, *ys))
    strata = [*xs, *ys]
    if _single_runs(strata):
        return point, math.nan, math.nan
    _, low, high = scalar_interval(averaged, strata, reps, strata_seed(seed, strata))
    return point, low, high


def _averaged_improvement(tasks: int, *strata: np.ndarray) -> np.ndarray:
    """The mean over tasks of P(X > Y): the first ``tasks`` strata are X's, the others Y's."""
    per_task = [
        pairwise_improvement(x, y) for x, y in zip(strata[:tasks], strata[tasks:], strict=True)
    ]
    return np.asarray(np.stack(per_task, axis=-1).mean(axis=-1))


def performance_profile(
    tasks: Sequence[np.ndarray], taus: np.ndarray, reps: int, seed: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fraction of runs (of all tasks) scoring above each tau, with 95 % pointwise intervals.

    As rliable's score distributions: every run weighs the same, runs resampled within tasks.
    """
    strata = _sorted_scores(tasks)
    return interval(partial(_fractions_above, taus), strata, reps, strata_seed(seed, strata))


def _fractions_above(taus: np.ndarray, *strata: np.ndarray) -> np.ndarray:
    """The fraction of the pooled runs scoring above each tau (runs on the last axis, as
    :func:`iqm`; one tau at a time, so that replications x runs x taus is never held)."""
    pooled = np.concatenate(strata, axis=-1)
    return np.stack([(pooled > tau).mean(axis=-1) for tau in taus], axis=-1)


def per_task_estimates(scores: pd.DataFrame, reps: int, seed: int) -> pd.DataFrame:
    """IQM and mean of the final return over seeds, per task and method, with 95 % intervals.

    ``scores`` has one row per run with columns ``env``, ``method`` and ``final``.
    """
    rows = []
    for (env, method), group in scores.groupby(["env", "method"], sort=False):
        estimates = interval_estimates([group["final"].to_numpy()], reps, seed)
        rows.append({"env": env, "method": method, "runs": len(group), **_flat(estimates)})
    return pd.DataFrame(rows)


def aggregate_estimates(scores: pd.DataFrame, reps: int, seed: int) -> pd.DataFrame:
    """IQM and mean of the normalised score over all tasks of each method, with 95 % intervals.

    ``scores`` has one row per run with columns ``env``, ``method`` and ``score``. A method is
    aggregated over the tasks it has runs on (column ``tasks``).
    """
    rows = []
    for method, group in scores.groupby("method", sort=False):
        tasks = [task["score"].to_numpy() for _, task in group.groupby("env")]
        estimates = interval_estimates(tasks, reps, seed)
        rows.append({"method": method, "tasks": len(tasks), "runs": len(group), **_flat(estimates)})
    return pd.DataFrame(rows)


def _flat(estimates: dict[str, Estimate]) -> dict[str, float]:
    flat: dict[str, float] = {}
    for name, (point, low, high) in estimates.items():
        flat.update({name: point, f"{name}_low": low, f"{name}_high": high})
    return flat


def _reference_runs(
    scores: pd.DataFrame, env: str, alpha: float, learned: bool, bf16: bool
) -> np.ndarray:
    """Final returns of the q = 1 runs on ``env`` with the same alpha (NaN matches NaN), the
    same alpha mode (a learned alpha is compared with a learned alpha from the same start) and
    the same products (bfloat16 with bfloat16, float32 with float32)."""
    same = scores[(scores["env"] == env) & (scores["q"] == 1.0)]
    same = same[same["alpha"].isna()] if np.isnan(alpha) else same[same["alpha"] == alpha]
    same = same[learns_alpha(same["variant"]) == learned]
    same = same[same["variant"].map(has_bf16_products) == bf16]
    return same["final"].to_numpy()


def improvement_over_q1(
    scores: pd.DataFrame, methods: Sequence[str], reps: int, seed: int
) -> pd.DataFrame:
    """P(method > q = 1) per task and over all tasks, with 95 % intervals.

    Each TAC method is compared, task by task, with the q = 1 runs that share its alpha, its
    alpha mode (fixed, or learned: --alpha auto) and its products (float32 or bfloat16); tasks
    without such runs are left out.
    ``env`` is ``"all tasks"`` on the aggregate rows. Columns: :data:`IMPROVEMENT_COLUMNS`.
    """
    rows = []
    for method in methods:
        xs, ys, envs = [], [], []
        mine = scores[scores["method"] == method]
        for env, group in mine.groupby("env", sort=False):
            alphas = group["alpha"].unique()
            modes = learns_alpha(group["variant"]).unique()
            products = group["variant"].map(has_bf16_products).unique()
            reference = _reference_runs(
                scores, str(env), float(alphas[0]), bool(modes[0]), bool(products[0])
            )
            if len(alphas) != 1 or len(modes) != 1 or len(products) != 1 or len(reference) == 0:
                continue
            xs.append(group["final"].to_numpy())
            ys.append(reference)
            envs.append(env)
        rows += [{"method": method, **row} for row in _comparison_rows(envs, xs, ys, reps, seed)]
    return pd.DataFrame(rows, columns=IMPROVEMENT_COLUMNS)


def improvement_over_baselines(
    scores: pd.DataFrame,
    methods: Sequence[str],
    baselines: Sequence[str],
    reps: int,
    seed: int,
) -> pd.DataFrame:
    """P(method > baseline) per task and over all tasks, with 95 % intervals: the paper's
    comparison of TAC with the actor-critic baselines.

    Every method in ``methods`` (TAC at its best q, SAC) is compared, task by task, with the runs
    of every baseline on the same task; tasks where either has no runs are left out. ``env`` is
    ``"all tasks"`` on the aggregate rows. Columns: :data:`BASELINE_COLUMNS`.
    """
    rows = []
    for method in methods:
        mine = scores[scores["method"] == method]
        for baseline in baselines:
            theirs = scores[scores["method"] == baseline]
            shared = set(theirs["env"])
            envs = [e for e in mine["env"].unique() if e in shared]
            xs = [mine.loc[mine["env"] == e, "final"].to_numpy() for e in envs]
            ys = [theirs.loc[theirs["env"] == e, "final"].to_numpy() for e in envs]
            rows += [
                {"method": method, "baseline": baseline, **row}
                for row in _comparison_rows(envs, xs, ys, reps, seed)
            ]
    return pd.DataFrame(rows, columns=BASELINE_COLUMNS)


def _comparison_rows(
    envs: Sequence[object],
    xs: Sequence[np.ndarray],
    ys: Sequence[np.ndarray],
    reps: int,
    seed: int,
) -> list[dict[str, object]]:
    """P(X > Y) on each task (``xs[i]`` against ``ys[i]`` on ``envs[i]``) with its test's
    p-value and verdict (:func:`tacbench.verdicts.improvement_verdict`), the
    difference of mean final returns and, where not distinguishable, the smallest difference
    these run counts detect; then, over two or more tasks, the same averaged over tasks, where
    the detectable difference is a shift of every task in its runs' standard deviations."""
    rows: list[dict[str, object]] = []
    for env, x, y in zip(envs, xs, ys, strict=True):
        p, low, high = probability_of_improvement([x], [y], reps, seed)
        p_value, verdict = improvement_verdict([x], [y], seed)
        rows.append(
            {
                "env": env,
                "tasks": 1,
                "p": p,
                "low": low,
                "high": high,
                "p_value": p_value,
                "verdict": verdict,
                "difference": float(np.mean(x) - np.mean(y)),
                "detectable": detectable_runs(y, x) if verdict == NOT_DISTINGUISHABLE else np.nan,
            }
        )
    if len(xs) > 1:
        p, low, high = probability_of_improvement(xs, ys, reps, seed)
        p_value, verdict = improvement_verdict(xs, ys, seed)
        rows.append(
            {
                "env": ALL_TASKS,
                "tasks": len(xs),
                "p": p,
                "low": low,
                "high": high,
                "p_value": p_value,
                "verdict": verdict,
                "difference": np.nan,  # returns of different tasks do not add up
                "detectable": detectable_shift_runs(ys, xs)
                if verdict == NOT_DISTINGUISHABLE
                else np.nan,
            }
        )
    return rows


def detectable_runs(reference: np.ndarray, runs: np.ndarray) -> float:
    """The smallest difference of mean final returns these run counts detect with 80 % power
    (:func:`tacbench.detectable.detectable_difference`); NaN below two runs a side."""
    if min(len(reference), len(runs)) < 2:
        return np.nan
    return detectable_difference(reference, runs)


def profile_table(scores: pd.DataFrame, taus: np.ndarray, reps: int, seed: int) -> pd.DataFrame:
    """Score-distribution performance profile of every method over ``taus`` (normalised scores)."""
    frames = []
    for method, group in scores.groupby("method", sort=False):
        tasks = [task["score"].to_numpy() for _, task in group.groupby("env")]
        profile, low, high = performance_profile(tasks, taus, reps, seed)
        frames.append(
            pd.DataFrame(
                {"method": method, "tau": taus, "fraction": profile, "low": low, "high": high}
            )
        )
    return pd.concat(frames, ignore_index=True)


def detectable_shift_runs(references: Sequence[np.ndarray], runs: Sequence[np.ndarray]) -> float:
    """Over tasks: the smallest shift of every task's mean, in standard deviations of its runs,
    these run counts detect with 80 % power (:func:`tacbench.detectable.detectable_shift`);
    NaN where a task has fewer than two runs a side."""
    if min(min(len(r), len(x)) for r, x in zip(references, runs, strict=True)) < 2:
        return np.nan
    return detectable_shift(references, runs)
