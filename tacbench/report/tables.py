"""Per-run scores, the per-task summary table, score normalisation and the best-q table.

Per run, from its logged series (evaluations for ``--metric eval``, training episodes for
``--metric train``):

* ``final``: mean return of the last ``last`` logged points (default 10);
* ``best``: highest logged return;
* ``auc``: area under the return-vs-step curve (trapezoids between logged points) divided by
  the steps it spans, i.e. the run's average return over training (its only point if it has one).

Per task and method the summary gives mean and sample standard deviation (ddof 1) over seeds.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from tacbench.config import has_bf16_products
from tacbench.paper import task_facts
from tacbench.report.mixing import learns_alpha, without_q

DEFAULT_LAST = 10
SUMMARY_COLUMNS = (
    "env", "method", "algo", "variant", "q", "alpha", "seeds", "partial", "failed",
    "steps_min", "steps_max", "planned", "final_mean", "final_std", "best_mean", "best_std",
    "auc_mean", "auc_std",
)  # fmt: skip
BEST_Q_COLUMNS = (
    "env",
    "setting",
    "best_q",
    "best_final",
    "best_final_std",
    "best_q_not_1",
    "ranking",
    "paper_q",
    "paper_q_rank",
    "agrees",
    "best_in_1_2",
    "alpha",
    "paper_alpha",
    "paper_note",
    "p_best_over_q1",
    "p_low",
    "p_high",
)


def run_scores(data: pd.DataFrame, last: int) -> pd.DataFrame:
    """``final``, ``best`` and ``auc`` per run (index ``run``), see the module docstring.

    ``data`` is the tidy frame: rows of one run together, sorted by step.
    """
    run = data["run"].to_numpy()
    step = data["step"].to_numpy(dtype=np.float64)
    value = data["return"].to_numpy(dtype=np.float64)
    starts = np.flatnonzero(np.append(True, run[1:] != run[:-1]))
    ends = np.append(starts[1:], len(run))
    tail = np.maximum(starts, ends - last)
    # each run's own sum: a running sum over all runs let one run's huge returns swamp the
    # finals of the runs after it (1e17 made the next run's 2.5 read 0)
    in_tail = np.arange(len(run)) >= np.repeat(tail, ends - starts)
    final = np.add.reduceat(np.where(in_tail, value, 0.0), starts) / (ends - tail)
    trapezoids = np.zeros(len(run))
    trapezoids[1:] = np.where(
        run[1:] == run[:-1], np.diff(step) * (value[1:] + value[:-1]) / 2, 0.0
    )
    span = step[ends - 1] - step[starts]
    area = np.add.reduceat(trapezoids, starts)
    auc = np.where(span > 0, area / np.where(span > 0, span, 1.0), value[starts])
    return pd.DataFrame(
        {"final": final, "best": np.maximum.reduceat(value, starts), "auc": auc},
        index=pd.Index(run[starts], name="run"),
    )


def normalise(scores: pd.DataFrame) -> tuple[pd.Series, pd.DataFrame]:
    """Min-max normalise ``final`` per task over every loaded run of every method.

    0 is the lowest final return of any run on the task, 1 the highest. A task whose runs all
    score the same maps to 0. Returns the scores and the anchors (``env``, ``low``, ``high``).
    """
    low = scores.groupby("env")["final"].transform("min").to_numpy()
    high = scores.groupby("env")["final"].transform("max").to_numpy()
    width = np.where(high > low, high - low, 1.0)
    anchors = scores.groupby("env")["final"].agg(low="min", high="max").reset_index()
    return pd.Series((scores["final"].to_numpy() - low) / width, index=scores.index), anchors


def _joined(values: pd.Series) -> str:
    return ", ".join(str(v) for v in sorted(values.unique(), key=str))


def summary_table(scores: pd.DataFrame, failed: pd.DataFrame) -> pd.DataFrame:
    """One row per task and method: seeds, partial and failed runs, steps, final, best, AUC.

    ``scores`` has one row per loaded run (``env``, ``method``, ``algo``, ``variant``, ``q``,
    ``alpha``, ``partial``, ``step_reached``, ``total_steps``, ``final``, ``best``, ``auc``);
    ``failed`` one row per failed run with ``env``, ``method``, ``algo``, ``variant``, ``q`` and
    ``alpha``. A method whose every run on a task failed gets a row too (seeds 0, its failures,
    no statistics): leaving out diverged runs flatters a method, all of them most of all.
    """
    failed_counts = failed.groupby(["env", "method"]).size()
    rows = []
    for (env, method), group in scores.groupby(["env", "method"], sort=False):
        row = {
            **_method_of(env, method, group),
            "seeds": len(group),
            "partial": int(group["partial"].sum()),
            "failed": int(failed_counts.get((env, method), 0)),
            "steps_min": group["step_reached"].min(),
            "steps_max": group["step_reached"].max(),
            "planned": group["total_steps"].max(),
        }
        for column in ("final", "best", "auc"):
            row[f"{column}_mean"] = group[column].mean()
            row[f"{column}_std"] = group[column].std(ddof=1)
        rows.append(row)
    loaded = set(scores.groupby(["env", "method"]).groups)
    for (env, method), group in failed.groupby(["env", "method"], sort=False):
        if (env, method) not in loaded:
            failures = {"seeds": 0, "partial": 0, "failed": len(group)}  # no statistics
            rows.append({**_method_of(env, method, group), **failures})
    return pd.DataFrame(rows, columns=list(SUMMARY_COLUMNS))


def _method_of(env: object, method: object, group: pd.DataFrame) -> dict[str, object]:
    """The summary columns that name a task's method, from its runs (loaded or failed)."""
    return {
        "env": env,
        "method": method,
        "algo": _joined(group["algo"]),
        "variant": _joined(group["variant"]),
        "q": group["q"].iat[0],
        "alpha": _joined(group["alpha"].dropna()) or "",
    }


def best_q_rows(summary: pd.DataFrame) -> pd.DataFrame:
    """Per task, the TAC row with the highest mean final return among q != 1 (for the figure):
    among the runs of the paper's design (a fixed alpha, float32 products) where the task has
    any, so that TAC (best q) is not one task's learned alpha beside another's fixed one. Column
    ``candidates``: how many rows it was picked from (more than one: picked by these runs)."""
    tac = summary[(summary["algo"] == "tac") & (summary["seeds"] > 0)]
    candidates = tac[tac["q"].notna() & (tac["q"] != 1.0)]  # a fixed q: not TAC q=auto
    variants = candidates["variant"]
    papers = candidates[~learns_alpha(variants) & ~variants.map(has_bf16_products)]
    candidates = pd.concat([papers, candidates[~candidates["env"].isin(papers["env"])]])
    by_task = candidates.groupby("env", sort=False)["final_mean"]
    best = candidates.loc[by_task.idxmax()].assign(candidates=by_task.size().to_numpy())
    return best.reset_index(drop=True)


def best_q_table(summary: pd.DataFrame, improvement: pd.DataFrame) -> pd.DataFrame:
    """The best q per task and setting from the data, and how its ranking compares with the
    paper's.

    A *setting* is a TAC variant without its q (``a0.2``; ``aauto0.2`` for a learned alpha;
    ``a0.2-bs32``): a task with runs of several gets a row for each, which ranks that setting's
    q values alone (ranked together, one q's fixed and learned alpha runs would stand side by
    side unnamed). Ranking is by mean final return over seeds (all q, q = 1 included); where
    the q values have different seed counts, the ranking gives each its count.
    ``p_best_over_q1`` is P(best q != 1 > q = 1) on that task with its 95 % interval (from
    ``improvement``); it is optimistic because the best q was picked on the same runs.
    """
    rows = []
    tac = summary[(summary["algo"] == "tac") & summary["q"].notna()]  # TAC q=auto has no q
    tac = tac.assign(setting=tac["variant"].map(without_q))
    for (env, setting), group in tac.groupby(["env", "setting"], sort=False):
        ranked = group[group["seeds"] > 0].sort_values("final_mean", ascending=False)
        if ranked.empty:
            continue  # every run failed: the summary table says so
        failed_qs = sorted(group.loc[group["seeds"] == 0, "q"])
        top = ranked.iloc[0]
        others = ranked[ranked["q"] != 1.0]
        paper = task_facts(str(env))
        paper_q = None if paper is None else paper.best_q
        rank = "n/a"
        agrees = "n/a"
        if paper_q is not None:
            positions = np.flatnonzero(ranked["q"].to_numpy() == paper_q)
            if len(positions):
                rank = f"{positions[0] + 1} of {len(ranked)}"
                agrees = "yes" if top["q"] == paper_q else "no"
            else:  # a ranking without the paper's q neither confirms nor refutes it
                rank = "every run failed" if paper_q in failed_qs else "not run"
                agrees = "not tested"
        row = {
            "env": env,
            "setting": setting,
            "best_q": top["q"],
            "best_final": top["final_mean"],
            "best_final_std": top["final_std"],
            "best_q_not_1": others.iloc[0]["q"] if len(others) else math.nan,
            "ranking": _ranking(ranked) + _all_failed(failed_qs),
            "paper_q": "task not in the paper" if paper is None else paper.best_q_label,
            "paper_q_rank": rank,
            "agrees": agrees,
            "best_in_1_2": "yes" if 1.0 <= top["q"] < 2.0 else "no",
            "alpha": _joined(group["alpha"].str.split(", ").explode()),
            "paper_alpha": None if paper is None else paper.alpha,
            "paper_note": "" if paper is None else paper.says,
        }
        best_method = str(others.iloc[0]["method"]) if len(others) else ""
        row.update(_improvement_of_best(improvement, str(env), best_method))
        rows.append(row)
    return pd.DataFrame(rows, columns=list(BEST_Q_COLUMNS))


def _ranking(ranked: pd.DataFrame) -> str:
    """The q values best first; each with its seed count where the counts differ, so that a q
    ranked on fewer seeds (one, say, whose mean is that seed's luck) reads as such."""
    if ranked["seeds"].nunique() == 1:
        return " > ".join(f"{q:g}" for q in ranked["q"])
    return " > ".join(f"{q:g} (n={n})" for q, n in zip(ranked["q"], ranked["seeds"], strict=True))


def _all_failed(qs: list[float]) -> str:
    """The ranking's tail naming the q values whose every run failed (empty if none)."""
    return "; every run failed: " + ", ".join(f"{q:g}" for q in qs) if qs else ""


def _improvement_of_best(improvement: pd.DataFrame, env: str, method: str) -> dict[str, float]:
    """P(method > q = 1) on ``env``, read from the improvement table (NaN where absent)."""
    empty = {"p_best_over_q1": math.nan, "p_low": math.nan, "p_high": math.nan}
    match = improvement[(improvement["env"] == env) & (improvement["method"] == method)]
    if not method or match.empty:
        return empty
    first = match.iloc[0]
    return {"p_best_over_q1": first["p"], "p_low": first["low"], "p_high": first["high"]}
